"""The scheduled controller's generated C in the loop (software in the loop, SIL).

:func:`schedule_tables` hands the matrices a :class:`~mpclab.controllers.scheduled.mpc.ScheduledMPC`
precomputed at build time to the C emitter (:mod:`mpclab.codegen.scheduled`);
:class:`ScheduledSIL` compiles and loads that C and turns one call of it into the step's
moves, operating point, predicted states and status. ``controller.codegen=true`` makes the
controller step through it instead of its Python solver; :meth:`ScheduledSIL.step_model` is
its time per step on the F401RE (a PIL trace weighed by the Cortex-M4 cycle model, fitted
once and cached: :mod:`mpclab.codegen.step_model`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from mpclab.codegen.build import CompileError
from mpclab.codegen.loader import DEFAULT_FLAGS, Precision, ScheduledLibrary
from mpclab.codegen.scheduled import (
    STATUS_CONVERGED,
    STATUS_MAX_ITER,
    STATUS_NOT_POSITIVE_DEFINITE,
    QpMethod,
    ScheduleAxis,
    ScheduledTables,
)
from mpclab.codegen.step_model import StepModel, step_model
from mpclab.controllers.base import ControlStep
from mpclab.core.errors import ConfigError
from mpclab.core.status import SolveStatus

#: a :class:`~mpclab.controllers.scheduled.mpc.ScheduledMPC` (which imports this module, so it
#: is not imported here: the generated C sits below the controller it stands in for)
ScheduledMPC = Any

#: what a return code of ``mpc_step`` means: (status, the C's word); any other: failed
C_STATUS = {
    STATUS_CONVERGED: (SolveStatus.converged, "converged"),
    STATUS_MAX_ITER: (SolveStatus.truncated, "max_iterations"),  # feasible, not optimal
    STATUS_NOT_POSITIVE_DEFINITE: (SolveStatus.failed, "not_positive_definite"),
}
#: calibration steps of the step model's PIL trace
CALIBRATION_STEPS = 24
#: the step log's column of a call's modelled time on the F401RE [s] (``sim.latency=modelled``)
M4_COLUMN = "step_m4_s"


def schedule_tables(ctrl: ScheduledMPC, qp: QpMethod) -> ScheduledTables:
    """The tables of ``ctrl``'s operating-point models, as the C emitter takes them."""
    models, th = ctrl.models, ctrl.heading_index
    rows = ctrl.qp.rows
    return ScheduledTables(
        nx=ctrl.plant.nx, nu=ctrl.plant.nu, horizon=ctrl.horizon,
        K_x=np.stack([m.Kx for m in models]),
        kc=np.stack([m.kc for m in models]),
        K_ref=np.stack([-m.Kr[:, rows] for m in models]),
        ref_rows=tuple(int(r) for r in rows),
        g_shift=np.stack([m.g_shift for m in models]),
        H=np.stack([m.H for m in models]),
        theta_op=np.array([m.theta for m in models]),
        theta_index=-1 if th is None else int(th),
        P=np.stack([m.P for m in models]),
        x_shift=np.stack([m.x_shift for m in models]),
        lb=ctrl.lb, ub=ctrl.ub,
        axes=tuple(ScheduleAxis(int(i), bool(p), tuple(cuts), tuple(ops))
                   for i, p, cuts, ops in ctrl.grid.cell_table),
        qp=qp,
    )


