"""Condensed (dense) linear MPC: prediction matrices, the QP they give, and its solvers.

An affine model ``x[k+1] = A x[k] + B u[k] + c`` held over ``T`` steps, with the inputs
move-blocked into ``M`` free moves ``U`` (:mod:`mpclab.controllers.blocking`: the control
horizon or a list of blocks), predicts

    X = Px x0 + Pu U + pc            X = (x[0], ..., x[T]) stacked, ((T+1) nx,)

The quadratic tracking cost ``sum_k ||x[k] - ref[k]||^2_W + sum_k ||u[k]||^2_R`` is then
``U' H U + 2 g' U + const`` with ``H = Pu' W Pu + E' R E`` (constant for a fixed model) and
``g = Pu' W (Px x0 + pc - ref)`` (changes every step with the state and the previewed
reference). With box bounds on the inputs the QP is ``min 1/2 U' H U + g' U``,
``lb <= U <= ub``:

* :func:`box_qp_2` solves it exactly in closed form when ``U`` has 2 entries (2 inputs,
  control horizon 1),
* :func:`box_qp_active_set`, a primal active-set method, solves any size exactly
  (finitely many steps, each an exact linear solve),
* :class:`CvxpyBoxQP` solves the same QP through CVXPY (the comparison in the benchmark).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import numpy.typing as npt

from mpclab.controllers.blocking import Blocking
from mpclab.controllers.cvxpy.direct import CompiledQP, DirectClarabel, QPSolution, SolveVia
from mpclab.core.lazy_import import lazy_import

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it

FloatArray = npt.NDArray[np.float64]


def condenser(nx: int, nu: int, blocking: Blocking) -> ca.Function:
    """A compiled CasADi function ``(A, B, c) -> (Px, Pu, pc)`` for a held affine model."""
    A = ca.SX.sym("A", nx, nx)
    B = ca.SX.sym("B", nx, nu)
    c = ca.SX.sym("c", nx)
    E = blocking.matrix(nu)
    horizon, M = blocking.horizon, blocking.n_moves
    Xk, Uk, ck = ca.SX.eye(nx), ca.SX.zeros(nx, M * nu), ca.SX.zeros(nx, 1)
    Px, Pu, pc = [Xk], [Uk], [ck]
    for k in range(horizon):
        Bk = ca.mtimes(B, ca.DM(E[k * nu : (k + 1) * nu, :]))
        Xk, Uk, ck = ca.mtimes(A, Xk), ca.mtimes(A, Uk) + Bk, ca.mtimes(A, ck) + c
        Px.append(Xk)
        Pu.append(Uk)
        pc.append(ck)
    return ca.Function(
        "condense", [A, B, c], [ca.vertcat(*Px), ca.vertcat(*Pu), ca.vertcat(*pc)],
        ["A", "B", "c"], ["Px", "Pu", "pc"],
    )


class TrackingQP:
    """The cost's constant parts: state weights over the horizon and blocked input weights.

    Parameters
    ----------
    state_w, terminal_w
        Diagonal state weights ``(nx,)`` on steps ``1..T`` and added on step ``T``.
    input_w
        Diagonal input weights ``(nu,)`` on steps ``0..T-1``.
    blocking
        The ``T`` steps' blocks into ``M`` free moves.
    """

    def __init__(
        self, state_w: FloatArray, terminal_w: FloatArray, input_w: FloatArray,
        blocking: Blocking,
    ) -> None:
        nx, nu, T = state_w.size, input_w.size, blocking.horizon
        w = np.tile(state_w, (T + 1, 1))
        w[0] = 0.0
        w[T] += terminal_w
        #: weights of the stacked prediction ``((T+1) nx,)``
        self.w = w.ravel()
        #: rows of the stacked prediction that carry weight
        self.rows = np.flatnonzero(self.w)
        E = blocking.matrix(nu)
        #: ``E' R E``: the input weights over the blocked moves
        self.R = E.T @ (np.tile(input_w, T)[:, None] * E)
        self.E = E
        self.nx, self.nu = nx, nu

    def hessian(self, Pu: FloatArray) -> FloatArray:
        """``H = Pu' W Pu + E' R E`` (the QP is ``1/2 U' H U + g' U``)."""
        Pw = Pu[self.rows]
        return Pw.T @ (self.w[self.rows, None] * Pw) + self.R

    def gradient_maps(
        self, Px: FloatArray, Pu: FloatArray, pc: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(Kx, kc, Kr)`` with ``g = Kx x0 + kc - Kr ref.ravel()``."""
        rows, wr = self.rows, self.w[self.rows]
        PwT = (Pu[rows] * wr[:, None]).T
        Kr = np.zeros((Pu.shape[1], self.w.size))
        Kr[:, rows] = PwT
        return PwT @ Px[rows], PwT @ pc[rows], Kr

    def gradient(
        self, Px: FloatArray, Pu: FloatArray, pc: FloatArray, x0: FloatArray, ref: FloatArray
    ) -> FloatArray:
        """``g`` for one state and reference (no precomputation: for per-step models)."""
        rows = self.rows
        resid = Px[rows] @ x0 + pc[rows] - ref.ravel()[rows]
        return Pu[rows].T @ (self.w[rows] * resid)

    def cost(self, X: FloatArray, ref: FloatArray, U: FloatArray) -> float:
        """The tracking cost of a predicted ``X ((T+1) nx,)`` and blocked moves ``U``."""
        e = X - ref.ravel()
        return float(self.w @ (e * e) + U @ self.R @ U)


