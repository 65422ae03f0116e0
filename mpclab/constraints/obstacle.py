"""Keep the robot a margin away from the sensed obstacle points (and optionally its plan
inside the sensed region).

:class:`ObstacleDistance` keeps every predicted position ``p_{k+1}`` (``k = 0..T-1``) at least
``R`` from every detected point ``p_i``, ``R`` the total of a margin budget (robot radius +
ray error + inter-sample error + noise). Its rows, scaled to metres near the boundary::

    g_i(p) = (R_i^2 - |p - p_i|^2) / (2 R)          (<= 0: at least R_i away)

Modes (:class:`ObstacleMode`):

* ``hard``: ``g_i(p_{k+1}) <= 0`` with ``R_i = min(R, |p_0 - p_i|)``: a point already nearer
  than ``R`` may not be approached further, so that standing still stays feasible;
* ``soft``: ``g_i(p_{k+1}) <= s_k``, one slack ``s_k >= 0`` per stage, ``penalty * sum s_k``
  added to the cost, ``R_i = R``: an exact (L1) penalty, so the solve never becomes
  infeasible and equals the hard solution where that is feasible and ``penalty`` exceeds its
  multipliers;
* ``cbf``: a discrete-time control barrier function ``h(x_{k+1}) >= (1 - gamma) h(x_k)`` with
  ``h_i = -g_i`` and ``R_i`` as in ``hard``.

Padding points (mask 0) give rows that always hold. :class:`SensedRegion` bounds the plan to
the sensor's disc around the measured position, ``|p_{k+1} - p_0| <= range``.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np

from mpclab.constraints.base import Constraint
from mpclab.errors import ConfigError, number, parse_choice


class ObstacleMode(StrEnum):
    hard = "hard"
    soft = "soft"
    cbf = "cbf"


class _Positions(Constraint):
    def bind(self, plant: Any) -> None:
        self._ix, self._iy = (plant.state_index(s) for s in plant.position)

    def _d2(self, x: Any, pts: Any) -> Any:
        """Squared distances ``(M,)`` from the position of state ``x`` to ``pts (2, M)``."""
        return (x[self._ix] - pts[0, :].T) ** 2 + (x[self._iy] - pts[1, :].T) ** 2


class ObstacleDistance(_Positions):
    """Distance to the detected points: hard, soft (exact L1 penalty) or discrete-time CBF.

    Parameters
    ----------
    mode
        ``hard``, ``soft`` or ``cbf`` (module docstring).
    robot_radius, ray_error, sample_error, noise
        The margin budget [m]; the distance kept is their total: the robot's radius, how far
        a detected point may lie beyond the true surface (oblique incidence), what sampling
        hides between two samples, and position noise.
    penalty
        ``soft``: weight of the slack (per metre of violation, per stage).
    gamma
        ``cbf``: the barrier's decay rate per step, ``0 < gamma <= 1``.
    """

    def __init__(
        self,
        mode: ObstacleMode | str = ObstacleMode.soft,
        robot_radius: float = 0.05,
        ray_error: float = 0.012,
        sample_error: float = 0.002,
        noise: float = 0.001,
        penalty: float = 1.0e6,
        gamma: float = 0.5,
    ) -> None:
        self.mode = parse_choice(ObstacleMode, mode, "mode")
        self.budget = {k: number(v, k, at_least=0) for k, v in {
            "robot_radius": robot_radius, "ray_error": ray_error,
            "sample_error": sample_error, "noise": noise}.items()}
        self.distance = number(sum(self.budget.values()),
                               "the margin total (robot_radius + ray_error + sample_error + noise)",
                               above=0)
        self.penalty = number(penalty, "penalty", above=0)
        self.gamma = number(gamma, "gamma", above=0)
        if self.gamma > 1:
            raise ConfigError(f"gamma must be in (0, 1], got {gamma}")
        self.soft = self.mode is ObstacleMode.soft
        self.couples_stages = self.mode is ObstacleMode.cbf

    def declare(self, params: Any, n_points: int) -> dict[str, Any]:
        return {"radius": params.add(f"{self.name}_radius", n_points)}

    def radius(self, x0: Any, detections: Any, mask: Any) -> np.ndarray:
        """``R_i`` ``(M,)``: ``min(R, |p_0 - p_i|)`` (hard, cbf) or ``R`` (soft); 0 for padding."""
        m = np.asarray(mask, dtype=float)
        if self.soft:
            return self.distance * m
        d0 = np.hypot(detections[0] - x0[self._ix], detections[1] - x0[self._iy])
        return np.minimum(self.distance, d0) * m

    def values(self, x0: Any, detections: Any, mask: Any) -> dict[str, Any]:
        return {f"{self.name}_radius": self.radius(x0, detections, mask)}

    def first_violation(self, x0: Any, X: Any, detections: Any, mask: Any) -> int | None:
        R = self.radius(x0, detections, mask)
        d = np.hypot(X[1:, self._ix, None] - detections[0][None],
                     X[1:, self._iy, None] - detections[1][None])       # (T, M)
        bad = np.flatnonzero(np.any((d < R[None] - 1e-9) & (mask[None] > 0), axis=1))
        return int(bad[0]) + 1 if bad.size else None

    def g(self, x: Any, ctx: Any, radius: Any) -> Any:
        """``g_i`` ``(M,)`` at state ``x`` (<= 0 where ``x`` keeps its distance)."""
        return (radius**2 - self._d2(x, ctx.detections) * ctx.mask) / (2 * self.distance)

    def casadi_rows(self, x: Any, x_next: Any, slack: Any, ctx: Any, par: Any,
                    first: bool) -> Any:
        R = par["radius"]
        if self.mode is ObstacleMode.hard:
            return self.g(x_next, ctx, R)
        if self.mode is ObstacleMode.soft:
            return self.g(x_next, ctx, R) - slack
        return self.g(x_next, ctx, R) - (1 - self.gamma) * self.g(x, ctx, R)  # cbf

    def info(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": type(self).__name__, "mode": self.mode.value,
                               "distance_m": self.distance, **self.budget}
        if self.soft:
            out["penalty"] = self.penalty
        if self.mode is ObstacleMode.cbf:
            out["gamma"] = self.gamma
        return out


class SensedRegion(_Positions):
    """Keep every predicted position within ``max_range`` of the measured one (hard).

    Parameters
    ----------
    max_range
        The sensor's range [m]: the plan stays where the sensor has looked.
    """

    def __init__(self, max_range: float = 0.3) -> None:
        self.max_range = number(max_range, "max_range", above=0)

    def casadi_rows(self, x: Any, x_next: Any, slack: Any, ctx: Any, par: Any,
                    first: bool) -> Any:
        p0 = ca.vertcat(ctx.x0[self._ix], ctx.x0[self._iy])
        d2 = self._d2(x_next, p0)
        return (d2 - self.max_range**2) / (2 * self.max_range)

    def info(self) -> dict[str, Any]:
        return {"type": type(self).__name__, "max_range_m": self.max_range}