class ScheduledSIL:
    """The compiled C of a switched scheduled controller, stepping in its place."""

    @classmethod
    def of(cls, ctrl: ScheduledMPC) -> ScheduledSIL:
        """The generated C of ``ctrl`` (``codegen=true``), after checking that it has one."""
        if ctrl.mode != "switched" or any(ctrl.grid.hysteresis):  # StrEnum: equal to values
            margins = dict(zip(ctrl.grid.labels, ctrl.grid.hysteresis, strict=True))
            raise ConfigError(
                "controller.codegen=true needs controller.schedule.mode=switched without "
                "hysteresis "
                f"(got mode={ctrl.mode.value}, hysteresis={margins})"
            )
        if ctrl.solver not in ("auto", "closed_form", "active_set"):
            raise ConfigError(
                f"controller.codegen=true: controller.solver={ctrl.solver.value} runs through "
                "CVXPY and has no generated C; valid: auto, closed_form, active_set"
            )
        return cls(ctrl, QpMethod.closed_form if ctrl.uses_closed_form else QpMethod.active_set,
                   precision=ctrl.codegen_precision)

    def __init__(self, ctrl: ScheduledMPC, qp: QpMethod, flags: tuple[str, ...] = DEFAULT_FLAGS,
                 precision: Precision = Precision.double):
        try:
            self.library = ScheduledLibrary(schedule_tables(ctrl, qp), flags, precision)
        except CompileError as exc:
            raise ConfigError(f"controller.codegen=true: {exc}") from None
        self._calibration = calibration_states(
            ctrl.op_states, [int(i) for i, periodic, *_ in ctrl.grid.cell_table if periodic],
            ctrl.horizon)
        self._model: StepModel | None = None

    def step_model(self) -> StepModel:
        """The step's modelled cycles on the F401RE in this C's precision (traced once)."""
        if self._model is None:
            try:
                self._model = step_model(self.library, *self._calibration,
                                         self.library.precision)
            except RuntimeError as exc:
                raise ConfigError(f"sim.latency=modelled: {exc}") from None
        return self._model

    def board_time(self) -> Callable[[ControlStep], float]:
        """A call's modelled time on the F401RE [s] at its active-set iterations (the
        :meth:`step_model`; its PIL trace paid now, once), kept in the call's info
        (:data:`M4_COLUMN`)."""
        model = self.step_model()

        def seconds(step: ControlStep) -> float:
            t = model.seconds(step.iterations or 0)
            step.info[M4_COLUMN] = t
            return t

        return seconds

    def board_summary(self, calls: pd.DataFrame) -> dict[str, Any]:
        """``step_m4_median_ms``, ``step_m4_p95_ms``, ``step_m4_max_ms`` and the model's
        description, when the loop modelled the calls' board time (else nothing)."""
        if M4_COLUMN not in calls or self._model is None:
            return {}
        ms = pd.to_numeric(calls[M4_COLUMN], errors="coerce").dropna().to_numpy() * 1e3
        if not len(ms):
            return {}
        return {"step_m4_median_ms": float(np.median(ms)),
                "step_m4_p95_ms": float(np.percentile(ms, 95)),
                "step_m4_max_ms": float(ms.max()), "step_m4_model": self._model.describe()}

    def step(self, x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, int, np.ndarray,
                                                            SolveStatus, str, int]:
        """``(z, op, X, status, the C's word, iterations)`` for state ``x``, reference ``ref``."""
        rc, z, op, iters = self.library.step(x, ref)
        status, word = C_STATUS.get(rc, (SolveStatus.failed, f"code_{rc}"))
        X = self.library.predict(op, x, z)
        return z, op, X, status, word, iters


def calibration_states(op_states: list[np.ndarray], periodic: list[int], horizon: int,
                       n: int = CALIBRATION_STEPS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` states and constant previewed references ``(n, nx)``, ``(n, (T+1) nx)`` for the
    step model's trace: every operating point in turn, its state moved by 10 % (of 1 + |x|),
    a periodic scheduling state by -1, 0 or 1 turn, and the reference off the state by
    amplitudes from 1e-3 to 3 (the inputs inside their bounds to all at a bound, so that the
    active set takes from its fewest to its most iterations)."""
    rng = np.random.default_rng(seed)
    xs, refs = [], []
    for i, amp in enumerate(np.geomspace(1e-3, 3.0, n)):
        xo = np.asarray(op_states[i % len(op_states)], dtype=float)
        scale = 1.0 + np.abs(xo)
        x = xo + 0.1 * scale * rng.standard_normal(xo.size)
        for j in periodic:
            x[j] += 2 * np.pi * int(rng.integers(-1, 2))
        xs.append(x)
        refs.append(np.tile(x + amp * scale * rng.standard_normal(xo.size), horizon + 1))
    return np.array(xs), np.array(refs)