def box_qp_2(
    h00: float, h01: float, h11: float, g0: float, g1: float,
    l0: float, u0: float, l1: float, u1: float,
) -> tuple[float, float]:
    """Exact minimizer of ``1/2 z' H z + g' z`` over the box ``[l0, u0] x [l1, u1]``.

    ``H = [[h00, h01], [h01, h11]]`` must be positive definite. If the unconstrained
    minimizer violates no bound it is the answer. Otherwise at least one bound it violates
    is active at the optimum (were none, the optimum would also solve the problem with only
    its active bounds, which the unconstrained minimizer satisfies and beats). So the
    optimum lies on the edge of a violated bound: a 1-D convex problem, solved exactly by
    clipping; with two violated bounds the better of the two edges wins. Plain floats: no
    array overhead for two numbers.
    """
    det = h00 * h11 - h01 * h01
    z0 = (h01 * g1 - h11 * g0) / det
    z1 = (h01 * g0 - h00 * g1) / det
    a = l0 if z0 < l0 else (u0 if z0 > u0 else None)
    b = l1 if z1 < l1 else (u1 if z1 > u1 else None)
    if a is None and b is None:
        return z0, z1
    if a is not None:  # on the edge z0 = a
        e1 = min(max(-(g1 + h01 * a) / h11, l1), u1)
        if b is None:
            return a, e1
    if b is not None:  # on the edge z1 = b
        e0 = min(max(-(g0 + h01 * b) / h00, l0), u0)
        if a is None:
            return e0, b
    Ja = 0.5 * (h00 * a * a + h11 * e1 * e1) + h01 * a * e1 + g0 * a + g1 * e1
    Jb = 0.5 * (h00 * e0 * e0 + h11 * b * b) + h01 * e0 * b + g0 * e0 + g1 * b
    return (a, e1) if Ja <= Jb else (e0, b)


