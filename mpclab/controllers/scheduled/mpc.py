"""Gain-scheduled multiple linear MPC (Study C): one condensed QP per operating point.

At every operating point of the grid (the study: heading x speed, other states and inputs at
their nominal values) the plant's own discrete step is linearized **with its affine offset**,
``x+ = A x + B u + c``, and the MPC's condensed QP is precomputed: the Hessian ``H`` and the
maps that give the gradient from the state and the previewed reference (see
:mod:`mpclab.controllers.scheduled.dense_qp`). Per step only ``g = Kx x + kc - Kr ref`` is formed
and the QP solved; with two inputs and control horizon 1 that is the exact closed form
:func:`~mpclab.controllers.scheduled.dense_qp.box_qp_2`.

Scheduling ``mode``:

* ``switched``: the nearest operating point's MPC (the study's Multiple MPC Controller),
  optionally with hysteresis;
* ``interpolated``: the predictions of the neighbouring operating points' models blended
  with multilinear weights in the scheduling states (heading periodic); at a grid point this
  is that point's model;
* ``adaptive``: relinearize at the current state and the last input every step (the study's
  adaptive MPC); the model is exact at the current state.

The heading is periodic: a model linearized at ``theta_i`` is used at ``theta_i + 2 pi k``
(nearest ``k``) by shifting state, reference and prediction by ``2 pi k``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from types import MappingProxyType
from typing import Any

import numpy as np
import pandas as pd

from mpclab.codegen.loader import Precision, ScheduledLibrary
from mpclab.config.registry import component
from mpclab.controllers.base import (
    Controller,
    ControlStep,
    FloatArray,
    SolveStatus,
    StepContext,
)
from mpclab.controllers.blocking import Blocking, ControlHorizon
from mpclab.controllers.cvxpy.direct import SolveVia
from mpclab.controllers.scheduled.dense_qp import (
    CvxpyBoxQP,
    TrackingQP,
    box_qp_2,
    box_qp_active_set,
    condenser,
)
from mpclab.controllers.scheduled.generated_c import M4_COLUMN, ScheduledSIL
from mpclab.controllers.scheduled.grid import TWO_PI, OperatingGrid
from mpclab.controllers.scheduled.models import OpModel, switch_metrics, tracking_weights
from mpclab.core.errors import ConfigError, parse_choice
from mpclab.core.options import group
from mpclab.core.status import Problem
from mpclab.objectives.base import Objective
from mpclab.plants.base import Plant
from mpclab.record import files as record


class ScheduleMode(StrEnum):
    switched = "switched"
    interpolated = "interpolated"
    adaptive = "adaptive"


class ScheduledQpSolver(StrEnum):
    #: closed form for 2 free variables, else the active-set method
    auto = "auto"
    closed_form = "closed_form"
    active_set = "active_set"
    #: through CVXPY (for comparison)
    CLARABEL = "CLARABEL"
    OSQP = "OSQP"


#: the default grid: heading every quarter turn, speed 1 and 2 m/s
OPERATING_POINTS: Mapping[str, Sequence[float]] = MappingProxyType(
    {"theta": (0.0, math.pi / 2, math.pi, -math.pi / 2), "V": (1.0, 2.0)})


@dataclass(frozen=True)
class Schedule:
    """Which linear model predicts where (``controller.schedule``).

    Parameters
    ----------
    mode
        ``switched`` (the nearest operating point's model), ``interpolated`` (the models
        blended by distance) or ``adaptive`` (the plant linearized at the state).
    operating_points
        ``{state label: values}``; the grid is their product.
    nominal_state
        Values of the other states at the operating points (default 0); inputs are 0.
    hysteresis
        ``{scheduling label: margin}`` for ``switched`` mode.
    """

    mode: ScheduleMode | str = ScheduleMode.switched
    operating_points: Mapping[str, Sequence[float]] = field(
        default_factory=lambda: OPERATING_POINTS)
    nominal_state: Mapping[str, float] | None = None
    hysteresis: Mapping[str, float] | None = None


@dataclass(frozen=True)
class ScheduledSolve:
    """How a CVXPY solver is called (``controller.solve``; ``solver=CLARABEL`` or ``OSQP``).

    Parameters
    ----------
    options
        Keyword options for the solver.
    via
        For CLARABEL: ``auto``/``direct`` (the compiled data straight into a persistent
        Clarabel solver) or ``problem`` (``Problem.solve`` every step).
    """

    options: Mapping[str, Any] | None = None
    via: SolveVia | str = SolveVia.auto


@component("controller", "scheduled", injected=("plant", "objective"))
class ScheduledMPC(Controller):
    """Multiple linear MPC over a grid of operating points (switched, interpolated, adaptive).

    Parameters
    ----------
    plant, objective
        Injected; the objective's terms must be :class:`QuadraticTracking` (their weights are
        summed into one diagonal state, terminal and input weight).
    schedule
        The operating points and how the model is picked (:class:`Schedule`: ``mode``,
        ``operating_points``, ``nominal_state``, ``hysteresis``).
    horizon
        Prediction steps ``T``.
    control_horizon
        The free moves: an integer ``M`` (the last held to the end), a list of block lengths
        or null (every move free); :mod:`mpclab.controllers.blocking`.
    dt
        Sample time [s]; the models are the plant's step over ``dt``.
    solver
        ``auto`` (closed form when there are 2 free variables, else active set),
        ``closed_form``, ``active_set``, or ``CLARABEL`` / ``OSQP`` through CVXPY.
    solve
        For a CVXPY solver (:class:`ScheduledSolve`): its keyword ``options``, and ``via``.
    codegen
        Step through the generated C of this controller (compiled with the machine's C
        compiler, cached; :mod:`mpclab.controllers.scheduled.generated_c`) instead of Python:
        switched mode without hysteresis, solver ``auto``, ``closed_form`` or ``active_set``.
    codegen_precision
        ``double`` or ``single`` (``float``, as the Cortex-M4F's FPU computes): the generated
        C's arithmetic in the loop, and the build whose time per step on the F401RE
        ``sim.latency=modelled`` (``sim=embedded_m4``) applies (:meth:`board_time_model`).
    """

    log_columns = ("op",)

    def __init__(
        self,
        plant: Plant,
        objective: Objective,
        schedule: Schedule | Mapping[str, Any] = Schedule(),
        horizon: int = 32,
        control_horizon: ControlHorizon = 1,
        dt: float = 0.02,
        solver: ScheduledQpSolver | str = ScheduledQpSolver.auto,
        solve: ScheduledSolve | Mapping[str, Any] = ScheduledSolve(),
        codegen: bool = False,
        codegen_precision: Precision | str = Precision.double,
    ) -> None:
        super().__init__(plant, horizon, dt)
        schedule = group(Schedule, schedule, "controller.schedule")
        solved = group(ScheduledSolve, solve, "controller.solve")
        self.mode = parse_choice(ScheduleMode, schedule.mode, "controller.schedule.mode")
        self.solver = parse_choice(ScheduledQpSolver, solver, "controller.solver")
        T, nx, nu = self.horizon, plant.nx, plant.nu
        self._nx, self._nu = nx, nu
        self.blocking = Blocking.of(control_horizon, T)
        self.control_horizon = M = self.blocking.n_moves
        self.nz = nz = M * nu
        if self.solver is ScheduledQpSolver.closed_form and nz != 2:
            raise ConfigError(
                f"controller.solver=closed_form needs 2 free variables (2 inputs, control "
                f"horizon 1); this problem has {nz}: use auto or active_set"
            )
        self.qp = TrackingQP(*tracking_weights(objective, plant), self.blocking)
        self.lb = np.tile(plant.u_lb, M)
        self.ub = np.tile(plant.u_ub, M)
        self._bounds = tuple(float(v) for pair in zip(self.lb, self.ub, strict=True) for v in pair)
        self._E = self.blocking.matrix(nu)
        self._condense = condenser(nx, nu, self.blocking)
        self.grid = OperatingGrid(
            schedule.operating_points or OPERATING_POINTS, plant.state_index,
            plant.heading, schedule.hysteresis,
        )
        self.heading_index = plant.state_index(plant.heading) if plant.heading else None
        xbar = np.zeros(nx)
        for label, v in (schedule.nominal_state or {}).items():
            try:
                xbar[plant.state_index(label)] = float(v)
            except ValueError as exc:
                raise ConfigError(f"controller.schedule.nominal_state: {exc}") from None
        self.op_states = []
        for point in self.grid.points():
            x = xbar.copy()
            for label, v in point.items():
                x[plant.state_index(label)] = v
            self.op_states.append(x)
        self._precompute()
        self._cvx = (
            CvxpyBoxQP(self.lb, self.ub, self.solver.value, dict(solved.options or {}),
                       solved.via)
            if self.solver in (ScheduledQpSolver.CLARABEL, ScheduledQpSolver.OSQP) else None
        )
        self._active: int | None = None
        self.codegen = bool(codegen)
        self.codegen_precision = parse_choice(Precision, codegen_precision,
                                              "controller.codegen_precision")
        self._sil = ScheduledSIL.of(self) if self.codegen else None
        if self._sil is not None:  # the modelled board time, when the loop asks for it
            self.log_columns = (*type(self).log_columns, M4_COLUMN)

    @property
    def c_library(self) -> ScheduledLibrary | None:
        """The compiled generated C it steps through (``codegen=true``), else None."""
        return self._sil.library if self._sil is not None else None

    # ------------------------------------------------------------------ construction
    def predictor(self, x: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Condensed prediction ``(Px, Pu, pc)`` of the plant linearized at ``(x, u)``."""
        A, B, c = self.plant.F_lin(x, u, self.dt)
        Px, Pu, pc = self._condense(A, B, c)
        return np.asarray(Px), np.asarray(Pu), np.asarray(pc).ravel()

    def _precompute(self) -> None:
        """Per operating point: predictor, Hessian, gradient maps and the 2 pi shift terms.

        The per-step products are stacked so that a step is two matrix-vector products:
        ``g = K [x; ref; 1]`` and ``X = P [x; z; 1]``.
        """
        nx, T, u0 = self.plant.nx, self.horizon, np.zeros(self.plant.nu)
        e_theta = np.zeros((T + 1) * nx)
        th = self.heading_index
        if th is not None:
            e_theta[th::nx] = 1.0
        self.models = []
        for op, x in enumerate(self.op_states):
            Px, Pu, pc = self.predictor(x, u0)
            H = self.qp.hessian(Pu)
            Kx, kc, Kr = self.qp.gradient_maps(Px, Pu, pc)
            # used at theta_op + 2 pi k, the model shifts state, reference and prediction by
            # 2 pi k in theta: g and X gain k times these
            g_shift = TWO_PI * (Kr @ e_theta - (Kx[:, th] if th is not None else 0.0))
            x_shift = TWO_PI * (e_theta - (Px[:, th] if th is not None else 0.0))
            self.models.append(OpModel(
                Px, Pu, pc, H, Kx, kc, Kr, g_shift, x_shift,
                K=np.hstack([Kx, -Kr, kc[:, None]]), P=np.hstack([Px, Pu, pc[:, None]]),
                h=(float(H[0, 0]), float(H[0, 1]), float(H[-1, -1])),
                theta=self.grid.heading(op) or 0.0,
            ))
        n_ref = (T + 1) * nx
        self._v = np.zeros(nx + n_ref + 1)  # [x; ref; 1]
        self._v[-1] = 1.0
        self._w = np.zeros(nx + self.nz + 1)  # [x; z; 1]
        self._w[-1] = 1.0
        self._wq = self.qp.w
        self._hysteresis = any(self.grid.hysteresis)
        self._r_diag = np.diag(self.qp.R).tolist()  # E' R E is diagonal: blocked inputs
        self.uses_closed_form = self.nz == 2 and self.solver in (
            ScheduledQpSolver.auto, ScheduledQpSolver.closed_form)

    # ------------------------------------------------------------------ per step
    def reset(self, x0: FloatArray) -> None:
        super().reset(x0)
        self._active = None
        if self._cvx is not None:
            self._cvx.reset()

    def _solve(self, t: float, x: FloatArray, ctx: StepContext) -> ControlStep:
        ref = ctx.target.ravel()
        if self.mode is not ScheduleMode.switched:
            return self._solve_model(x, ref)
        if self._sil is not None:
            return self._solve_c(x, ref)
        xl = x.tolist()
        op = self._active = (
            self.grid.switched(xl, self._active) if self._hysteresis else self.grid.nearest(xl)
        )
        m = self.models[op]
        nx = self._nx
        v, w = self._v, self._w
        v[:nx] = x
        v[nx:-1] = ref
        w[:nx] = x
        th = self.heading_index
        k = round((xl[th] - m.theta) / TWO_PI) if th is not None else 0
        if self.uses_closed_form:  # plain floats: no array overhead for two numbers
            g0, g1 = m.K.dot(v).tolist()
            if k:
                g0, g1 = g0 + k * m.gs[0], g1 + k * m.gs[1]
            z0, z1 = box_qp_2(*m.h, g0, g1, *self._bounds)
            w[nx], w[nx + 1] = z0, z1
            u_cost = self._r_diag[0] * z0 * z0 + self._r_diag[1] * z1 * z1
        else:
            g = m.K.dot(v)
            if k:
                g += k * m.g_shift
            z, status, raw = self._qp(m.H, g)
            if z is None:
                return self._failed_at(status, x, raw, op)
            w[nx:-1] = z
            u_cost = float(np.dot(self._r_diag, z * z))
        X = m.P.dot(w)
        if k:
            X += k * m.x_shift
        return self._result(X, w[nx:-1].copy(), ref, op, u_cost)

    def _solve_c(self, x: FloatArray, ref: FloatArray) -> ControlStep:
        """The step by the generated C (its status and iteration count kept)."""
        z, op, X, status, word, iters = self._sil.step(x, ref)
        self._active = op
        u_cost = sum(r * v * v for r, v in zip(self._r_diag, z.tolist(), strict=True))
        return self._result(X, z, ref, op, u_cost, status, word, iters)

    def _solve_model(self, x: FloatArray, ref: FloatArray) -> ControlStep:
        """Interpolated or adaptive mode: a predictor built for this state, then the QP."""
        op = self.grid.nearest(x)
        Px, Pu, pc = self._model(x)
        z, status, raw = self._qp(self.qp.hessian(Pu), self.qp.gradient(Px, Pu, pc, x, ref))
        if z is None:
            return self._failed_at(status, x, raw, op)
        return self._result(Px @ x + Pu @ z + pc, z, ref, op, float(np.dot(self._r_diag, z * z)))

    def _result(
        self, X: FloatArray, z: FloatArray, ref: FloatArray, op: int, u_cost: float,
        status: SolveStatus = SolveStatus.converged, solver_status: str = "",
        iterations: int | None = None,
    ) -> ControlStep:
        """The step's result; ``u_cost`` is the input part of the cost."""
        nx, nu, T = self._nx, self._nu, self.horizon
        u_pred = z[None, :].repeat(T, 0) if self.nz == nu else (self._E @ z).reshape(T, nu)
        e = X - ref
        e *= e
        return ControlStep(
            u=z if self.nz == nu else z[:nu].copy(), x_pred=X.reshape(T + 1, nx),
            u_pred=u_pred, status=status, cost=float(self._wq.dot(e)) + u_cost,
            solver_status=solver_status, iterations=iterations, info={"op": op},
        )

    def _model(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The predictor of the interpolated or adaptive mode at state ``x``."""
        if self.mode is ScheduleMode.adaptive:
            prev = self.previous_plan
            return self.predictor(x, prev.u if prev is not None else np.zeros(self.plant.nu))
        Px = Pu = pc = 0.0
        for op, w in self.grid.weights(x):
            m = self.models[op]
            k = self.grid.wraps(x, op)
            Px = Px + w * m.Px
            Pu = Pu + w * m.Pu
            pc = pc + w * (m.pc + k * m.x_shift if k else m.pc)
        return Px, Pu, pc

    def _qp(self, H: FloatArray, g: FloatArray) -> tuple[FloatArray | None, SolveStatus, str]:
        """``(z or None, status, the solver's own word)``; the box QPs here are solved
        exactly (closed form, or a finite active-set method)."""
        if self._cvx is not None:
            sol = self._cvx.solve(H, g)
            z = None if sol.values is None else np.asarray(sol.values[0], dtype=float)
            return z, sol.status, sol.raw
        if self.nz == 2 and self.solver is not ScheduledQpSolver.active_set:
            z = box_qp_2(*H.ravel()[[0, 1, 3]].tolist(), *g.tolist(), *self._bounds)
            return np.array(z), SolveStatus.converged, "closed_form"
        return box_qp_active_set(H, g, self.lb, self.ub), SolveStatus.converged, "active_set"

    def _failed_at(self, status: SolveStatus, x: FloatArray, raw: str, op: int) -> ControlStep:
        """A failed solve at operating point ``op`` (kept in the step's info)."""
        res = self._failed(status, x, raw)
        res.info["op"] = op
        return res

    def board_time_model(self) -> Callable[[ControlStep], float] | None:
        """With ``codegen=true``: a call's time on the F401RE (Cortex-M4F, 84 MHz) by the
        step model of the generated C in ``codegen_precision``
        (:meth:`ScheduledSIL.board_time`)."""
        return None if self._sil is None else self._sil.board_time()

    # ------------------------------------------------------------------ results
    def operating_table(self) -> pd.DataFrame:
        """One row per operating point: ``op`` and the scheduling states' values."""
        return pd.DataFrame([{"op": i, **p} for i, p in enumerate(self.grid.points())])

    @property
    def solved_problem(self) -> Problem:
        """What a ``converged`` step solved exactly: the QP of the model linearized at the
        current state (``adaptive``) or of operating points' fixed models (``switched``,
        ``interpolated``); never the nonlinear OCP, and with the input held over the
        horizon as ``control_horizon`` blocks it."""
        if self.mode is ScheduleMode.adaptive:
            return Problem.linearized
        return Problem.scheduled_linear

    def metrics(self, steps: pd.DataFrame) -> dict[str, Any]:
        """What problem was solved; switches of the (nearest or active) operating point and
        the input jumps there."""
        calls = record.controller_steps(steps)
        ops = pd.to_numeric(calls["op"], errors="coerce").to_numpy(dtype=float)
        U = calls[list(self.plant.inputs)].to_numpy(dtype=float)
        out: dict[str, Any] = {
            "schedule_mode": self.mode.value, "n_operating_points": len(self.grid),
            "codegen": self.codegen,
        }
        if self._sil is not None:  # where its C is (printed at the end of the run)
            out["generated_c"] = [str(p) for p in self._sil.library.generated]
            out["codegen_precision"] = self.codegen_precision.value
            out |= self._sil.board_summary(calls)
        return out | switch_metrics(calls["t"].to_numpy(dtype=float), ops, U, self.plant)
