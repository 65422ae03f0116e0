"""What every backend that takes the objective's constraints does with them, in one place.

The detected points are padded to the room the problem has for them (the nearest kept), and
the soft constraints' slacks are summed up for the run record. CasADi
(:mod:`mpclab.controllers.casadi.mpc`) and CVXPY (:mod:`mpclab.controllers.cvxpy.mpc`) both call
these.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mpclab.constraints.base import Constraint
from mpclab.controllers.base import FloatArray
from mpclab.plants.base import Plant

#: a slack above this [m] counts as a step on which a soft constraint gave way
GAVE_WAY = 1e-6


def pad_detections(
    plant: Plant, x: FloatArray, det: Any, max_detections: int,
) -> tuple[FloatArray, FloatArray]:
    """Detections ``(2, M)`` (``M = max(max_detections, 1)``) and their mask ``(M,)``: more
    than ``max_detections`` points are cut to the nearest, the rest is padding far away
    (mask 0)."""
    M = max(max_detections, 1)
    ix, iy = (plant.state_index(s) for s in plant.position)
    pos = np.array([x[ix], x[iy]])
    det = np.asarray(det, dtype=float).reshape(-1, 2)
    if len(det) > max_detections:  # keep the nearest
        order = np.argsort(np.linalg.norm(det - pos, axis=1))[:max_detections]
        det = det[order]
    out = np.tile(pos + 1e3, (M, 1))  # padding far away, masked out anyway
    out[: len(det)] = det
    mask = np.zeros(M)
    mask[: len(det)] = 1.0
    return out.T, mask


#: a soft constraint's stage multipliers this near its penalty (their ratio above it) make a
#: warning: within 10x, the exact penalty's margin is thin (:class:`SlackLog`)
PENALTY_WARNING = 0.1


class SlackLog:
    """The largest slack of the soft constraints at each step, for the run record, and how
    much of its penalty a soft constraint's stage used.

    A soft constraint's rows at stage ``k`` share one slack ``s_k >= 0`` priced ``penalty``
    per unit; stationarity in ``s_k`` gives ``sum_i lambda_ik = penalty - mu_k`` (``mu_k`` the
    multiplier of ``s_k >= 0``), so the rows' multipliers are read off the slack's bound. The
    L1 penalty is exact (the soft solution is the hard one where that is feasible) while
    ``penalty`` exceeds the hard problem's stage multipliers: ``penalty_use`` is their largest
    sum over the penalty, 1 where a plan gave way."""

    def __init__(self) -> None:
        self.steps: list[float] = []
        self.use: list[float] = []

    def reset(self) -> None:
        self.steps = []
        self.use = []

    def add(self, largest: float, use: float | None = None) -> None:
        self.steps.append(float(largest))
        if use is not None:
            self.use.append(float(use))

    def metrics(self, constraints: Sequence[Constraint]) -> dict[str, Any]:
        """The constraints' :meth:`~mpclab.constraints.base.Constraint.info` and, with soft
        ones, on how many steps and how far [m] they gave way, and the largest use of the
        penalty (``penalty_use_max``; ``penalty_warning`` above :data:`PENALTY_WARNING`)."""
        out: dict[str, Any] = {"constraints": {c.name: c.info() for c in constraints}}
        if self.steps:
            sl = np.array(self.steps)
            out["slack_steps"] = int(np.sum(sl > GAVE_WAY))
            out["slack_max_m"] = float(sl.max())
        if self.use:
            # the steps whose plans kept the constraint: there the exact penalty should hold
            kept = [u for u, s in zip(self.use, self.steps, strict=True) if s <= GAVE_WAY]
            top = max(kept, default=0.0)
            out["penalty_use_max"] = float(top)
            out["penalty_warning"] = (
                f"a soft constraint's stage multipliers reached {top:.3g} of its penalty "
                f"on a plan that kept it (within 10x: the soft solution may leave the hard "
                f"one; raise the penalty)" if top > PENALTY_WARNING else None)
        return out
