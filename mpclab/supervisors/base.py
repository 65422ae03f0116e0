"""Supervisors pick the active objective terms each step; ``none`` keeps them all on."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from mpclab.config.registry import component

FloatArray = npt.NDArray[np.float64]
#: the scenario's arrival rule: whether a state is at the goal
Arrival = Callable[[FloatArray], bool]


class Supervisor:
    """Base class: chooses a mode and the objective terms active in it.

    :meth:`target` may replace the scenario's reference over the horizon for a step.
    """

    def reset(self, x0: FloatArray, goal: FloatArray, arrived: Arrival | None = None) -> None:
        """Start a new run toward ``goal``; ``arrived`` is the scenario's arrival rule (the
        loop ends a run on the true state meeting it; a supervisor sees measured states)."""

    def update(
        self, t: float, x: FloatArray, detections: FloatArray
    ) -> tuple[str, frozenset[str] | None]:
        """Return ``(mode, active term names)``; ``None`` means every term."""
        return "", None

    def target(self, t: float, horizon: int, dt: float) -> FloatArray | None:
        """After :meth:`update`: the reference over the horizon ``(horizon + 1, nx)`` the
        controller is given this step in place of the scenario's, or None (the scenario's)."""
        return None


@component("supervisor", "none")
class NoSupervisor(Supervisor):
    """Every objective term is always active."""
