"""Successive linearization iterated to convergence with a trust region (the CVXPY backend's
``sl: converge``).

Each iteration solves a QP linearized about the plant's rollout of the current inputs
``Ubar``, its inputs kept within ``|U - Ubar| <= radius`` (per input, in half its range, max
norm). The QP's objective is either a quadratic model of the rollout's true cost in the
inputs (``exact``: its gradient and Hessian, eigenvalues clipped to be convex) or the terms'
own quadratic form on the linearized states (``gauss_newton``). A step is taken when the true
merit of its rollout (the objective's CasADi form, the soft constraints' penalty of the
rollout's true violation, and a penalty on any other constraint's violation) falls by at
least a tenth of what the QP predicted; the radius grows after good steps that reach it
and shrinks after poor ones. The iteration has ``converged`` when a step inside the trust
region is at most ``tol`` or predicts a relative decrease of at most ``tol`` (and, with the
exact Hessian, no direction of negative curvature lowers the cost: a saddle point is left),
provided that QP itself converged (else ``truncated``); at ``max_iterations`` it is
``truncated``.

With the objective's constraints (linearized in the QP), a step that the linearization
error of the dynamics carries across a constraint's boundary is rejected however good its
cost (the Maratos effect, here of the robot turning along a wall). A rejected step is then
corrected once (a second-order correction): the same QP with the dynamics model moved through
the step's rollout (``A_k, B_k`` kept, ``c_k`` such that the model meets the rollout,
:func:`model_through`) and the constraints linearized about that rollout, judged against
the first QP's prediction (``zumo_cvxpy_wall``: 25 of 25 steps converged, 23 without it).
A QP the linearized constraints leave infeasible even without the trust region (linearized
about a rollout through an obstacle) is posed again about standing still (zero input), which
keeps every distance it has.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import NamedTuple

import casadi as ca
import numpy as np

from mpclab.controllers.base import FloatArray, SolveStatus
from mpclab.controllers.blocking import Blocking
from mpclab.controllers.cvxpy.direct import QPSolution
from mpclab.objectives.base import Objective, TermContext
from mpclab.plants.base import Plant

#: largest trust radius (in half input ranges)
MAX_RADIUS = 1e3
#: a step is taken when the true merit falls by this fraction of the predicted fall
ACCEPT = 0.1
#: weight of the constraint violation of a rollout in the merit (cost + weight * violation),
#: and the violation [state units] below which a rollout counts as feasible (a QP solved by
#: Clarabel keeps its constraints to about 1e-6 in the rollout); a soft constraint's penalty
#: in the merit counts its violation beyond the same tolerance (without it, steps along a
#: wall whose rollout gave up 1e-5 m were rejected: 33 QPs where 13 do)
PENALTY, FEAS_TOL = 1e6, 1e-5
#: ``exact``: eigenvalues of the Hessian are raised to this fraction of the largest (at
#: 1e-9, Clarabel stopped with numerical errors near the goal at ``horizon=60``)
CURVATURE = 1e-6


def model_through(model: FloatArray, X: FloatArray, U: FloatArray) -> FloatArray:
    """The LTV ``model`` (columns ``[A_0..A_T-1 | B_0..B_T-1 | c_0..c_T-1]``) with ``c_k``
    such that it meets the trajectory ``X (T+1, nx)``, ``U (T, nu)``:
    ``c_k = x_{k+1} - A_k x_k - B_k u_k``."""
    (T, nu), nx = U.shape, X.shape[1]
    A = model[:, :T * nx].reshape(nx, T, nx)
    B = model[:, T * nx:T * (nx + nu)].reshape(nx, T, nu)
    c = X[1:].T - np.einsum("ikj,kj->ik", A, X[:-1]) - np.einsum("ikj,kj->ik", B, U)
    return np.concatenate([model[:, :T * (nx + nu)], c], axis=1)


class Hessian(StrEnum):
    #: the Hessian in the inputs of the rollout's true cost, eigenvalues clipped to >= 0:
    #: the QP's objective is that quadratic model (SQP in the inputs)
    exact = "exact"
    #: the terms' own quadratic form on the linearized states (Gauss-Newton)
    gauss_newton = "gauss_newton"


class Point(NamedTuple):
    """The free moves ``U (M, nu)`` (the inputs under a control horizon, ``M = T``
    unblocked), their rollout ``(T+1, nx)``, its true cost, merit and feasibility; where a QP
    is linearized: the LTV model (laid out as the backend's ``model`` parameter) and, with
    the exact Hessian, the cost's gradient in ``vec(U)``, ``L`` with ``L'L`` the clipped
    Hessian, and a direction of negative curvature (or None)."""

    U: FloatArray
    X: FloatArray
    cost: float
    merit: float
    feasible: bool
    model: FloatArray | None = None
    grad: FloatArray | None = None
    L: FloatArray | None = None
    descent: FloatArray | None = None
    #: the soft constraints' penalty of the rollout (the true cost is ``cost + penalty``)
    penalty: float = 0.0


class Outcome(NamedTuple):
    """The iteration's result: the plan, its status, the QP's last word, the QPs solved,
    the QP solver's iterations summed, the final radius; ``failure`` when a QP failed."""

    point: Point
    status: SolveStatus
    raw: str
    iterations: int
    qp_iterations: int
    radius: float
    failure: QPSolution | None = None


#: ``solve(point, radius, through)``: the QP linearized about ``point`` within ``radius``,
#: its model moved through the rollout ``through`` (a second-order correction) unless None
QPStep = Callable[[Point, float, "Point | None"], QPSolution]
#: ``judge(X)``: per constraint, its penalty if soft (else None) and how far the rollout
#: ``X`` breaks it at each stage
Judge = Callable[[FloatArray], list[tuple["float | None", FloatArray]]]


class TrustRegionSL:
    """The iteration, with the rollout, its cost and its linearization compiled once.

    Parameters
    ----------
    plant, objective, dt
        As the backend's; every term needs a CasADi form (the true cost).
    blocking
        The horizon's blocks: the iteration is over the free moves.
    terminal
        ``(state index, value)`` rows of the terminal constraint.
    hessian, tol, max_iterations, trust_radius
        See the module docstring and :class:`~mpclab.controllers.cvxpy.mpc.CvxpyMPC`.
    u_lo, u_hi
        Input bounds (finite).
    judge
        The objective's constraints on a rollout
        (:meth:`~mpclab.controllers.cvxpy.constraints.QPConstraints.judge`), or None.
    """

    def __init__(
        self, plant: Plant, objective: Objective, blocking: Blocking, dt: float,
        terminal: list[tuple[int, float]], hessian: Hessian, tol: float, max_iterations: int,
        trust_radius: float, u_lo: FloatArray, u_hi: FloatArray, judge: Judge | None = None,
    ) -> None:
        self.plant, self.dt, self.terminal = plant, dt, terminal
        self.blocking, self.horizon = blocking, blocking.horizon
        self.exact = hessian is Hessian.exact
        self.tol, self.max_iterations, self.trust_radius = tol, max_iterations, trust_radius
        self.u_lo, self.u_hi, self.judge = u_lo, u_hi, judge
        lo, hi = plant.u_lb, plant.u_ub
        #: half of each input's range (1 for an unbounded input): the trust region's unit
        self.scale = np.where(np.isfinite(hi - lo), (hi - lo) / 2, 1.0)
        self._cost_fn, self._model_fn = self._build(objective)

    def _build(self, objective: Objective) -> tuple[ca.Function, ca.Function]:
        """Two CasADi functions of ``(x0, V, target, u_prev)`` (``V (nu, M)`` the moves):
        ``(X, cost)``, the rollout and its true cost (the terms' CasADi form), for every
        candidate; and ``(model[, grad, hess])``, only where the next QP is linearized (the
        derivatives in ``vec(V)``)."""
        p, T, dt = self.plant, self.horizon, self.dt
        x0, V = ca.SX.sym("x0", p.nx), ca.SX.sym("V", p.nu, self.blocking.n_moves)
        U = V if self.blocking.free else ca.mtimes(V, ca.DM(self.blocking.matrix().T))
        target, u_prev = ca.SX.sym("target", p.nx, T + 1), ca.SX.sym("u_prev", p.nu)
        cols = [x0]
        for k in range(T):
            cols.append(p.F(cols[-1], U[:, k], dt))
        X = ca.horzcat(*cols)
        ctx = TermContext(x0=x0, target=target, u_prev=u_prev)
        cost = sum(term.casadi_cost(X, U, ctx) for term in objective)
        lin = [p.F_lin(X[:, k], U[:, k], dt) for k in range(T)]
        out = [ca.horzcat(*[m[0] for m in lin], *[m[1] for m in lin], *[m[2] for m in lin])]
        if self.exact:
            hess, grad = ca.hessian(cost, ca.vec(V))
            out += [grad, hess]
        args, opts = [x0, V, target, u_prev], {"cse": True}  # CSE: 20 % fewer instructions
        return (ca.Function("sl_cost", args, [X, cost], opts),
                ca.Function("sl_model", args, out, opts))

    # ------------------------------------------------------------------ points
    def point(self, x: FloatArray, U: FloatArray, target: FloatArray,
              u_prev: FloatArray) -> Point:
        """The moves ``U (M, nu)`` rolled out from ``x``, with its true cost and merit (no
        model yet)."""
        X, cost = self._cost_fn(x, U.T, target, u_prev)
        X = np.asarray(X, dtype=float).T
        viol, penalty = self.violation(X), 0.0
        for weight, v in self.judge(X) if self.judge is not None else ():
            beyond = float(np.sum(np.maximum(v - FEAS_TOL, 0.0)))
            if weight is None:
                viol += beyond
            else:
                penalty += weight * beyond
        return Point(U, X, float(cost), float(cost) + penalty + PENALTY * viol, viol == 0.0,
                     penalty=penalty)

    def with_model(self, pt: Point, x: FloatArray, target: FloatArray,
                   u_prev: FloatArray) -> Point:
        """``pt`` with what a QP linearized about it needs."""
        if pt.model is not None:
            return pt
        out = self._model_fn.call([x, pt.U.T, target, u_prev])
        model = np.asarray(out[0], dtype=float)
        if not self.exact:
            return pt._replace(model=model)
        lam, V = np.linalg.eigh(np.asarray(out[2], dtype=float))
        floor = CURVATURE * max(float(lam[-1]), 1.0)
        L = np.sqrt(np.maximum(lam, floor))[:, None] * V.T
        descent = None
        if lam[0] < -floor:
            descent = V[:, 0].reshape(self.blocking.n_moves, self.plant.nu) / self.scale
            descent /= np.max(np.abs(descent))
        grad = np.asarray(out[1], dtype=float).ravel()
        return pt._replace(model=model, grad=grad, L=L, descent=descent)

    def violation(self, X: FloatArray) -> float:
        """Sum of the rollout's state-bound and terminal violations beyond ``FEAS_TOL``."""
        p = self.plant
        over = np.maximum(X[1:] - p.x_ub, 0.0) + np.maximum(p.x_lb - X[1:], 0.0)
        total = float(np.sum(np.maximum(over - FEAS_TOL, 0.0)))
        for i, value in self.terminal:
            total += max(abs(X[-1, i] - value) - FEAS_TOL, 0.0)
        return total

    def escape(self, pt: Point, bar: Point, x: FloatArray, target: FloatArray,
               u_prev: FloatArray, radius: float) -> Point | None:
        """A point of lower merit than ``pt`` along ``bar``'s negative curvature, or None.

        A convex QP cannot leave a saddle point (the car heading straight at the goal, where
        steering either way is better than none): there the clipped model predicts no
        decrease. Steps of the trust radius (then a quarter of it) are tried both ways.
        """
        if bar.descent is None:
            return None
        for alpha in (radius, radius / 4):
            trials = [
                self.point(x, np.clip(pt.U + sign * alpha * bar.descent * self.scale,
                                      self.u_lo, self.u_hi), target, u_prev)
                for sign in (1.0, -1.0)
            ]
            best = min(trials, key=lambda t: t.merit)
            if best.merit < pt.merit - self.tol * abs(pt.merit):
                return best
        return None

    # ------------------------------------------------------------------ iteration
    def run(self, x: FloatArray, U0: FloatArray, target: FloatArray, u_prev: FloatArray,
            solve: QPStep) -> Outcome:
        """Iterate from the moves ``U0 (M, nu)``; ``target`` is ``(nx, T+1)``."""
        bar = self.point(x, U0, target, u_prev)
        still = np.tile(np.clip(0.0, self.u_lo, self.u_hi), (len(U0), 1))  # zero input
        radius, qp_iters, raw = self.trust_radius, 0, ""
        it = 0
        for it in range(1, self.max_iterations + 1):
            # a first guess that breaks a constraint, or gives way on a soft one (the nominal
            # input of a cold start) takes a full step; so does a trust region the linearized
            # constraints cannot meet
            r = np.inf if it == 1 and (not bar.feasible or bar.penalty > 0) else radius
            bar = self.with_model(bar, x, target, u_prev)
            sol = solve(bar, r, None)
            if sol.status is SolveStatus.infeasible and np.isfinite(r):
                qp_iters += sol.iterations or 0
                r = np.inf
                sol = solve(bar, r, None)
            if sol.status is SolveStatus.infeasible and self.judge is not None \
                    and not np.array_equal(bar.U, still):
                # linearized about a rollout through an obstacle, the halfspaces of the stages
                # on either side of it leave no way between; about standing still they all
                # face the robot where it stands, and standing still meets them
                qp_iters += sol.iterations or 0
                bar = self.with_model(self.point(x, still, target, u_prev), x, target, u_prev)
                sol = solve(bar, r, None)
            qp_iters += sol.iterations or 0
            raw = sol.raw
            if sol.values is None:
                return Outcome(bar, sol.status, raw, it, qp_iters, radius, sol)
            U = sol.values[1].T
            step = float(np.max(np.abs(U - bar.U) / self.scale))
            inside = step < 0.999 * r
            predicted = bar.merit - sol.objective
            if bar.grad is not None:  # the exact model's QP objective leaves out a constant
                predicted -= bar.cost - bar.grad @ bar.U.ravel()
            new = self.point(x, U, target, u_prev)
            actual = bar.merit - new.merit
            if inside and new.feasible and (
                step <= self.tol or predicted <= self.tol * abs(bar.merit)
            ):
                best = new if actual >= 0 else bar
                escape = self.escape(best, bar, x, target, u_prev, radius)
                if escape is None:  # converged, if the QP that says so converged itself
                    status = SolveStatus(sol.status)
                    return Outcome(best, status, raw, it, qp_iters, radius)
                bar = escape
                continue
            rho = actual / predicted if predicted > 0 else -np.inf
            if rho < ACCEPT and self.judge is not None and predicted > 0:
                corrected = solve(bar, r, new)
                qp_iters += corrected.iterations or 0
                if corrected.values is not None:
                    soc = self.point(x, corrected.values[1].T, target, u_prev)
                    if bar.merit - soc.merit >= ACCEPT * predicted:
                        new, rho = soc, (bar.merit - soc.merit) / predicted
            if rho >= ACCEPT:
                bar = new
            if rho < 0.25:
                radius = 0.25 * step
            elif rho > 0.75 and not inside:
                radius = min(2 * radius, MAX_RADIUS)
            if radius < self.tol * 1e-3:  # no progress possible at this accuracy
                break
        return Outcome(bar, SolveStatus.truncated, raw, it, qp_iters, radius)
