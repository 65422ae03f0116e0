"""CVXPY backend: successive-linearization MPC as one DPP-compliant QP built once.

Per step only parameter values change: the initial state, the LTV model ``(A_k, B_k, c_k)``,
the input bounds and the target. The problem is compiled once (``Problem.is_dpp()`` is
checked at construction), so a solve skips canonicalization. With Clarabel, each solve by
default goes straight from the compiled parameter-to-data map to a persistent Clarabel solver
(:mod:`mpclab.controllers.cvxpy_direct`); ``solve_via: problem`` uses ``Problem.solve``.

``sl: converge`` (default) iterates the linearization to convergence with a trust region:
each QP is linearized about the plant's rollout of the current inputs ``Ubar``, its inputs
kept within ``|U - Ubar| <= radius`` (per input, scaled by half its range; the trust region
and the input bounds are one pair of parameters, so the QP does not grow). A step is taken
when the true nonlinear cost of its rollout (the objective's CasADi form, compiled with the
rollout and the linearization into one function) falls by at least a tenth of what the QP
predicted; the radius grows after good steps that hit it and shrinks after poor ones. The
step is ``converged`` when a step inside the trust region is below ``tol`` (scaled inputs,
max norm) or predicts a relative cost decrease below ``tol``; at ``max_iterations`` it is
``truncated``. ``sl: one_pass`` is the study's scheme, one QP per step, always ``truncated``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from mpclab.controllers.base import (
    Controller,
    ControlStep,
    FloatArray,
    SolveStatus,
    StepContext,
    shift,
    terminal_rows,
)
from mpclab.controllers.cvxpy_direct import CompiledQP, DirectClarabel, SolveVia
from mpclab.errors import ConfigError
from mpclab.lazy import lazy_import
from mpclab.objectives.base import Objective, TermContext
from mpclab.plants.base import Plant
from mpclab.registry import component

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it

#: bound given to the QP for an input without one (and no trust region): never active
_FREE = 1e6
#: largest trust radius (in half input ranges)
_MAX_RADIUS = 1e3
#: a step is taken when the true cost falls by this fraction of the predicted fall
_ACCEPT = 0.1
#: weight of the constraint violation of a rollout in the merit (cost + weight * violation),
#: and the violation [state units] below which a rollout counts as feasible
_PENALTY, _FEAS_TOL = 1e6, 1e-5
#: ``hessian: exact``: eigenvalues of the Hessian are raised to this fraction of the largest
_CURVATURE = 1e-9


class CvxpySolver(StrEnum):
    CLARABEL = "CLARABEL"
    OSQP = "OSQP"


class SlMode(StrEnum):
    #: iterate with a trust region until the step or the predicted cost decrease is below tol
    converge = "converge"
    #: one linearize-and-solve pass per step (the study's scheme): truncated by design
    one_pass = "one_pass"


class Hessian(StrEnum):
    #: the Hessian in the inputs of the rollout's true cost, eigenvalues clipped to >= 0:
    #: the QP's objective is that quadratic model (SQP in the inputs)
    exact = "exact"
    #: the terms' own quadratic form on the linearized states (Gauss-Newton)
    gauss_newton = "gauss_newton"


class Linearization(StrEnum):
    #: the previous solution shifted by one step, first point replaced by the measured state
    shifted_plan = "shifted_plan"
    #: the previous inputs shifted by one step, states simulated from the measured state
    rollout = "rollout"


@dataclass
class CvxpyConf:
    _target_: str = "mpclab.controllers.cvxpy.CvxpyMPC"
    horizon: int = 10
    dt: float = 0.1
    solver: CvxpySolver = CvxpySolver.CLARABEL
    warm_start: bool = True
    sl: SlMode = SlMode.converge
    tol: float = 1e-6
    max_iterations: int = 20
    trust_radius: float = 0.5
    hessian: Hessian = Hessian.exact
    initial_input: dict[str, float] = field(default_factory=dict)
    linearize_about: Linearization = Linearization.shifted_plan
    terminal_constraint: dict[str, float] = field(default_factory=dict)
    solver_options: dict[str, Any] = field(default_factory=dict)
    solve_via: SolveVia = SolveVia.auto


class _Point(NamedTuple):
    """Inputs, their rollout, its true cost, merit and feasibility, the LTV model along it,
    and (``hessian: exact``) the cost's gradient in ``vec(U)``, the clipped Hessian ``L'L``
    and a direction of negative curvature."""

    U: FloatArray
    X: FloatArray
    cost: float
    merit: float
    feasible: bool
    model: FloatArray | None
    grad: FloatArray | None = None
    L: FloatArray | None = None
    #: the direction ``(T, nu)`` of the Hessian's most negative curvature, if it has one
    descent: FloatArray | None = None


@component("controller", "cvxpy", CvxpyConf)
class CvxpyMPC(Controller):
    """Successive-linearization MPC solved as a convex QP with CVXPY.

    Parameters
    ----------
    plant, objective
        Injected; every objective term must support CVXPY (and CasADi, for ``converge``:
        the true cost of a rollout is evaluated with the terms' CasADi form).
    horizon, dt
        Prediction steps and sample time [s].
    solver
        ``CLARABEL`` (default) or ``OSQP``.
    warm_start
        Passed to the solver (OSQP reuses its factorization and previous solution).
    sl
        ``converge`` (iterate to ``tol`` or ``max_iterations``) or ``one_pass``.
    tol
        ``converge``: stop when a step inside the trust region is at most ``tol`` (inputs in
        half their ranges, max norm) or predicts a relative cost decrease of at most ``tol``.
    max_iterations
        ``converge``: QPs per step at most; a step stopped here is ``truncated``.
    trust_radius
        ``converge``: the trust region at the start of each step, in half input ranges.
    hessian
        ``converge``: the QP's objective, ``exact`` (a quadratic model of the rollout's true
        cost in the inputs) or ``gauss_newton`` (the terms' CVXPY form on the linearized
        states, as ``one_pass``).
    initial_input
        ``{input label: value}`` held over the horizon as the first linearization point
        (others 0). The car at rest with zero steering angle has no first-order steering
        effect; a forward acceleration gives it one.
    linearize_about
        ``one_pass``: ``shifted_plan`` or ``rollout`` (``converge`` always linearizes about
        the rollout, whose true cost it needs).
    terminal_constraint
        ``{state label: value}`` imposed on the last predicted state.
    solver_options
        Extra keyword options for the solver (Clarabel settings by name, ``max_iter``, ...).
    solve_via
        ``auto`` (default: ``direct`` with Clarabel, else ``problem``), ``direct`` (the
        compiled data straight into a persistent Clarabel solver) or ``problem``
        (``Problem.solve`` every step). Both give the same solution.
    """

    def __init__(
        self,
        plant: Plant,
        objective: Objective,
        horizon: int = 10,
        dt: float = 0.1,
        solver: CvxpySolver | str = CvxpySolver.CLARABEL,
        warm_start: bool = True,
        sl: SlMode | str = SlMode.converge,
        tol: float = 1e-6,
        max_iterations: int = 20,
        trust_radius: float = 0.5,
        hessian: Hessian | str = Hessian.exact,
        initial_input: Mapping[str, float] | None = None,
        linearize_about: Linearization | str = Linearization.shifted_plan,
        terminal_constraint: Mapping[str, float] | None = None,
        solver_options: Mapping[str, Any] | None = None,
        solve_via: SolveVia | str = SolveVia.auto,
    ) -> None:
        super().__init__(plant, horizon, dt)
        self.solver = _enum(CvxpySolver, solver, "controller.solver").value
        self.warm_start = bool(warm_start)
        self.sl = _enum(SlMode, sl, "controller.sl")
        if int(max_iterations) < 1:
            raise ConfigError(f"controller.max_iterations must be >= 1, got {max_iterations}")
        if not float(tol) > 0:
            raise ConfigError(f"controller.tol must be > 0, got {tol}")
        if not 0 < float(trust_radius) <= _MAX_RADIUS:
            raise ConfigError(
                f"controller.trust_radius must be in (0, {_MAX_RADIUS:g}], got {trust_radius}"
            )
        self.max_iterations, self.tol = int(max_iterations), float(tol)
        self.trust_radius = float(trust_radius)
        self.hessian = _enum(Hessian, hessian, "controller.hessian")
        #: the QP's objective is the terms' CVXPY form (else the exact quadratic model)
        self._terms_qp = self.sl is SlMode.one_pass or self.hessian is Hessian.gauss_newton
        self.linearize_about = _enum(Linearization, linearize_about, "controller.linearize_about")
        self.solver_options = dict(solver_options or {})
        self._u_guess = np.zeros(plant.nu)
        for label, value in dict(initial_input or {}).items():
            try:
                self._u_guess[plant.input_index(label)] = float(value)
            except ValueError as exc:
                raise ConfigError(f"controller.initial_input: {exc}") from None
        self._u_guess = plant.clip_input(self._u_guess)
        lo, hi = plant.u_lb, plant.u_ub
        self._scale = np.where(np.isfinite(hi - lo), (hi - lo) / 2, 1.0)
        self._u_lo, self._u_hi = np.maximum(lo, -_FREE), np.minimum(hi, _FREE)
        self.objective = objective
        objective.bind(plant, "cvxpy")
        if self.sl is SlMode.converge:
            for term in objective:
                term.require("casadi")
        self._terminal = terminal_rows(plant, terminal_constraint)
        self._build()
        self.qp = CompiledQP(self.problem, [self.X, self.U], self.solver, self.solver_options,
                             self.warm_start, solve_via)
        if self.sl is SlMode.converge:
            self._cost_fn, self._model_fn = self._build_evaluation()

    def _build(self) -> None:
        nx, nu, T = self.plant.nx, self.plant.nu, self.horizon
        self.X = X = cp.Variable((nx, T + 1), name="X")
        self.U = U = cp.Variable((nu, T), name="U")
        self.p_x0 = cp.Parameter(nx, name="x0")
        # the whole LTV model in one parameter, columns [A_0..A_T-1 | B_0..B_T-1 | c_0..c_T-1]:
        # one value update per step instead of 2T+1 (each update is validated by CVXPY)
        self.p_model = M = cp.Parameter((nx, T * (nx + nu + 1)), name="model")
        a0, c0 = T * nx, T * (nx + nu)
        self.p_target = cp.Parameter((nx, T + 1), name="target")
        # input bounds, intersected with the trust region around Ubar in `converge`
        self.p_u_lo = cp.Parameter((nu, T), name="u_lo")
        self.p_u_hi = cp.Parameter((nu, T), name="u_hi")
        cons = [X[:, 0] == self.p_x0]
        cons += [
            X[:, k + 1]
            == M[:, k * nx : (k + 1) * nx] @ X[:, k]
            + M[:, a0 + k * nu : a0 + (k + 1) * nu] @ U[:, k]
            + M[:, c0 + k]
            for k in range(T)
        ]
        cons += [U >= self.p_u_lo, U <= self.p_u_hi]
        cons += _box(X[:, 1:], self.plant.x_lb, self.plant.x_ub)
        cons += [X[i, T] == value for i, value in self._terminal]
        self.p_u_prev = cp.Parameter(nu, name="u_prev")
        if self._terms_qp:
            ctx = TermContext(x0=self.p_x0, target=self.p_target, u_prev=self.p_u_prev)
            cost = sum(term.cvxpy_cost(X, U, ctx) for term in self.objective)
        else:  # g'u + |L u - L ubar|^2 / 2: the model up to a constant (L'L: clipped Hessian)
            n = nu * T
            self.p_grad = cp.Parameter(n, name="grad")
            self.p_L = cp.Parameter((n, n), name="L")
            self.p_Lu = cp.Parameter(n, name="L_ubar")
            u = cp.vec(U, order="F")
            cost = self.p_grad @ u + 0.5 * cp.sum_squares(self.p_L @ u - self.p_Lu)
        self.problem = cp.Problem(cp.Minimize(cost), cons)
        if not self.problem.is_dpp():
            raise ConfigError(
                "the CVXPY problem is not DPP-compliant, so it would be recompiled every step; "
                "check that every objective term is affine in its parameters"
            )
        # compile now (canonicalization, the parameter-to-data map), not in the first step
        for param in self.problem.parameters():
            param.value = np.zeros(param.shape)
        self.problem.get_problem_data(self.solver)

    def _build_evaluation(self) -> tuple[ca.Function, ca.Function]:
        """Two CasADi functions of ``(x0, U, target, u_prev)``: ``(X, cost)``, the rollout and
        its true cost (the terms' CasADi form), for every candidate; and ``(model[, grad,
        hess])``, the LTV model along the rollout laid out as the ``model`` parameter (and the
        cost's gradient and Hessian in ``vec(U)``), only where the next QP is linearized."""
        p, T, dt = self.plant, self.horizon, self.dt
        x0, U = ca.SX.sym("x0", p.nx), ca.SX.sym("U", p.nu, T)
        target, u_prev = ca.SX.sym("target", p.nx, T + 1), ca.SX.sym("u_prev", p.nu)
        cols = [x0]
        for k in range(T):
            cols.append(p.F(cols[-1], U[:, k], dt))
        X = ca.horzcat(*cols)
        ctx = TermContext(x0=x0, target=target, u_prev=u_prev)
        cost = sum(term.casadi_cost(X, U, ctx) for term in self.objective)
        lin = [p.F_lin(X[:, k], U[:, k], dt) for k in range(T)]
        out = [ca.horzcat(*[m[0] for m in lin], *[m[1] for m in lin], *[m[2] for m in lin])]
        if not self._terms_qp:
            hess, grad = ca.hessian(cost, ca.vec(U))
            out += [grad, hess]
        args = [x0, U, target, u_prev]
        return ca.Function("sl_cost", args, [X, cost]), ca.Function("sl_model", args, out)

    @property
    def direct(self) -> DirectClarabel | None:
        """The direct Clarabel path, or None when solving through ``Problem.solve``."""
        return self.qp.direct

    def reset(self, x0: Any) -> None:
        """Forget the previous plan and anything the solver keeps from the last run (its
        warm start, the persistent Clarabel solver), so a reused controller repeats a run."""
        super().reset(x0)
        self.qp.reset()

    def _guess(self) -> FloatArray:
        """The first linearization inputs ``(T, nu)``: the previous plan shifted, or
        ``initial_input`` held."""
        prev = self.previous_plan
        if prev is None:
            return np.tile(self._u_guess, (self.horizon, 1))
        return shift(prev.u_pred)

    def _set_model(self, A: FloatArray, B: FloatArray, c: FloatArray) -> None:
        nx = self.plant.nx
        _assign(self.p_model, np.concatenate(
            [A.transpose(1, 0, 2).reshape(nx, -1), B.transpose(1, 0, 2).reshape(nx, -1), c.T],
            axis=1,
        ))

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        _assign(self.p_x0, x)
        _assign(self.p_target, ctx.target.T)
        _assign(self.p_u_prev, self.previous_input)
        if self.sl is SlMode.one_pass:
            return self._one_pass(x)
        return self._converge(x, ctx)

    # ------------------------------------------------------------------ one pass
    def _one_pass(self, x: FloatArray) -> ControlStep:
        Ubar = self._guess()
        if self.previous_plan is None or self.linearize_about is Linearization.rollout:
            Xbar = self.plant.rollout(x, Ubar, self.dt)[:-1]
        else:
            Xbar = shift(self.previous_plan.x_pred)[:-1].copy()
            Xbar[0] = x
        self._set_model(*self.plant.linearize_trajectory(Xbar, Ubar, self.dt))
        T = self.horizon
        _assign(self.p_u_lo, np.tile(self._u_lo[:, None], (1, T)))
        _assign(self.p_u_hi, np.tile(self._u_hi[:, None], (1, T)))
        sol = self.qp.solve()
        if sol.values is None:
            return self._failed(sol.status, x, sol.raw, sol.message, sol.iterations)
        Xv, Uv = sol.values
        # one linearize-and-solve pass: the QP converged, the linearization was not iterated
        return ControlStep(
            u=Uv[:, 0].copy(), x_pred=Xv.T.copy(), u_pred=Uv.T.copy(),
            status=SolveStatus.truncated, cost=sol.objective, solver_status=sol.raw,
            iterations=1, info={"qp_iterations": sol.iterations},
        )

    # ------------------------------------------------------------------ converge
    def _point(self, x: FloatArray, U: FloatArray, ctx: StepContext) -> _Point:
        """``U`` rolled out from ``x``, with its true cost and merit (no model yet)."""
        X, cost = self._cost_fn(x, U.T, ctx.target.T, self.previous_input)
        X = np.asarray(X, dtype=float).T
        viol = self._violation(X)
        return _Point(U, X, float(cost), float(cost) + _PENALTY * viol, viol == 0.0, None)

    def _with_model(self, pt: _Point, x: FloatArray, ctx: StepContext) -> _Point:
        """``pt`` with the LTV model along its rollout (and the exact quadratic model)."""
        if pt.model is not None:
            return pt
        out = self._model_fn.call([x, pt.U.T, ctx.target.T, self.previous_input])
        model = np.asarray(out[0], dtype=float)
        if self._terms_qp:
            return pt._replace(model=model)
        lam, V = np.linalg.eigh(np.asarray(out[2], dtype=float))
        floor = _CURVATURE * max(float(lam[-1]), 1.0)
        L = np.sqrt(np.maximum(lam, floor))[:, None] * V.T
        grad = np.asarray(out[1], dtype=float).ravel()
        descent = None
        if lam[0] < -_CURVATURE * max(float(lam[-1]), 1.0):
            descent = V[:, 0].reshape(self.horizon, self.plant.nu) / self._scale
            descent /= np.max(np.abs(descent))
        return pt._replace(model=model, grad=grad, L=L, descent=descent)

    def _escape(self, pt: _Point, bar: _Point, x: FloatArray, ctx: StepContext,
                radius: float) -> _Point | None:
        """A point of lower merit than ``pt`` along ``bar``'s negative curvature, or None.

        A convex QP cannot leave a saddle point (the car heading straight at the goal, where
        steering either way is better than none): at a stationary point the clipped model
        predicts no decrease. Try steps of the trust radius (and a quarter of it) both ways.
        """
        if bar.descent is None:
            return None
        best = None
        for alpha in (radius, radius / 4):
            for sign in (1.0, -1.0):
                U = np.clip(pt.U + sign * alpha * bar.descent * self._scale,
                            self._u_lo, self._u_hi)
                trial = self._point(x, U, ctx)
                if trial.merit < pt.merit - self.tol * abs(pt.merit) and (
                    best is None or trial.merit < best.merit
                ):
                    best = trial
            if best is not None:
                return best
        return None

    def _violation(self, X: FloatArray) -> float:
        """Sum of the rollout's state-bound and terminal violations beyond ``_FEAS_TOL``."""
        p = self.plant
        over = np.maximum(X[1:] - p.x_ub, 0.0) + np.maximum(p.x_lb - X[1:], 0.0)
        total = float(np.sum(np.maximum(over - _FEAS_TOL, 0.0)))
        for i, value in self._terminal:
            total += max(abs(X[-1, i] - value) - _FEAS_TOL, 0.0)
        return total

    def _converge(self, x: FloatArray, ctx: StepContext) -> ControlStep:
        bar = self._point(x, self._guess(), ctx)
        radius, qp_iters, raw = self.trust_radius, 0, ""
        s = self._scale
        for it in range(1, self.max_iterations + 1):
            # a first guess that breaks a constraint (the nominal input of a cold start)
            # takes a full step; so does a trust region the linearized constraints cannot meet
            r = np.inf if it == 1 and not bar.feasible else radius
            bar = self._with_model(bar, x, ctx)
            sol = self._trust_region_qp(bar, r)
            if sol.status is SolveStatus.infeasible and np.isfinite(r):
                r = np.inf
                qp_iters += sol.iterations or 0
                sol = self._trust_region_qp(bar, r)
            qp_iters += sol.iterations or 0
            raw = sol.raw
            if sol.values is None:
                return self._failed(sol.status, x, sol.raw, sol.message, it)
            U = sol.values[1].T
            step = float(np.max(np.abs(U - bar.U) / s))
            inside = step < 0.999 * r
            predicted = bar.merit - sol.objective
            if bar.grad is not None:  # the exact model's QP objective leaves out a constant
                predicted -= bar.cost - bar.grad @ bar.U.ravel()
            new = self._point(x, U, ctx)
            actual = bar.merit - new.merit
            if inside and new.feasible and (
                step <= self.tol or predicted <= self.tol * abs(bar.merit)
            ):
                best = new if actual >= 0 else bar
                escape = self._escape(best, bar, x, ctx, radius)
                if escape is None:
                    return self._plan_step(best, SolveStatus.converged, raw, it, qp_iters,
                                           radius)
                bar = escape
                continue
            rho = actual / predicted if predicted > 0 else -np.inf
            if rho >= _ACCEPT:
                bar = new
            if rho < 0.25:
                radius = 0.25 * step
            elif rho > 0.75 and not inside:
                radius = min(2 * radius, _MAX_RADIUS)
            if radius < self.tol * 1e-3:  # no progress possible at this accuracy
                break
        return self._plan_step(bar, SolveStatus.truncated, raw, it, qp_iters, radius)

    def _trust_region_qp(self, bar: _Point, r: float) -> Any:
        """The QP linearized about ``bar`` with ``|U - bar.U| <= r`` (scaled)."""
        _assign(self.p_model, bar.model)
        if bar.grad is not None:
            _assign(self.p_grad, bar.grad)
            _assign(self.p_L, bar.L)
            _assign(self.p_Lu, bar.L @ bar.U.ravel())
        _assign(self.p_u_lo, np.maximum(self._u_lo, bar.U - r * self._scale).T)
        _assign(self.p_u_hi, np.minimum(self._u_hi, bar.U + r * self._scale).T)
        return self.qp.solve()

    def _plan_step(self, pt: _Point, status: SolveStatus, raw: str, iterations: int,
                   qp_iterations: int, radius: float) -> ControlStep:
        return ControlStep(
            u=pt.U[0].copy(), x_pred=pt.X, u_pred=pt.U.copy(), status=status, cost=pt.cost,
            solver_status=raw, iterations=iterations,
            info={"qp_iterations": qp_iterations, "trust_radius": radius},
        )


def _box(V: cp.Expression, lb: FloatArray, ub: FloatArray) -> list[cp.Constraint]:
    """Row-wise bounds on ``V`` for the finite entries of ``lb``/``ub``."""
    cons = []
    lo = [i for i in range(len(lb)) if np.isfinite(lb[i])]
    hi = [i for i in range(len(ub)) if np.isfinite(ub[i])]
    if lo:
        cons.append(V[lo, :] >= lb[lo][:, None])
    if hi:
        cons.append(V[hi, :] <= ub[hi][:, None])
    return cons


def _assign(param: cp.Parameter, value: Any) -> None:
    """Set a parameter's value without CVXPY's per-assignment validation (it projects the
    value onto the parameter's attributes, of which ours have none: about 0.1 ms each, a
    dozen times a step); the shape and finiteness are checked here."""
    value = np.array(value, dtype=float)
    if value.shape != param.shape or not np.all(np.isfinite(value)):
        raise ValueError(f"parameter {param.name()}: bad value of shape {value.shape}")
    param.save_value(value)


def _enum(cls: type[StrEnum], value: Any, where: str) -> Any:
    try:
        return cls(value.value if isinstance(value, StrEnum) else value)
    except ValueError:
        valid = ", ".join(m.value for m in cls)
        raise ConfigError(f"{where}: unknown choice {value!r}; valid: {valid}") from None
