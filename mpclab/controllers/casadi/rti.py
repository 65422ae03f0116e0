"""Real-time iteration of the CasADi backend's NLP: a preparation and a feedback phase.

Diehl's real-time iteration (RTI) takes one SQP step per sample, split at the measurement:

* **preparation** (:meth:`RealTimeIteration.prepare`, before the measurement): at a guess
  ``w`` (the previous solution shifted by one step) with the parameters known then ``p``,
  it evaluates the constraints ``g``, their Jacobian ``J``, the cost's gradient and the
  Hessian of the Lagrangian ``f + lam' g`` (exact, made convex by clipping its eigenvalues
  block by block, as CasADi's ``sqpmethod`` does with ``convexify_strategy=eigen-clip``),
  and the sensitivities of ``g`` and of the cost's gradient to the *fast* parameters ``q``:
  the measured state and the input in effect. The QP in the step ``d``

      min 1/2 d' H d + c(q)' d   s.t.  lbg - g(q) <= J d <= ubg - g(q),  lbw - w <= d <= ubw - w

  with ``g(q) = g + G (q - q0)`` and ``c(q) = grad f + F (q - q0)`` is then fixed up to ``q``
  (the initial-value embedding: exact where ``q`` enters the NLP linearly, as the initial
  state does under multiple shooting; first order under single shooting, whose states are
  the rollout from it). CasADi's ``conic`` factors its matrices inside each call (none of its
  plugins takes a factorization made beforehand), so the preparation ends at the QP's data.
* **feedback** (:meth:`RealTimeIteration.feedback`, after the measurement): ``q`` embedded
  (two matrix-vector products), the one QP solved (``conic`` with ``controller.solve.qp_solver``),
  ``w + d`` and the QP's multipliers the new iterate.

Every other parameter (goal, reference, detected points, constraint data) is the one the
preparation had. Convergence (:attr:`RtiResult.kkt`) is read on the QP's model at the
linearization point: the constraint violation ``g(q)`` and the bounds at ``w``, and the
gradient of the Lagrangian with the QP's multipliers, ``c(q) + J' lam_a + lam_x``, which the
QP's optimality makes ``-H d``; both within ``tol`` (sqpmethod's ``tol_pr``, ``tol_du``) means
``w`` was a KKT point (of the NLP itself where ``q`` enters linearly) and the step vanishes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
import numpy.typing as npt
from scipy.sparse import csc_matrix
from scipy.sparse.csgraph import connected_components

from mpclab.controllers.base import FEEDBACK_KEY, ControlStep
from mpclab.controllers.casadi.ocp import OCP
from mpclab.controllers.casadi.solvers import CasadiQpSolver, bind_buffers, qp_options, read_status
from mpclab.core.native_output import c_stdout_silenced
from mpclab.core.status import USABLE, SolveStatus

FloatArray = npt.NDArray[np.float64]

#: the smallest eigenvalue a convexified Hessian block keeps (sqpmethod's
#: ``convexify_margin`` default)
MARGIN = 1e-7


@dataclass
class Prepared:
    """One preparation: the linearization point and the QP's data that do not depend on
    the fast parameters, with the sensitivities that embed them."""

    owner: RealTimeIteration
    w: FloatArray        # the linearization point
    p: FloatArray        # the parameters it was prepared with
    f: float             # the cost at ``w``
    g: FloatArray        # g(w, p)
    grad: FloatArray     # the cost's gradient at w
    G: FloatArray        # dg/dq (ng, nq)
    F: FloatArray        # d(grad f)/dq (nw, nq)
    h: FloatArray        # the convexified Hessian's nonzeros (the QP's pattern)
    a: FloatArray        # J's nonzeros
    lam_x0: FloatArray   # the QP's multiplier guesses
    lam_a0: FloatArray


@dataclass
class RtiResult:
    """The feedback's new iterate and how its QP went."""

    w: FloatArray
    lam_x: FloatArray
    lam_g: FloatArray
    p: FloatArray        # the parameters the QP embedded
    status: SolveStatus  # ``truncated`` (one SQP step; ``converged`` after :meth:`refine`
    #                      found a KKT point), or the QP's failure
    raw: str             # the QP solver's return string
    g: FloatArray        # the constraints at the linearization point, ``q`` embedded
    c: FloatArray        # the cost's gradient there


