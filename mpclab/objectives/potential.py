"""Study B's potential-field terms J1, J3, J4, J5 (J2, input effort, is QuadraticTracking).

Every term sums over the predicted positions ``p_k``, ``k = 1..T`` (``p_0`` is the measured
state and only adds a constant). Distances are ``sqrt(|.|^2 + eps)`` so that derivatives stay
finite at zero distance. They read ``goal``, ``x0`` (the measured state), ``detections (2, M)``
and ``mask (M, 1)`` (1 for a real detected point, 0 for padding) from the backend's
:class:`~mpclab.objectives.base.TermContext`: CasADi values (symbols or numbers).

==========  ===========================================================  ====================
term        cost                                                         default weights
==========  ===========================================================  ====================
J1          ``-C1 exp(-dist_g / L1)``                                    C1 = 5500, L1 = 2
J3          ``wrap(theta0 - theta)^2 C2 exp(-dist_g / L2)``              C2 = 100, L2 = 0.04
J4          ``sum_i C3 exp(-|p - p_i| / L3)``                            C3 = 8000, L3 = 0.1527
J5          ``sum_i dist_g * (-C4 exp(-|p - g_i| / L4))``                C4 = 900, L4 = 0.3
==========  ===========================================================  ====================

with ``g_i = Rot(angle) (p_i - p_0) + p_0`` (``angle = 70 deg``: to the left of the obstacle).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from mpclab.core.errors import ConfigError, number
from mpclab.objectives.base import Term, TermContext


class _PositionTerm(Term):
    """A term over predicted positions; resolves the plant's position/heading labels."""

    def __init__(self, eps: float = 1e-6) -> None:
        self.eps = number(eps, "eps", above=0)

    def bind(self, plant: Any) -> None:
        self._ix, self._iy = (plant.state_index(s) for s in plant.position)
        self._ith = None if plant.heading is None else plant.state_index(plant.heading)

    def _xy(self, X: Any) -> tuple[Any, Any]:
        """Predicted positions ``x, y`` as row vectors ``(1, T)`` (steps 1..T)."""
        return X[self._ix, 1:], X[self._iy, 1:]

    def _goal_dist(self, X: Any, ctx: TermContext) -> Any:
        x, y = self._xy(X)
        g = ctx.goal
        return ca.sqrt((x - g[self._ix]) ** 2 + (y - g[self._iy]) ** 2 + self.eps)


def _positive(**weights: float) -> None:
    for key, w in weights.items():
        number(w, key, above=0)


class GoalAttraction(_PositionTerm):
    """J1: ``sum_k -C1 exp(-dist_g / L1)``."""

    def __init__(self, C1: float = 5500.0, L1: float = 2.0, eps: float = 1e-6) -> None:
        super().__init__(eps)
        _positive(C1=C1, L1=L1)
        self.C1, self.L1 = float(C1), float(L1)

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        return ca.sum2(-self.C1 * ca.exp(-self._goal_dist(X, ctx) / self.L1))


class HeadingNearGoal(_PositionTerm):
    """J3: ``sum_k wrap(theta0 - theta)^2 C2 exp(-dist_g / L2)``, ``theta0`` = goal heading."""

    def __init__(self, C2: float = 100.0, L2: float = 0.04, eps: float = 1e-6) -> None:
        super().__init__(eps)
        _positive(C2=C2, L2=L2)
        self.C2, self.L2 = float(C2), float(L2)

    def bind(self, plant: Any) -> None:
        super().bind(plant)
        if self._ith is None:
            raise ConfigError(f"objective term {self.name!r} needs a plant with a heading")

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        e = ctx.goal[self._ith] - X[self._ith, 1:]
        wrapped = ca.atan2(ca.sin(e), ca.cos(e))
        return ca.sum2(wrapped**2 * self.C2 * ca.exp(-self._goal_dist(X, ctx) / self.L2))


class ObstacleRepulsion(_PositionTerm):
    """J4: ``sum_k sum_i mask_i C3 exp(-|p_k - p_i| / L3)`` over the detected points."""

    def __init__(self, C3: float = 8000.0, L3: float = 0.1527, eps: float = 1e-6) -> None:
        super().__init__(eps)
        _positive(C3=C3, L3=L3)
        self.C3, self.L3 = float(C3), float(L3)

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        dist = _pairwise(*self._xy(X), ctx.detections, self.eps)  # (M, T)
        return ca.sum1(ca.sum2(self.C3 * ca.exp(-dist / self.L3)) * ctx.mask)


class LeftHandPull(_PositionTerm):
    """J5 (right-hand rule): ``sum_k sum_i mask_i Q(p_k) (-C4 exp(-|p_k - g_i| / L4))``.

    ``g_i`` is detected point ``i`` rotated by ``angle_deg`` (counter-clockwise: to the
    robot's left of the obstacle) about the robot's measured position. ``Q = dist_g`` (the
    study) when ``goal_scaled``, else ``Q = 1``: without goal attraction (BUG2's
    wall-following) the factor ``dist_g`` pushes the robot away from the goal and off the wall.
    """

    def __init__(
        self,
        C4: float = 900.0,
        L4: float = 0.3,
        angle_deg: float = 70.0,
        goal_scaled: bool = True,
        eps: float = 1e-6,
    ) -> None:
        super().__init__(eps)
        _positive(C4=C4, L4=L4)
        self.C4, self.L4 = float(C4), float(L4)
        self.goal_scaled = bool(goal_scaled)
        self.angle_deg = number(angle_deg, "angle_deg")
        a = np.deg2rad(self.angle_deg)
        self._rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])

    def pull_points(self, ctx: TermContext) -> Any:
        """The attracting points ``g_i`` ``(2, M)``."""
        x0 = ctx.x0
        c = ca.vertcat(x0[self._ix], x0[self._iy])
        det = ctx.detections
        M = det.shape[1]
        centre = ca.repmat(c, 1, M)
        return ca.mtimes(ca.DM(self._rot), det - centre) + centre

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        dist = _pairwise(*self._xy(X), self.pull_points(ctx), self.eps)  # (M, T)
        W = -self.C4 * ca.exp(-dist / self.L4)
        if self.goal_scaled:
            W = W * ca.repmat(self._goal_dist(X, ctx), W.shape[0], 1)  # Q = dist_g, (1, T)
        return ca.sum1(ca.sum2(W) * ctx.mask)


def _pairwise(x: Any, y: Any, pts: Any, eps: float) -> Any:
    """Distances ``(M, T)`` between points ``pts (2, M)`` and positions ``x, y (1, T)``."""
    M, T = pts.shape[1], x.shape[1]
    dx = ca.repmat(x, M, 1) - ca.repmat(pts[0, :].T, 1, T)
    dy = ca.repmat(y, M, 1) - ca.repmat(pts[1, :].T, 1, T)
    return ca.sqrt(dx**2 + dy**2 + eps)
