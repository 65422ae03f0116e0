"""CVXPY backend: successive-linearization MPC as one DPP-compliant QP built once.

Per step only parameter values change: the initial state, the LTV model ``(A_k, B_k, c_k)``
along the previous plan shifted by one step, and the target. The problem is compiled once
(``Problem.is_dpp()`` is checked at construction), so a solve skips canonicalization. With
Clarabel, each step by default goes straight from the compiled parameter-to-data map to a
persistent Clarabel solver (:mod:`mpclab.controllers.cvxpy_direct`), skipping
``Problem.solve``'s fixed per-call cost; ``solve_via: problem`` uses ``Problem.solve``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

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


class CvxpySolver(StrEnum):
    CLARABEL = "CLARABEL"
    OSQP = "OSQP"


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
    iterations: int = 1
    linearize_about: Linearization = Linearization.shifted_plan
    terminal_constraint: dict[str, float] = field(default_factory=dict)
    solver_options: dict[str, Any] = field(default_factory=dict)
    solve_via: SolveVia = SolveVia.auto


@component("controller", "cvxpy", CvxpyConf)
class CvxpyMPC(Controller):
    """Successive-linearization MPC solved as a convex QP with CVXPY.

    Parameters
    ----------
    plant, objective
        Injected; every objective term must support CVXPY.
    horizon, dt
        Prediction steps and sample time [s].
    solver
        ``CLARABEL`` (default) or ``OSQP``.
    warm_start
        Passed to the solver (OSQP reuses its factorization and previous solution).
    iterations
        Linearize-and-solve passes per step (1: real-time iteration).
    linearize_about
        ``shifted_plan`` or ``rollout``.
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
        iterations: int = 1,
        linearize_about: Linearization | str = Linearization.shifted_plan,
        terminal_constraint: Mapping[str, float] | None = None,
        solver_options: Mapping[str, Any] | None = None,
        solve_via: SolveVia | str = SolveVia.auto,
    ) -> None:
        super().__init__(plant, horizon, dt)
        self.solver = CvxpySolver(solver).value
        self.warm_start = bool(warm_start)
        if int(iterations) < 1:
            raise ConfigError(f"controller.iterations must be >= 1, got {iterations}")
        self.iterations = int(iterations)
        self.linearize_about = Linearization(linearize_about)
        self.solver_options = dict(solver_options or {})
        self.objective = objective
        objective.bind(plant, "cvxpy")
        self._build(dict(terminal_constraint or {}))
        self.qp = CompiledQP(self.problem, [self.X, self.U], self.solver, self.solver_options,
                             self.warm_start, solve_via)

    def _build(self, terminal: dict[str, float]) -> None:
        nx, nu, T = self.plant.nx, self.plant.nu, self.horizon
        self.X = X = cp.Variable((nx, T + 1), name="X")
        self.U = U = cp.Variable((nu, T), name="U")
        self.p_x0 = cp.Parameter(nx, name="x0")
        # the whole LTV model in one parameter, columns [A_0..A_T-1 | B_0..B_T-1 | c_0..c_T-1]:
        # one value update per step instead of 2T+1 (each update is validated by CVXPY)
        self.p_model = M = cp.Parameter((nx, T * (nx + nu + 1)), name="model")
        a0, c0 = T * nx, T * (nx + nu)
        self.p_target = cp.Parameter((nx, T + 1), name="target")
        cons = [X[:, 0] == self.p_x0]
        cons += [
            X[:, k + 1]
            == M[:, k * nx : (k + 1) * nx] @ X[:, k]
            + M[:, a0 + k * nu : a0 + (k + 1) * nu] @ U[:, k]
            + M[:, c0 + k]
            for k in range(T)
        ]
        cons += _box(U, self.plant.u_lb, self.plant.u_ub)
        cons += _box(X[:, 1:], self.plant.x_lb, self.plant.x_ub)
        cons += [X[i, T] == value for i, value in terminal_rows(self.plant, terminal)]
        self.p_u_prev = cp.Parameter(nu, name="u_prev")
        ctx = TermContext(x0=self.p_x0, target=self.p_target, u_prev=self.p_u_prev)
        cost = sum(term.cvxpy_cost(X, U, ctx) for term in self.objective)
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

    @property
    def direct(self) -> DirectClarabel | None:
        """The direct Clarabel path, or None when solving through ``Problem.solve``."""
        return self.qp.direct

    def reset(self, x0: Any) -> None:
        """Forget the previous plan and anything the solver keeps from the last run (its
        warm start, the persistent Clarabel solver), so a reused controller repeats a run."""
        super().reset(x0)
        self.qp.reset()

    def _linearization_points(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        prev = self.previous_plan
        if prev is None:
            U = np.tile(self.plant.clip_input(np.zeros(self.plant.nu)), (self.horizon, 1))
            return self.plant.rollout(x, U, self.dt)[:-1], U
        U = shift(prev.u_pred)
        if self.linearize_about is Linearization.rollout:
            return self.plant.rollout(x, U, self.dt)[:-1], U
        X = shift(prev.x_pred)[:-1].copy()
        X[0] = x
        return X, U

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        Xbar, Ubar = self._linearization_points(x)
        self.p_x0.value = x
        self.p_target.value = ctx.target.T
        self.p_u_prev.value = self.previous_input
        for _ in range(self.iterations):
            A, B, c = self.plant.linearize_trajectory(Xbar, Ubar, self.dt)
            nx = self.plant.nx
            self.p_model.value = np.concatenate(
                [A.transpose(1, 0, 2).reshape(nx, -1), B.transpose(1, 0, 2).reshape(nx, -1), c.T],
                axis=1,
            )
            sol = self.qp.solve()
            if sol.values is None:
                return self._failed(sol.status, x, sol.raw, sol.message, sol.iterations)
            Xv, Uv = sol.values
            Xbar, Ubar = Xv.T[:-1], Uv.T
        # a fixed number of linearize-and-solve passes: the QP converged, the successive
        # linearization was not iterated to convergence
        return ControlStep(
            u=Uv[:, 0].copy(), x_pred=Xv.T.copy(), u_pred=Uv.T.copy(),
            status=SolveStatus.truncated, cost=sol.objective, solver_status=sol.raw,
            iterations=sol.iterations,
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