class RealTimeIteration:
    """The preparation and feedback of one SQP step on an :class:`OCP`.

    Parameters
    ----------
    ocp
        The NLP and its bounds.
    fast
        The names of the parameters the feedback embeds (``x0``, ``u_prev``).
    qp_solver
        The QP solver of ``conic``.
    tol
        The KKT tolerance of ``converged``.
    """

    def __init__(self, ocp: OCP, fast: tuple[str, ...], qp_solver: CasadiQpSolver,
                 tol: float) -> None:
        nlp = ocp.nlp
        w, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
        self.ocp, self.tol = ocp, float(tol)
        self.fast = np.concatenate([ocp.params.indices(n) for n in fast])
        q = ca.vertcat(*[p[int(i)] for i in self.fast])
        lam = ca.SX.sym("lam_g", g.shape[0])
        H, _ = ca.hessian(f + ca.dot(lam, g), w)
        grad = ca.gradient(f, w)
        J = ca.jacobian(g, w)
        self._lin = ca.Function(
            "rti_linearization", [w, p, lam],
            [f, g, grad, J, ca.densify(ca.jacobian(g, q)), ca.densify(ca.jacobian(grad, q)),
             H],
            ["w", "p", "lam_g"], ["f", "g", "grad", "J", "G", "F", "H"])
        self._cost = ca.Function("rti_cost", [w, p], [f])
        n = int(w.shape[0])
        # the Hessian's blocks: the connected parts of its pattern with the diagonal, each
        # clipped on its own and held dense in the QP
        hs = H.sparsity() + ca.Sparsity.diag(n)
        rows, cols = (np.asarray(a) for a in hs.get_triplet())
        _, label = connected_components(
            csc_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)), directed=False)
        self._blocks = [np.flatnonzero(label == b) for b in range(label.max() + 1)]
        pattern = np.zeros((n, n), dtype=bool)
        for b in self._blocks:
            pattern[np.ix_(b, b)] = True
        qr, qc = np.nonzero(pattern.T)  # column-major: CasADi's order of nonzeros
        h_sp = ca.Sparsity.triplet(n, n, qc.tolist(), qr.tolist())
        self._h_rows, self._h_cols = (np.asarray(a) for a in h_sp.get_triplet())
        hr, hc = (np.asarray(a) for a in H.sparsity().get_triplet())
        self._hess_at = (hr, hc)
        self._j_rows, self._j_cols = (np.asarray(a) for a in J.sparsity().get_triplet())
        with c_stdout_silenced():  # qpOASES prints its banner whenever one is built
            self.qp = ca.conic("rti_qp", qp_solver.value,
                               {"h": h_sp, "a": J.sparsity()}, qp_options(qp_solver))
            self._lin_buf, self._lin_go, self._lin_io = bind_buffers(self._lin, {})
            self._qp_buf, self._qp_go, self._qp_io = bind_buffers(self.qp, {})
        self._dense_h = np.zeros((n, n))

    # ---------------------------------------------------------------- preparation
    def prepare(self, w: FloatArray, p: FloatArray, lam_g: FloatArray | None = None,
                lam_x: FloatArray | None = None) -> Prepared:
        """Linearize at ``w`` with the parameters ``p`` and multipliers ``lam_g`` (zero:
        the cost's Hessian alone), and load the QP's matrices (``H`` convexified, ``J``)."""
        io = self._lin_io
        ng = self.ocp.lbg.size
        io["w"][:], io["p"][:] = w, p
        io["lam_g"][:] = 0.0 if lam_g is None else lam_g
        self._lin_go()
        nq = self.fast.size
        return Prepared(
            self, np.array(w, dtype=float), np.array(p, dtype=float), float(io["f"][0]),
            io["g"].copy(), io["grad"].copy(), io["G"].reshape(nq, ng).T.copy(),
            io["F"].reshape(nq, w.size).T.copy(), self._convexified(io["H"]), io["J"].copy(),
            np.zeros(w.size) if lam_x is None else np.array(lam_x, dtype=float),
            np.zeros(ng) if lam_g is None else np.array(lam_g, dtype=float))

    def _convexified(self, h_nz: FloatArray) -> FloatArray:
        """The Hessian's nonzeros with each block's eigenvalues clipped at :data:`MARGIN`,
        as the QP's nonzeros (every block dense)."""
        Hd = self._dense_h
        Hd[:] = 0.0
        Hd[self._hess_at] = h_nz
        for b in self._blocks:
            if b.size == 1:
                i = b[0]
                Hd[i, i] = max(Hd[i, i], MARGIN)
                continue
            block = Hd[np.ix_(b, b)]
            vals, vecs = np.linalg.eigh(block)
            if vals[0] < MARGIN:
                Hd[np.ix_(b, b)] = (vecs * np.maximum(vals, MARGIN)) @ vecs.T
        return Hd[self._h_rows, self._h_cols]

    # ---------------------------------------------------------------- feedback
    def feedback(self, prep: Prepared, p: FloatArray) -> RtiResult:
        """The QP of ``prep`` with the fast parameters of ``p`` embedded, solved: the new
        iterate (its other parameters are ``prep``'s)."""
        ocp, qp = self.ocp, self._qp_io
        used = prep.p.copy()
        used[self.fast] = p[self.fast]
        dq = used[self.fast] - prep.p[self.fast]
        g = prep.g + prep.G @ dq
        c = prep.grad + prep.F @ dq
        qp["h"][:], qp["a"][:], qp["g"][:] = prep.h, prep.a, c
        qp["lba"][:], qp["uba"][:] = ocp.lbg - g, ocp.ubg - g
        qp["lbx"][:], qp["ubx"][:] = ocp.lbw - prep.w, ocp.ubw - prep.w
        qp["x0"][:] = 0.0
        qp["lam_x0"][:], qp["lam_a0"][:] = prep.lam_x0, prep.lam_a0
        self._qp_go()
        status, raw, _ = read_status(self._qp_buf)
        if status is SolveStatus.converged:  # the QP's solution: one SQP step, not the NLP's
            status = SolveStatus.truncated
        return RtiResult(prep.w + qp["x"], qp["lam_x"].copy(), qp["lam_a"].copy(), used,
                         status, raw, g, c)

    def kkt(self, prep: Prepared, sol: RtiResult) -> tuple[float, float]:
        """(primal violation, dual residual) at the linearization point on the QP's model
        with the QP's multipliers (module docstring)."""
        ocp, w, g = self.ocp, prep.w, sol.g
        with np.errstate(invalid="ignore"):  # inf - inf of an unbounded side
            viol = np.concatenate([ocp.lbg - g, g - ocp.ubg, ocp.lbw - w, w - ocp.ubw, [0.0]])
        primal = float(np.nanmax(viol))
        jt_lam = np.zeros(w.size)  # J' lam_a from J's nonzeros
        np.add.at(jt_lam, self._j_cols, prep.a * sol.lam_g[self._j_rows])
        dual = float(np.abs(sol.c + jt_lam + sol.lam_x).max()) if w.size else 0.0
        return primal, dual

    def refine(self, prep: Prepared, sol: RtiResult) -> None:
        """``sol`` converged if its linearization point was a KKT point within ``tol``."""
        if sol.status is SolveStatus.truncated and max(self.kkt(prep, sol)) <= self.tol:
            sol.status = SolveStatus.converged

    def cost(self, w: FloatArray, p: FloatArray) -> float:
        """The NLP's cost at ``w`` (the iterate the feedback gave)."""
        return float(self._cost(w, p))


