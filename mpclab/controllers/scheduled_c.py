"""The scheduled controller's generated C in the loop (software in the loop, SIL).

:func:`schedule_tables` hands the matrices a :class:`~mpclab.controllers.scheduled.ScheduledMPC`
precomputed at build time to the C emitter (:mod:`mpclab.codegen.scheduled`);
:class:`ScheduledSIL` compiles and loads that C and turns one call of it into the step's
moves, operating point, predicted states and status. ``controller.codegen=true`` makes the
controller step through it instead of its Python solver.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mpclab.codegen.build import CompileError
from mpclab.codegen.loader import DEFAULT_FLAGS, ScheduledLibrary
from mpclab.codegen.scheduled import (
    STATUS_CONVERGED,
    STATUS_MAX_ITER,
    STATUS_NOT_POSITIVE_DEFINITE,
    QpMethod,
    ScheduleAxis,
    ScheduledTables,
)
from mpclab.errors import ConfigError
from mpclab.status import SolveStatus

#: a :class:`~mpclab.controllers.scheduled.ScheduledMPC` (which imports this module, so it
#: is not imported here: the generated C sits below the controller it stands in for)
ScheduledMPC = Any

#: what a return code of ``mpc_step`` means: (status, the C's word); any other: failed
C_STATUS = {
    STATUS_CONVERGED: (SolveStatus.converged, "converged"),
    STATUS_MAX_ITER: (SolveStatus.truncated, "max_iterations"),  # feasible, not optimal
    STATUS_NOT_POSITIVE_DEFINITE: (SolveStatus.failed, "not_positive_definite"),
}


def schedule_tables(ctrl: ScheduledMPC, qp: QpMethod) -> ScheduledTables:
    """The tables of ``ctrl``'s operating-point models, as the C emitter takes them."""
    models, th = ctrl.models, ctrl._theta
    rows = ctrl.qp.rows
    return ScheduledTables(
        nx=ctrl._nx, nu=ctrl._nu, horizon=ctrl.horizon,
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
                "controller.codegen=true needs controller.mode=switched without hysteresis "
                f"(got mode={ctrl.mode.value}, hysteresis={margins})"
            )
        if ctrl.solver not in ("auto", "closed_form", "active_set"):
            raise ConfigError(
                f"controller.codegen=true: controller.solver={ctrl.solver.value} runs through "
                "CVXPY and has no generated C; valid: auto, closed_form, active_set"
            )
        return cls(ctrl, QpMethod.closed_form if ctrl._closed_form else QpMethod.active_set)

    def __init__(self, ctrl: ScheduledMPC, qp: QpMethod, flags: tuple[str, ...] = DEFAULT_FLAGS):
        try:
            self.library = ScheduledLibrary(schedule_tables(ctrl, qp), flags)
        except CompileError as exc:
            raise ConfigError(f"controller.codegen=true: {exc}") from None

    def step(self, x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, int, np.ndarray,
                                                            SolveStatus, str, int]:
        """``(z, op, X, status, the C's word, iterations)`` for state ``x``, reference ``ref``."""
        rc, z, op, iters = self.library.step(x, ref)
        status, word = C_STATUS.get(rc, (SolveStatus.failed, f"code_{rc}"))
        X = self.library.predict(op, x, z)
        return z, op, X, status, word, iters
