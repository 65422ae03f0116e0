"""CVXPY backend: successive-linearization MPC as one DPP-compliant QP built once.

Per step only parameter values change: the initial state, the LTV model ``(A_k, B_k, c_k)``,
the input bounds and the target. The problem is compiled once (``Problem.is_dpp()`` is
checked at construction), so a solve skips canonicalization. With Clarabel, each solve by
default goes straight from the compiled parameter-to-data map to a persistent Clarabel solver
(:mod:`mpclab.controllers.cvxpy.direct`); ``solve.via: problem`` uses ``Problem.solve``.

``sl: converge`` (default) iterates the linearization to convergence with a trust region
(:mod:`mpclab.controllers.cvxpy.successive_linearization`); the trust region and the input bounds
are one pair of parameters, so the QP does not grow. ``sl: one_pass`` is the study's scheme, one QP
per step about the previous plan shifted, always ``truncated``.

The objective's constraints (``objective.constraints``, :mod:`mpclab.constraints`) enter the
QP by :mod:`mpclab.controllers.cvxpy.constraints`, linearized about the same trajectory as
the dynamics (each iterate's rollout; in ``one_pass`` the previous plan shifted or its
rollout), their per-step data as parameters: still compiled once. A warm start that breaks
one is not cut there as the CasADi backend cuts it (the iteration weighs a rollout by its
violation; the cut stalled runs past a wall that arrive without it). A soft one's slacks
are reported in the summary (``slack_steps``, ``slack_max_m``: the largest distance a plan
gave up, measured on the plan).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from mpclab.config.registry import component
from mpclab.controllers.base import (
    Controller,
    ControlStep,
    FloatArray,
    SolveStatus,
    StepContext,
    input_vector,
    shift,
    terminal_rows,
)
from mpclab.controllers.blocking import Blocking, ControlHorizon
from mpclab.controllers.cvxpy.constraints import QPConstraints, assign
from mpclab.controllers.cvxpy.direct import CompiledQP, DirectClarabel, QPSolution, SolveVia
from mpclab.controllers.cvxpy.successive_linearization import (
    MAX_RADIUS,
    Hessian,
    Point,
    TrustRegionSL,
    model_through,
)
from mpclab.core.errors import ConfigError, parse_choice
from mpclab.core.lazy_import import lazy_import
from mpclab.core.options import group
from mpclab.core.status import Problem
from mpclab.objectives.base import Objective, TermContext
from mpclab.plants.base import Plant

cp = lazy_import("cvxpy")  # about 0.6 s to import: paid only by runs that use it

#: bound given to the QP for an input without one (and no trust region): never active
_FREE = 1e6
log = logging.getLogger("mpclab")
#: dense size [bytes] of the exact-Hessian compile above which a build is announced as long
_BIG_COMPILE = 1e8
class CvxpySolver(StrEnum):
    CLARABEL = "CLARABEL"
    OSQP = "OSQP"


class SlMode(StrEnum):
    #: iterate with a trust region until the step or the predicted cost decrease is below tol
    converge = "converge"
    #: one linearize-and-solve pass per step (the study's scheme): truncated by design
    one_pass = "one_pass"


class Linearization(StrEnum):
    #: the previous solution shifted by one step, first point replaced by the measured state
    shifted_plan = "shifted_plan"
    #: the previous inputs shifted by one step, states simulated from the measured state
    rollout = "rollout"


@dataclass(frozen=True)
class CvxpySolve:
    """How each step's QPs are iterated and solved (``controller.solve``).

    Parameters
    ----------
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
    linearize_about
        ``one_pass``: ``shifted_plan`` or ``rollout`` (``converge`` always linearizes about
        the rollout, whose true cost it needs).
    warm_start
        Passed to the solver (OSQP reuses its factorization and previous solution).
    options
        Extra keyword options for the solver (Clarabel settings by name, ``max_iter``, ...).
    via
        ``auto`` (default: ``direct`` with Clarabel, else ``problem``), ``direct`` (the
        compiled data straight into a persistent Clarabel solver) or ``problem``
        (``Problem.solve`` every step). Both give the same solution.
    """

    tol: float = 1e-6
    max_iterations: int = 20
    trust_radius: float = 0.5
    hessian: Hessian | str = Hessian.exact
    linearize_about: Linearization | str = Linearization.shifted_plan
    warm_start: bool = True
    options: Mapping[str, Any] | None = None
    via: SolveVia | str = SolveVia.auto


@component("controller", "cvxpy", injected=("plant", "objective"))
class CvxpyMPC(Controller):
    """Successive-linearization MPC solved as a convex QP with CVXPY.

    Parameters
    ----------
    plant, objective
        Injected; every objective term must support CVXPY (and CasADi, for ``converge``:
        the true cost of a rollout is evaluated with the terms' CasADi form), and so must
        every constraint (the obstacle distance in modes ``hard`` and ``soft``, linearized).
    horizon, dt
        Prediction steps and sample time [s].
    control_horizon
        The free moves: null (all), an integer ``Nc`` (the last held to the end) or a list
        of block lengths (:mod:`mpclab.controllers.blocking`). The QP's input variable is
        the moves ``V (nu, M)``; the inputs ``U = V S`` (``S`` the blocking, constant).
    solver
        ``CLARABEL`` (default) or ``OSQP``.
    sl
        ``converge`` (iterate to ``solve.tol`` or ``solve.max_iterations``) or ``one_pass``.
    solve
        How each step's QPs are iterated and solved (:class:`CvxpySolve`: ``tol``,
        ``max_iterations``, ``trust_radius``, ``hessian``, ``linearize_about``,
        ``warm_start``, ``options``, ``via``).
    initial_input
        ``{input label: value}`` held over the horizon as the first linearization point
        (others 0). The car at rest with zero steering angle has no first-order steering
        effect; a forward acceleration gives it one.
    terminal_constraint
        ``{state label: value}`` imposed on the last predicted state.
    max_detections
        Detected points the QP has room for (with constraints); more are cut to the nearest.
    """

    def __init__(
        self,
        plant: Plant,
        objective: Objective,
        horizon: int = 10,
        dt: float = 0.1,
        control_horizon: ControlHorizon = None,
        solver: CvxpySolver | str = CvxpySolver.CLARABEL,
        sl: SlMode | str = SlMode.converge,
        solve: CvxpySolve | Mapping[str, Any] = CvxpySolve(),
        initial_input: Mapping[str, float] | None = None,
        terminal_constraint: Mapping[str, float] | None = None,
        max_detections: int = 20,
    ) -> None:
        super().__init__(plant, horizon, dt)
        self.blocking = Blocking.of(control_horizon, self.horizon)
        self.solver = parse_choice(CvxpySolver, solver, "controller.solver").value
        solve = group(CvxpySolve, solve, "controller.solve")
        self.warm_start = bool(solve.warm_start)
        self.sl = parse_choice(SlMode, sl, "controller.sl")
        if int(solve.max_iterations) < 1:
            raise ConfigError(f"controller.solve.max_iterations must be >= 1, "
                              f"got {solve.max_iterations}")
        if not float(solve.tol) > 0:
            raise ConfigError(f"controller.solve.tol must be > 0, got {solve.tol}")
        if not 0 < float(solve.trust_radius) <= MAX_RADIUS:
            raise ConfigError(f"controller.solve.trust_radius must be in "
                              f"(0, {MAX_RADIUS:g}], got {solve.trust_radius}")
        self.max_iterations, self.tol = int(solve.max_iterations), float(solve.tol)
        self.trust_radius = float(solve.trust_radius)
        self.hessian = parse_choice(Hessian, solve.hessian, "controller.solve.hessian")
        #: the QP's objective is the terms' CVXPY form (else the exact quadratic model)
        self._terms_qp = self.sl is SlMode.one_pass or self.hessian is Hessian.gauss_newton
        self.linearize_about = parse_choice(Linearization, solve.linearize_about,
                                            "controller.solve.linearize_about")
        self.solver_options = dict(solve.options or {})
        self._u_guess = input_vector(plant, initial_input, "controller.initial_input")
        self._u_lo, self._u_hi = np.maximum(plant.u_lb, -_FREE), np.minimum(plant.u_ub, _FREE)
        self.objective = objective
        objective.bind(plant, "cvxpy")
        if self.sl is SlMode.converge:
            for term in objective:
                term.require("casadi")
        if int(max_detections) < 0:
            raise ConfigError(f"controller.max_detections must be >= 0, got {max_detections}")
        self.limits = QPConstraints(plant, objective.constraints.values(), self.horizon,
                                    int(max_detections))
        self._terminal = terminal_rows(plant, terminal_constraint)
        if not self._terms_qp:
            self._check_compile_size()
        self._build()
        self.qp = CompiledQP(self.problem, [self.X, self.V], self.solver, self.solver_options,
                             self.warm_start, solve.via)
        self.iteration = None if self.sl is SlMode.one_pass else TrustRegionSL(
            plant, objective, self.blocking, self.dt, self._terminal, self.hessian, self.tol,
            self.max_iterations, self.trust_radius, self._u_lo, self._u_hi,
            self.limits.judge if self.limits else None,
        )

    def _check_compile_size(self) -> None:
        """Refuse, or announce, an exact-Hessian QP too large to compile in reasonable time.

        Its objective has an ``(n, n)`` Hessian parameter (``n = nu M``, ``M`` free moves,
        the horizon unblocked); CVXPY's
        compile makes a dense ``(n + 1, n^2)`` tensor of it (``toarray`` in its quadratic
        coefficient extraction), and several copies: 3.8 GB resident and still building after
        3 minutes at horizon 200 (0.5 GB dense), on the car.
        """
        n = self.plant.nu * self.blocking.n_moves
        dense = 8.0 * (n + 1) * n * n
        try:
            memory = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
        except (ValueError, OSError, AttributeError):  # not on this platform
            memory = float("inf")
        what = (f"controller.horizon={self.horizon} with controller.hessian=exact: CVXPY's "
                f"compile densifies a ({n + 1} x {n * n}) tensor ({dense / 1e9:.3g} GB)")
        fixes = ("a shorter horizon, controller.hessian=gauss_newton or controller=casadi "
                 "poses the problem without it")
        if 8 * dense > memory:
            raise ConfigError(f"{what} and needs several times that; this machine has "
                              f"{memory / 1e9:.3g} GB. {fixes[0].upper()}{fixes[1:]}")
        if dense > _BIG_COMPILE:
            log.warning("%s: building may take minutes and several times that memory; %s",
                        what, fixes)

    def _build(self) -> None:
        nx, nu, T, M = self.plant.nx, self.plant.nu, self.horizon, self.blocking.n_moves
        self.X = X = cp.Variable((nx, T + 1), name="X")
        #: the free moves; the inputs are ``U = V S`` (held within each block)
        self.V = V = cp.Variable((nu, M), name="V")
        U = V if self.blocking.free else V @ self.blocking.matrix().T
        self.p_x0 = cp.Parameter(nx, name="x0")
        # the whole LTV model in one parameter, columns [A_0..A_T-1 | B_0..B_T-1 | c_0..c_T-1]:
        # one value update per linearization instead of 2T+1
        self.p_model = model = cp.Parameter((nx, T * (nx + nu + 1)), name="model")
        a0, c0 = T * nx, T * (nx + nu)
        self.p_target = cp.Parameter((nx, T + 1), name="target")
        # bounds of the moves, intersected with the trust region around Vbar in `converge`
        self.p_u_lo = cp.Parameter((nu, M), name="u_lo")
        self.p_u_hi = cp.Parameter((nu, M), name="u_hi")
        cons = [X[:, 0] == self.p_x0]
        cons += [
            X[:, k + 1]
            == model[:, k * nx : (k + 1) * nx] @ X[:, k]
            + model[:, a0 + k * nu : a0 + (k + 1) * nu] @ U[:, k]
            + model[:, c0 + k]
            for k in range(T)
        ]
        cons += [V >= self.p_u_lo, V <= self.p_u_hi]
        cons += _box(X[:, 1:], self.plant.x_lb, self.plant.x_ub)
        cons += [X[i, T] == value for i, value in self._terminal]
        self.p_u_prev = cp.Parameter(nu, name="u_prev")
        ctx = TermContext(x0=self.p_x0, target=self.p_target, u_prev=self.p_u_prev)
        rows, penalty = self.limits.rows(X, ctx)
        cons += rows
        if self._terms_qp:
            cost = sum(term.cvxpy_cost(X, U, ctx) for term in self.objective)
        else:  # g'v + |L v - L vbar|^2 / 2: the model up to a constant (L'L: clipped Hessian)
            n = nu * M
            self.p_grad = cp.Parameter(n, name="grad")
            self.p_L = cp.Parameter((n, n), name="L")
            self.p_Lu = cp.Parameter(n, name="L_ubar")
            u = cp.vec(V, order="F")
            cost = self.p_grad @ u + 0.5 * cp.sum_squares(self.p_L @ u - self.p_Lu)
        self.problem = cp.Problem(cp.Minimize(cost + penalty), cons)
        if not self.problem.is_dpp():
            raise ConfigError(
                "the CVXPY problem is not DPP-compliant, so it would be recompiled every step; "
                "check that every objective term and constraint is affine in its parameters"
            )
        # compile now (canonicalization, the parameter-to-data map), not in the first step
        for param in self.problem.parameters():
            param.value = np.zeros(param.shape)
        self.problem.get_problem_data(self.solver)

    @property
    def direct(self) -> DirectClarabel | None:
        """The direct Clarabel path, or None when solving through ``Problem.solve``."""
        return self.qp.direct

    def reset(self, x0: Any) -> None:
        """Forget the previous plan and anything the solver keeps from the last run (its
        warm start, the persistent Clarabel solver), so a reused controller repeats a run."""
        super().reset(x0)
        self.qp.reset()
        self.limits.log.reset()

    def _guess(self) -> FloatArray:
        """The first linearization moves ``(M, nu)``: the previous plan shifted and
        re-blocked, or ``initial_input`` held."""
        prev = self.previous_plan
        if prev is None:
            return np.tile(self._u_guess, (self.blocking.n_moves, 1))
        return self.blocking.shift(prev.u_pred)

    def _set_model(self, A: FloatArray, B: FloatArray, c: FloatArray) -> None:
        nx = self.plant.nx
        assign(self.p_model, np.concatenate(
            [A.transpose(1, 0, 2).reshape(nx, -1), B.transpose(1, 0, 2).reshape(nx, -1), c.T],
            axis=1,
        ))

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        assign(self.p_x0, x)
        assign(self.p_target, ctx.target.T)
        assign(self.p_u_prev, self.previous_input)
        if self.limits:
            self.limits.at_step(x, ctx.detections)
        step = self._one_pass(x) if self.sl is SlMode.one_pass else self._converge(x, ctx)
        if self.limits and step.ok:
            self.limits.record(step.x_pred)
        return step

    # ------------------------------------------------------------------ one pass
    def _linearization_points(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``one_pass``: the states and inputs ``(T+1, nx)``, ``(T, nu)`` linearized about."""
        Ubar = self.blocking.expand(self._guess())
        if self.previous_plan is None or self.linearize_about is Linearization.rollout:
            return self.plant.rollout(x, Ubar, self.dt), Ubar
        Xbar = shift(self.previous_plan.x_pred).copy()
        Xbar[0] = x
        return Xbar, Ubar

    def _one_pass(self, x: FloatArray) -> ControlStep:
        Xbar, Ubar = self._linearization_points(x)
        self._set_model(*self.plant.linearize_trajectory(Xbar[:-1], Ubar, self.dt))
        if self.limits:
            self.limits.linearize(Xbar)
        M = self.blocking.n_moves
        assign(self.p_u_lo, np.tile(self._u_lo[:, None], (1, M)))
        assign(self.p_u_hi, np.tile(self._u_hi[:, None], (1, M)))
        sol = self.qp.solve()
        if sol.values is None:
            return self._failed(sol.status, x, sol.raw, sol.message, sol.iterations)
        Xv, Uv = sol.values[0], self.blocking.expand(sol.values[1].T).T
        # one linearize-and-solve pass: the QP converged, the linearization was not iterated
        return ControlStep(
            u=Uv[:, 0].copy(), x_pred=Xv.T.copy(), u_pred=Uv.T.copy(),
            status=SolveStatus.truncated, cost=sol.objective, solver_status=sol.raw,
            iterations=1, info={"qp_iterations": sol.iterations},
        )

    # ------------------------------------------------------------------ converge
    def _converge(self, x: FloatArray, ctx: StepContext) -> ControlStep:
        out = self.iteration.run(x, self._guess(), ctx.target.T, self.previous_input,
                                 self._trust_region_qp)
        if out.failure is not None:
            sol = out.failure
            return self._failed(sol.status, x, sol.raw, sol.message, out.iterations)
        pt = out.point
        U = self.blocking.expand(pt.U)
        return ControlStep(
            u=U[0].copy(), x_pred=pt.X, u_pred=U, status=out.status,
            cost=pt.cost + pt.penalty, solver_status=out.raw, iterations=out.iterations,
            info={"qp_iterations": out.qp_iterations, "trust_radius": out.radius},
        )

    # ------------------------------------------------------------------ results
    @property
    def solved_problem(self) -> Problem:
        """``nonlinear`` when the linearization is iterated to convergence (a converged step
        is a stationary point of the nonlinear OCP), ``linearized`` for one pass."""
        return Problem.nonlinear if self.sl is SlMode.converge else Problem.linearized

    def metrics(self, steps: Any) -> dict[str, Any]:
        """The solver and the linearization scheme; with constraints, theirs and their
        slacks."""
        return {"solver": self.solver, "sl": self.sl.value,
                **(self.limits.metrics() if self.limits else {})}

    def _trust_region_qp(self, bar: Point, r: float, through: Point | None = None,
                         ) -> QPSolution:
        """The QP linearized about ``bar`` with ``|V - bar.U| <= r`` (in half input ranges);
        ``through``: its dynamics model moved through that rollout, the constraints
        linearized about it (a second-order correction,
        :mod:`~mpclab.controllers.cvxpy.successive_linearization`)."""
        assign(self.p_model, bar.model if through is None else
               model_through(bar.model, through.X, self.blocking.expand(through.U)))
        if self.limits:
            self.limits.linearize((through or bar).X)
        if bar.grad is not None:
            assign(self.p_grad, bar.grad)
            assign(self.p_L, bar.L)
            assign(self.p_Lu, bar.L @ bar.U.ravel())
        scale = self.iteration.scale
        assign(self.p_u_lo, np.maximum(self._u_lo, bar.U - r * scale).T)
        assign(self.p_u_hi, np.minimum(self._u_hi, bar.U + r * scale).T)
        return self.qp.solve()


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