#: what the preparation starts from: ``(w, p, lam_g, lam_x)`` (None multipliers: zero)
Point = tuple[Any, ...]
#: ``(w, status, raw) -> (w, status, raw)``: an iterate outside its bounds clipped or failed
Check = Callable[[FloatArray, SolveStatus, str], tuple[FloatArray, SolveStatus, str]]


class RtiLoop:
    """When the two phases run in the closed loop, which calls the controller once per
    sample: the feedback at the measurement on the QP prepared for it, then (the input
    known, between samples) the next sample's preparation. A call with no QP prepared for
    it (the first, one on another NLP, one after a failure) prepares first, after the
    measurement: a *late* preparation, counted in its feedback time.

    The step log gets :attr:`columns`: ``feedback_s`` (from the call to the input: the
    parameters packed, the state embedded, the QP solved, its iterate checked against its
    bounds; the latency; ``feedback_cpu_s`` its CPU time, which waits for a core do not
    inflate), ``prep_s`` (after the input: the convergence check, the plan and its cost, the
    next sample's preparation) and ``late_prep``.
    """

    columns = ("prep_s", FEEDBACK_KEY, "feedback_cpu_s", "late_prep")

    def __init__(self) -> None:
        self.prepared: Prepared | None = None

    def reset(self) -> None:
        self.prepared = None

    def step(self, rti: RealTimeIteration, params: Callable[[], FloatArray],
             start: Callable[[FloatArray], Point], check: Check,
             finish: Callable[[RtiResult], ControlStep],
             next_point: Callable[[ControlStep], Point]) -> ControlStep:
        """One sample: ``params()`` are the measured sample's parameters, ``start(p)`` a
        late preparation's point, ``check(w, status, raw)`` decides whether the feedback's
        iterate is applied (its bounds), ``finish`` makes the step of it (the plan, the
        multipliers kept), ``next_point(step)`` the next preparation's point."""
        t0, c0 = time.perf_counter(), time.thread_time()
        p = params()
        prep = self.prepared
        late = prep is None or prep.owner is not rti
        if late:
            prep = rti.prepare(*start(p))
        sol = rti.feedback(prep, p)
        sol.w, sol.status, sol.raw = check(sol.w, sol.status, sol.raw)
        t1, c1 = time.perf_counter(), time.thread_time()  # the input is known
        if sol.status in USABLE:
            rti.refine(prep, sol)
        res = finish(sol)
        self.prepared = None
        if res.ok:
            res.cost = rti.cost(sol.w, sol.p)
            self.prepared = rti.prepare(*next_point(res))
        res.info |= {"prep_s": time.perf_counter() - t1, FEEDBACK_KEY: t1 - t0,
                     "feedback_cpu_s": c1 - c0, "late_prep": late}
        return res

    @staticmethod
    def metrics(steps: Any) -> dict[str, Any]:
        """The phases over a run's step log: median and largest times [ms], and how many
        calls prepared late."""
        out: dict[str, Any] = {}
        for col in ("prep_s", "feedback_s"):
            v = np.asarray(steps[col], dtype=float) if col in steps else np.zeros(0)
            v = v[np.isfinite(v)] * 1e3
            name = col.removesuffix("_s")
            out[f"{name}_median_ms"] = float(np.median(v)) if v.size else None
            out[f"{name}_max_ms"] = float(v.max()) if v.size else None
        late = steps["late_prep"] if "late_prep" in steps else []
        out["late_preps"] = int(sum(bool(v) for v in late if v is not None and v == v))
        return out
