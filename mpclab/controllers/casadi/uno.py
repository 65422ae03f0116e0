"""CasADi backend solved by Uno: the extension guide's example backend (docs/extending.md).

It reuses the CasADi backend's OCP (:func:`~mpclab.controllers.casadi.ocp.build_ocp`:
multiple shooting over the plant's RK4 step, the objective's CasADi terms, named parameters)
and hands it to CasADi's ``uno`` plugin, the unified NLP solver of Vanaret and Leyffer:
``preset: filtersqp`` (trust-region filter SQP) or ``ipopt`` (its interior point). Obstacle
free: the NLP has no room for detected points (``max_detections = 0``). A control horizon
blocks the moves as every backend does (:mod:`mpclab.controllers.blocking`): the NLP's
inputs are the free moves.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np

from mpclab.config.registry import component
from mpclab.controllers.base import (
    USABLE,
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
from mpclab.controllers.casadi.ocp import Shooting, build_ocp
from mpclab.controllers.casadi.solvers import read_status
from mpclab.core.errors import ConfigError, parse_choice
from mpclab.core.status import Problem
from mpclab.objectives.base import Objective
from mpclab.plants.base import Plant

#: Uno's return string for a point that minimizes the constraint violation (no feasible one)
_INFEASIBLE = "Converged with infeasible stationary point"


class UnoPreset(StrEnum):
    filtersqp = "filtersqp"
    ipopt = "ipopt"


@component("controller", "casadi_uno", injected=("plant", "objective"))
class UnoMPC(Controller):
    """Nonlinear MPC on the CasADi backend's OCP, solved to convergence by Uno.

    Parameters
    ----------
    plant, objective
        Injected; every objective term must support CasADi.
    horizon, dt
        Prediction steps and sample time [s].
    control_horizon
        The free moves: null (all), an integer ``Nc`` (the last held to the end) or a list
        of block lengths (:mod:`mpclab.controllers.blocking`).
    preset
        Uno's strategy: ``filtersqp`` or ``ipopt``.
    max_iter, tol
        Uno's iteration limit (a capped solve is ``truncated``) and its tolerance.
    initial_input
        ``{input label: value}`` held over the horizon as the first guess (others 0); later
        guesses are the previous plan shifted by one step.
    terminal_constraint
        ``{state label: value}`` imposed on the last predicted state.
    """

    #: the NLP of the plant's own model, solved to Uno's tolerance
    solved_problem = Problem.nonlinear

    def __init__(
        self, plant: Plant, objective: Objective, horizon: int = 10, dt: float = 0.1,
        control_horizon: ControlHorizon = None,
        preset: UnoPreset | str = UnoPreset.filtersqp, max_iter: int = 100, tol: float = 1e-6,
        initial_input: Mapping[str, float] | None = None,
        terminal_constraint: Mapping[str, float] | None = None,
    ) -> None:
        super().__init__(plant, horizon, dt)
        self.blocking = Blocking.of(control_horizon, self.horizon)
        self.preset = parse_choice(UnoPreset, preset, "controller.preset")
        if int(max_iter) < 1:
            raise ConfigError(f"controller.max_iter must be >= 1, got {max_iter}")
        objective.bind(plant, "casadi")
        if objective.constraints:
            raise ConfigError(
                f"controller=casadi_uno has no room for detected points, so it cannot take "
                f"objective.constraints ({', '.join(objective.constraints)}); use "
                "controller=casadi")
        self._names = list(objective.terms)
        self._u_guess = input_vector(plant, initial_input, "controller.initial_input")
        terminal = terminal_rows(plant, terminal_constraint)
        self.ocp = build_ocp(plant, objective, self._names, self.horizon, self.dt,
                             Shooting.multiple, 0, (), terminal, self.blocking)
        self.solver = ca.nlpsol("mpc", "uno", self.ocp.nlp, {"print_time": False, "uno": {
            "preset": self.preset.value, "logger": "SILENT", "print_solution": False,
            "max_iterations": int(max_iter), "primal_tolerance": float(tol),
            "dual_tolerance": float(tol)}})

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        if len(ctx.detections):  # an exception: recorded, and the step falls back
            raise ValueError("casadi_uno has no room for detected points; use controller=casadi")
        prev, ocp, T = self.previous_plan, self.ocp, self.horizon
        if prev is None or prev.fallback:
            U = np.tile(self._u_guess, (T, 1))
            X = self.plant.rollout(x, U, self.dt)
        else:
            X, U = shift(prev.x_pred), shift(prev.u_pred)
        w0 = np.zeros(ocp.lbw.size)
        w0[ocp.x_idx], w0[ocp.u_idx] = X, self.blocking.reblock(U)  # the moves
        w0[ocp.x_idx[0]] = x
        active = [1.0 if ctx.active is None or n in ctx.active else 0.0 for n in self._names]
        p = ocp.params.pack(
            x0=x, goal=ctx.goal, target=np.asarray(ctx.target).T, detections=np.zeros((2, 1)),
            mask=np.zeros(1), active=active, u_prev=self.previous_input)
        sol = self.solver(x0=w0, p=p, lbx=ocp.lbw, ubx=ocp.ubw, lbg=ocp.lbg, ubg=ocp.ubg)
        status, raw, iters = read_status(self.solver)
        if raw == _INFEASIBLE:
            status = SolveStatus.infeasible
        if status not in USABLE:
            return self._failed(status, x, raw, iterations=iters)
        w = sol["x"].full().ravel()
        U = self.blocking.expand(w[ocp.u_idx])
        return ControlStep(u=U[0], x_pred=w[ocp.x_idx], u_pred=U,
                           status=status, cost=float(sol["f"]), solver_status=raw,
                           iterations=iters)

    def metrics(self, steps: Any) -> dict[str, Any]:
        return {"solver": f"uno_{self.preset.value}"}
