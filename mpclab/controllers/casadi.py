"""CasADi backend: nonlinear MPC by multiple shooting over the plant's RK4 step.

The NLP is built once, with every per-step quantity a parameter: the measured state, the
goal, the target over the horizon, up to ``max_detections`` detected points with a mask, and
one activity weight per objective term (so a supervisor switches objective sets without a
rebuild). Two solvers share the NLP:

* ``ipopt``: solved to convergence (interior point), warm-started from the previous
  solution shifted by one step;
* ``sqp_rti``: real-time iteration, a fixed number of SQP steps (``sqp_iterations``, one QP
  each: qpOASES, OSQP or CasADi's sparse active-set ``qrqp``) per sample from the shifted
  previous solution and multipliers, the Hessian of the Lagrangian made convex.

Optional hard collision constraint (``collision_distance = R > 0``): every predicted position
``p_k`` (``k = 1..T``) keeps ``|p_k - p_i| >= R_i`` from every detected point ``p_i``, written
``R_i^2 - |p_k - p_i|^2 <= 0``, with ``R_i = min(R, |p_0 - p_i|)`` (a point already nearer
than ``R`` may not be approached further, so that standing still stays feasible) and
``R_i = 0`` for padding. Detected points lie on obstacle surfaces, so ``R`` = robot radius +
a margin keeps the robot's disc off them. The left side is concave in ``p_k``: its
linearization (the QP of ``sqp_rti``) is a half-plane inside the feasible set.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum, StrEnum
from typing import Any

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
from mpclab.errors import ConfigError
from mpclab.objectives.base import Objective, TermContext
from mpclab.plants.base import Plant
from mpclab.quiet import c_stdout_silenced
from mpclab.registry import component


class CasadiSolver(StrEnum):
    ipopt = "ipopt"
    sqp_rti = "sqp_rti"


class Shooting(StrEnum):
    multiple = "multiple"
    single = "single"


class QpSolver(StrEnum):
    qpoases = "qpoases"
    osqp = "osqp"
    qrqp = "qrqp"


#: solvers' own return strings that mean a stop short of the full tolerance with a usable
#: iterate (an iteration or time cap, IPOPT's reduced "acceptable" tolerance)
_TRUNCATED = frozenset({
    "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded",
    "Maximum_WallTime_Exceeded", "Search_Direction_Becomes_Too_Small",
})
#: CasADi's unified return status -> ours (``SOLVER_RET_SUCCESS`` is refined by _TRUNCATED)
_UNIFIED = {
    "SOLVER_RET_SUCCESS": SolveStatus.converged,
    "SOLVER_RET_LIMITED": SolveStatus.truncated,
    "SOLVER_RET_INFEASIBLE": SolveStatus.infeasible,
    "SOLVER_RET_NAN": SolveStatus.failed,
    "SOLVER_RET_EXCEPTION": SolveStatus.exception,
}


def read_status(fn: ca.Function) -> tuple[SolveStatus, str, int | None]:
    """What an ``nlpsol`` did in its last call: ``(status, return string, iterations)``.

    ``stats()`` raises for some plugins when they stop without a status string (sqpmethod
    after a failed QP); that is a failed solve, not a crash. IPOPT's "acceptable" level and
    an iteration cap count as truncated; fatrop's ``return_status`` is a number, so its
    ``success`` flag decides.
    """
    try:
        stats = fn.stats()
    except RuntimeError:
        return SolveStatus.failed, "no_status", None
    raw = str(stats.get("return_status", ""))
    iters = stats.get("iter_count")
    iters = int(iters) if iters is not None else None
    if raw in _TRUNCATED:
        return SolveStatus.truncated, raw, iters
    if stats.get("success"):
        return SolveStatus.converged, raw or "success", iters
    unified = str(stats.get("unified_return_status", ""))
    status = _UNIFIED.get(unified, SolveStatus.failed)
    if status is SolveStatus.converged:  # success is False: the flag and the code disagree
        status = SolveStatus.failed
    return status, raw or unified or "unknown", iters


@dataclass
class CasadiConf:
    _target_: str = "mpclab.controllers.casadi.CasadiMPC"
    horizon: int = 10
    dt: float = 0.1
    solver: CasadiSolver = CasadiSolver.ipopt
    qp_solver: QpSolver = QpSolver.qpoases
    sqp_iterations: int = 1
    shooting: Shooting = Shooting.multiple
    collision_distance: float = 0.0
    max_iter: int = 100
    tol: float = 1e-6
    warm_start: bool = True
    max_detections: int = 20
    initial_input: dict[str, float] = field(default_factory=dict)
    terminal_constraint: dict[str, float] = field(default_factory=dict)
    solver_options: dict[str, Any] = field(default_factory=dict)


@component("controller", "casadi", CasadiConf)
class CasadiMPC(Controller):
    """Nonlinear MPC with CasADi (IPOPT, or SQP real-time iteration).

    Parameters
    ----------
    plant, objective
        Injected; every objective term must support CasADi.
    horizon, dt
        Prediction steps and sample time [s].
    solver
        ``ipopt`` (solve to convergence) or ``sqp_rti`` (one QP per step).
    qp_solver
        QP solver of ``sqp_rti``: ``qpoases`` (dense), ``osqp`` or ``qrqp`` (sparse).
    sqp_iterations
        SQP steps per sample of ``sqp_rti`` (fewer if converged first); ignored by IPOPT.
    shooting
        ``multiple`` (states and inputs are variables, the dynamics equality constraints)
        or ``single`` (inputs only, the states their rollout: the NLP is small and dense and
        its QPs have bounds only, unless state bounds or constraints are set).
    collision_distance
        ``R`` [m] of the hard collision constraint on detected points (module docstring);
        0 turns it off.
    max_iter, tol
        IPOPT's iteration limit and tolerance (ignored by ``sqp_rti``).
    warm_start
        Start from the previous solution (primal and multipliers) shifted by one step.
    max_detections
        Detected points the NLP has room for; more are cut to the nearest ones.
    initial_input
        ``{input label: value}`` held over the horizon as the guess of a cold start (others
        0). A non-zero guess moves the first solve off symmetric stationary points, such as
        a robot at rest facing sideways to its goal.
    terminal_constraint
        ``{state label: value}`` imposed on the last predicted state.
    solver_options
        Extra options for ``nlpsol`` (e.g. ``{"ipopt.linear_solver": "ma27"}``).
    """

    def __init__(
        self,
        plant: Plant,
        objective: Objective,
        horizon: int = 10,
        dt: float = 0.1,
        solver: CasadiSolver | str = CasadiSolver.ipopt,
        qp_solver: QpSolver | str = QpSolver.qpoases,
        sqp_iterations: int = 1,
        shooting: Shooting | str = Shooting.multiple,
        collision_distance: float = 0.0,
        max_iter: int = 100,
        tol: float = 1e-6,
        warm_start: bool = True,
        max_detections: int = 20,
        initial_input: Mapping[str, float] | None = None,
        terminal_constraint: Mapping[str, float] | None = None,
        solver_options: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(plant, horizon, dt)
        self.solver = _enum(CasadiSolver, solver, "controller.solver")
        self.qp_solver = _enum(QpSolver, qp_solver, "controller.qp_solver")
        if int(max_iter) < 1:
            raise ConfigError(f"controller.max_iter must be >= 1, got {max_iter}")
        if int(sqp_iterations) < 1:
            raise ConfigError(f"controller.sqp_iterations must be >= 1, got {sqp_iterations}")
        if not float(collision_distance) >= 0:
            raise ConfigError(
                f"controller.collision_distance must be >= 0 (0: off), got {collision_distance}"
            )
        self.sqp_iterations = int(sqp_iterations)
        self.shooting = _enum(Shooting, shooting, "controller.shooting")
        self.collision_distance = float(collision_distance)
        if int(max_detections) < 0:
            raise ConfigError(f"controller.max_detections must be >= 0, got {max_detections}")
        self.max_iter, self.tol = int(max_iter), float(tol)
        self.warm_start = bool(warm_start)
        self.max_detections = int(max_detections)
        self._u_guess = np.zeros(plant.nu)
        for label, value in dict(initial_input or {}).items():
            try:
                self._u_guess[plant.input_index(label)] = float(value)
            except ValueError as exc:
                raise ConfigError(f"controller.initial_input: {exc}") from None
        self._u_guess = plant.clip_input(self._u_guess)
        self.objective = objective
        objective.bind(plant, "casadi")
        self._names = list(objective.terms)
        self._build(dict(terminal_constraint or {}), dict(solver_options or {}))
        self._lam_x: FloatArray | None = None
        self._lam_g: FloatArray | None = None

    # ------------------------------------------------------------------ build once
    def _build(self, terminal: dict[str, float], extra: dict[str, Any]) -> None:
        nx, nu, T, M = self.plant.nx, self.plant.nu, self.horizon, max(self.max_detections, 1)
        U = ca.SX.sym("U", nu, T)
        x0 = ca.SX.sym("x0", nx)
        goal = ca.SX.sym("goal", nx)
        target = ca.SX.sym("target", nx, T + 1)
        det = ca.SX.sym("detections", 2, M)
        mask = ca.SX.sym("mask", M)
        active = ca.SX.sym("active", len(self._names))
        u_prev = ca.SX.sym("u_prev", nu)
        p = TermContext(x0=x0, target=target, u_prev=u_prev, goal=goal, detections=det,
                        mask=mask)
        P = ca.vertcat(x0, goal, ca.vec(target), ca.vec(det), mask, active, u_prev)
        if self.collision_distance > 0:
            radius = ca.SX.sym("radius", M)  # R_i, see the module docstring
            P = ca.vertcat(P, radius)
        g: list[Any] = []  # equalities first, then inequalities (bounds in lbg, ubg)
        if self.shooting is Shooting.multiple:
            X = ca.SX.sym("X", nx, T + 1)
            w = ca.vertcat(ca.vec(X), ca.vec(U))
            g += [X[:, 0] - x0]
            g += [X[:, k + 1] - self.plant.F(X[:, k], U[:, k], self.dt) for k in range(T)]
        else:  # single shooting: the states are the rollout of the inputs
            cols = [x0]
            for k in range(T):
                cols.append(self.plant.F(cols[-1], U[:, k], self.dt))
            X = ca.horzcat(*cols)
            w = ca.vec(U)
        self._plan_fn = ca.Function("plan", [w, P], [X])
        cost = 0
        for j, term in enumerate(self.objective):
            cost += active[j] * term.casadi_cost(X, U, p)
        for i, value in terminal_rows(self.plant, terminal):
            g.append(X[i, T] - value)
        lbg = [np.zeros(sum(int(gi.shape[0]) for gi in g))]
        ubg = [lbg[0]]
        if self.shooting is Shooting.single:  # finite state bounds become constraints
            rows = np.flatnonzero(np.isfinite(self.plant.x_lb) | np.isfinite(self.plant.x_ub))
            for i in rows:
                g.append(X[int(i), 1:].T)
                lbg.append(np.full(T, self.plant.x_lb[i]))
                ubg.append(np.full(T, self.plant.x_ub[i]))
        if self.collision_distance > 0:
            g.append(ca.vec(self._collision(X, det, radius)))
            lbg.append(np.full(M * T, -np.inf))
            ubg.append(np.zeros(M * T))
        nlp = {"x": w, "p": P, "f": cost, "g": ca.vertcat(*g)}
        self._ng = int(nlp["g"].shape[0])
        self._lbg, self._ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._M = M
        name, opts = self._solver_setup(extra)
        with c_stdout_silenced():  # qpOASES prints its banner on construction
            self.solver_fn = ca.nlpsol("mpc", name, nlp, opts)
        ulb = np.tile(self.plant.u_lb[:, None], (1, T)).ravel("F")
        uub = np.tile(self.plant.u_ub[:, None], (1, T)).ravel("F")
        if self.shooting is Shooting.multiple:
            inf = np.inf
            xlb = np.column_stack([np.full(nx, -inf)] + [self.plant.x_lb] * T).ravel("F")
            xub = np.column_stack([np.full(nx, inf)] + [self.plant.x_ub] * T).ravel("F")
            ulb, uub = np.concatenate([xlb, ulb]), np.concatenate([xub, uub])
        self._lbw, self._ubw = ulb, uub

    def _collision(self, X: Any, det: Any, radius: Any) -> Any:
        """``R_i^2 - |p_k - p_i|^2`` ``(M, T)`` over the predicted positions ``k = 1..T``."""
        ix, iy = (self.plant.state_index(s) for s in self.plant.position)
        M, T = det.shape[1], self.horizon
        dx = ca.repmat(X[ix, 1:], M, 1) - ca.repmat(det[0, :].T, 1, T)
        dy = ca.repmat(X[iy, 1:], M, 1) - ca.repmat(det[1, :].T, 1, T)
        return ca.repmat(radius**2, 1, T) - dx**2 - dy**2

    def _solver_setup(self, extra: dict[str, Any]) -> tuple[str, dict[str, Any]]:
        if self.solver is CasadiSolver.ipopt:
            opts: dict[str, Any] = {
                "print_time": False,
                "ipopt.print_level": 0,
                "ipopt.sb": "yes",
                "ipopt.max_iter": self.max_iter,
                "ipopt.tol": self.tol,
            }
            if self.warm_start:
                opts["ipopt.warm_start_init_point"] = "yes"
            name = "ipopt"
        else:
            qp_opts = {
                QpSolver.qpoases: {"printLevel": "none"},
                QpSolver.osqp: {"osqp": {"verbose": False}},
                QpSolver.qrqp: {"print_iter": False, "print_header": False, "print_info": False},
            }[self.qp_solver] | {"error_on_fail": False}
            opts = {
                "print_time": False,
                "print_header": False,
                "print_iteration": False,
                "print_status": False,
                "max_iter": self.sqp_iterations,
                "qpsol": self.qp_solver.value,
                "qpsol_options": qp_opts,
                "convexify_strategy": "eigen-clip",
                "max_iter_eig": 500,  # the default 50 left dense Hessians undecomposed
                "error_on_fail": False,
            }
            name = "sqpmethod"
        opts.update(extra)
        return name, opts

    # ------------------------------------------------------------------ per step
    def reset(self, x0: Any) -> None:
        super().reset(x0)
        self._lam_x = self._lam_g = None

    def _params(self, x: FloatArray, ctx: StepContext) -> FloatArray:
        det, mask = self._pad_detections(x, np.asarray(ctx.detections, dtype=float))
        if ctx.active is None:
            act = np.ones(len(self._names))
        else:
            unknown = set(ctx.active) - set(self._names)
            if unknown:
                raise ValueError(
                    f"active terms {sorted(unknown)} are not in the objective; "
                    f"its terms: {', '.join(self._names)}"
                )
            act = np.array([1.0 if n in ctx.active else 0.0 for n in self._names])
        target = np.asarray(ctx.target, dtype=float)
        parts = [x, np.asarray(ctx.goal, dtype=float), target.T.ravel("F"), det.ravel("F"), mask,
                 act, self.previous_input]
        if self.collision_distance > 0:
            ix, iy = (self.plant.state_index(s) for s in self.plant.position)
            d0 = np.hypot(det[0] - x[ix], det[1] - x[iy])
            parts.append(np.minimum(self.collision_distance, d0) * mask)
        return np.concatenate(parts)

    def _pad_detections(self, x: FloatArray, det: FloatArray) -> tuple[FloatArray, FloatArray]:
        M = self._M
        ix, iy = (self.plant.state_index(s) for s in self.plant.position)
        pos = np.array([x[ix], x[iy]])
        det = det.reshape(-1, 2)
        if len(det) > self.max_detections:  # keep the nearest
            order = np.argsort(np.linalg.norm(det - pos, axis=1))
            det = det[order[: self.max_detections]]
        out = np.tile(pos + 1e3, (M, 1))  # padding far away, masked out anyway
        out[: len(det)] = det
        mask = np.zeros(M)
        mask[: len(det)] = 1.0
        return out.T, mask

    def _initial_guess(self, x: FloatArray) -> FloatArray:
        prev = self.previous_plan
        T = self.horizon
        if prev is None or not self.warm_start:
            U = np.tile(self._u_guess, (T, 1))
            X = self.plant.rollout(x, U, self.dt)
        else:
            X, U = shift(prev.x_pred), shift(prev.u_pred)
            X[0] = x
        if self.shooting is Shooting.single:
            return U.ravel()
        return np.concatenate([X.ravel(), U.ravel()])  # row-major (T+1, nx) == vec of (nx, T+1)

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        args: dict[str, Any] = {
            "x0": self._initial_guess(x),
            "p": self._params(x, ctx),
            "lbx": self._lbw,
            "ubx": self._ubw,
            "lbg": self._lbg,
            "ubg": self._ubg,
        }
        if self.warm_start and self._lam_g is not None and self.previous_plan is not None:
            args["lam_x0"], args["lam_g0"] = self._lam_x, self._lam_g
        sol = self.solver_fn(**args)
        status, raw, iters = read_status(self.solver_fn)
        nu, T = self.plant.nu, self.horizon
        w = np.asarray(sol["x"], dtype=float).ravel()
        if status in (SolveStatus.converged, SolveStatus.truncated) and not (
            np.all(np.isfinite(w)) and self._within_bounds(w)
        ):  # an iterate outside its bounds: an SQP step whose QP failed silently
            status, raw = SolveStatus.failed, f"{raw}:out_of_bounds"
        if status not in (SolveStatus.converged, SolveStatus.truncated):
            self._lam_x = self._lam_g = None
            return self._failed(status, x, raw, iterations=iters)
        self._lam_x = self._shift_lam_x(np.asarray(sol["lam_x"], dtype=float).ravel())
        self._lam_g = np.asarray(sol["lam_g"], dtype=float).ravel()
        X = np.asarray(self._plan_fn(w, args["p"]), dtype=float).T  # (T+1, nx)
        U = w[w.size - nu * T:].reshape(T, nu)
        return ControlStep(
            u=U[0].copy(), x_pred=X, u_pred=U, status=status, cost=float(sol["f"]),
            solver_status=raw, iterations=iters,
        )

    def _within_bounds(self, w: FloatArray, tol: float = 1e-6) -> bool:
        """Whether ``w`` keeps its variable bounds (a QP solved to success always does)."""
        slack = tol * (1.0 + np.abs(w))
        return bool(np.all(w >= self._lbw - slack) and np.all(w <= self._ubw + slack))

    def _shift_lam_x(self, lam: FloatArray) -> FloatArray:
        nx, nu, T = self.plant.nx, self.plant.nu, self.horizon
        lu = shift(lam[lam.size - nu * T:].reshape(T, nu))
        if self.shooting is Shooting.single:
            return lu.ravel()
        lx = shift(lam[: nx * (T + 1)].reshape(T + 1, nx))
        return np.concatenate([lx.ravel(), lu.ravel()])

    def metrics(self, steps: Any) -> dict[str, Any]:
        return {"solver": self.solver.value, "collision_distance": self.collision_distance}


def _enum(cls: type[Enum], value: Any, where: str) -> Any:
    try:
        return cls(value.value if isinstance(value, Enum) else value)
    except ValueError:
        valid = ", ".join(m.value for m in cls)
        raise ConfigError(f"{where}: unknown choice {value!r}; valid: {valid}") from None