def box_qp_active_set(
    H: FloatArray, g: FloatArray, lb: FloatArray, ub: FloatArray, max_iter: int = 200,
) -> FloatArray:
    """Exact minimizer of ``1/2 z' H z + g' z`` over ``lb <= z <= ub`` (H positive definite).

    Primal active-set method on the bounds, started from the clipped unconstrained
    minimizer: solve the equality-constrained problem on the free variables, step to it or
    to the first bound in the way (which joins the working set), and when the step is zero
    release the bound whose multiplier is most negative; stop when all are >= 0.

    Raises
    ------
    RuntimeError
        If ``max_iter`` iterations do not reach optimality (a degenerate cycle).
    """
    n = g.size
    z = np.clip(np.linalg.solve(H, -g), lb, ub)
    fixed = (z <= lb) | (z >= ub)
    upper = z >= ub
    scale = 1.0 + float(np.max(np.abs(g), initial=0.0))
    for _ in range(max_iter):
        free = ~fixed
        p = np.zeros(n)
        if free.any():
            rhs = g[free] + H[np.ix_(free, fixed)] @ z[fixed]
            p[free] = np.linalg.solve(H[np.ix_(free, free)], -rhs) - z[free]
        if np.max(np.abs(p)) <= 1e-14 * (1.0 + np.max(np.abs(z))):
            grad = H @ z + g
            lam = np.where(upper, -grad, grad)
            lam[free] = np.inf
            j = int(np.argmin(lam))
            if lam[j] >= -1e-13 * scale:
                return z
            fixed[j] = upper[j] = False
            continue
        alpha, block = 1.0, -1
        for i in np.flatnonzero(free):
            if p[i] < 0 and np.isfinite(lb[i]):
                a = (lb[i] - z[i]) / p[i]
            elif p[i] > 0 and np.isfinite(ub[i]):
                a = (ub[i] - z[i]) / p[i]
            else:
                continue
            if a < alpha:
                alpha, block = a, i
        z = z + alpha * p
        if block >= 0:
            z[block] = lb[block] if p[block] < 0 else ub[block]
            fixed[block] = True
            upper[block] = p[block] > 0
    raise RuntimeError(f"box QP active set: no optimum after {max_iter} iterations")


class CvxpyBoxQP:
    """The same box QP through CVXPY, built once (DPP): ``H`` enters by its Cholesky factor.

    Parameters
    ----------
    lb, ub
        Bounds of ``z`` (infinite entries are left unbounded).
    solver
        A CVXPY solver name (``CLARABEL``, ``OSQP``).
    options
        Keyword options for the solver.
    solve_via
        ``auto`` (Clarabel on the compiled data, others through ``Problem.solve``),
        ``direct`` or ``problem``; see :mod:`mpclab.controllers.cvxpy.direct`.
    """

    def __init__(
        self,
        lb: FloatArray,
        ub: FloatArray,
        solver: str,
        options: dict | None = None,
        solve_via: SolveVia | str = SolveVia.auto,
    ) -> None:
        n = lb.size
        self.z = cp.Variable(n, name="z")
        self.L = cp.Parameter((n, n), name="L")
        self.g = cp.Parameter(n, name="g")
        cons = []
        lo, hi = np.flatnonzero(np.isfinite(lb)), np.flatnonzero(np.isfinite(ub))
        if lo.size:
            cons.append(self.z[lo] >= lb[lo])
        if hi.size:
            cons.append(self.z[hi] <= ub[hi])
        cost = 0.5 * cp.sum_squares(self.L @ self.z) + self.g @ self.z
        self.problem = cp.Problem(cp.Minimize(cost), cons)
        if not self.problem.is_dpp():  # pragma: no cover - a construction bug, not input
            raise RuntimeError("CvxpyBoxQP is not DPP")
        self.L.value, self.g.value = np.eye(n), np.zeros(n)  # the direct path needs values
        self.qp = CompiledQP(self.problem, [self.z], solver, options, via=solve_via)

    @property
    def direct(self) -> DirectClarabel | None:
        """The direct Clarabel path, or None when solving through ``Problem.solve``."""
        return self.qp.direct

    def reset(self) -> None:
        """Start the next run as a fresh solver would."""
        self.qp.reset()

    def solve(self, H: FloatArray, g: FloatArray) -> QPSolution:
        """The QP's solution; its ``values`` are None unless the solve is usable."""
        self.L.value = np.linalg.cholesky(H).T
        self.g.value = g
        return self.qp.solve()
