"""Wall-following as distance keeping to the followed boundary (BUG2's ``wall_follow``).

The supervisor marks the detected points of the boundary being followed
(:attr:`~mpclab.objectives.base.TermContext.follow`). At every predicted position ``p_k``
(``k = 1..T``) the term measures the soft minimum distance to those points,
``d_k = -tau log sum_i f_i exp(-|p_k - q_i| / tau)``, and the boundary's outward normal
``n_k`` (the points' unit directions to ``p_k``, weighted as in the soft minimum); the
tangent ``t_k`` is ``n_k`` turned so that the boundary lies on the robot's ``side``. The cost
tracks the clearance and rewards progress along the boundary::

    sum_k  C_clear (d_k - clearance)^2  -  C_progress (p_k - p_{k-1}) . t_k / |n_k|

``side = right`` (default) keeps the boundary on the robot's right, the study's right-hand
rule (J5 pulls toward points rotated 70 degrees to the left). Without followed points the
term is 0.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import casadi as ca

from mpclab.errors import number, parse_choice
from mpclab.objectives.base import TermContext
from mpclab.objectives.potential import _pairwise, _PositionTerm


class Side(StrEnum):
    right = "right"
    left = "left"


class BoundaryFollow(_PositionTerm):
    """Track ``clearance`` to the followed points while moving along them.

    Parameters
    ----------
    clearance
        The reference distance to the followed boundary [m].
    C_clear
        Weight of the squared clearance error [1/m^2].
    C_progress
        Weight of the progress along the boundary [1/m].
    tau
        Smoothing length of the soft minimum [m].
    side
        ``right`` or ``left``: where the boundary stays.
    side_width
        > 0: a point counts by how far it lies on ``side`` of the predicted heading,
        ``1 / (1 + exp(-s / side_width))`` with ``s`` its signed distance from the heading
        line (so that in a passage narrower than twice the clearance the wall on ``side``
        is the one followed, and turning round makes the other wall that one) [m]; 0: every
        followed point counts.
    """

    uses_follow = True

    def __init__(
        self,
        clearance: float = 0.08,
        C_clear: float = 2.0e4,
        C_progress: float = 500.0,
        tau: float = 0.01,
        side: Side | str = Side.right,
        side_width: float = 0.0,
        eps: float = 1e-6,
    ) -> None:
        super().__init__(eps)
        self.clearance = number(clearance, "clearance", above=0)
        self.C_clear = number(C_clear, "C_clear", at_least=0)
        self.C_progress = number(C_progress, "C_progress", at_least=0)
        self.tau = number(tau, "tau", above=0)
        self.side = parse_choice(Side, side, "side")
        self.side_width = number(side_width, "side_width", at_least=0)

    def casadi_cost(self, X: Any, U: Any, ctx: TermContext) -> Any:
        x, y = self._xy(X)                                   # (1, T)
        pts, f = ctx.detections, ctx.follow                  # (2, M), (M,)
        M, T = pts.shape[1], x.shape[1]
        dist = _pairwise(x, y, pts, self.eps)                # (M, T)
        sign = 1.0 if self.side is Side.right else -1.0
        e = ca.repmat(f, 1, T) * ca.exp(-dist / self.tau)
        if self.side_width > 0:
            th = X[self._ith, 1:]
            rx = ca.repmat(pts[0, :].T, 1, T) - ca.repmat(x, M, 1)
            ry = ca.repmat(pts[1, :].T, 1, T) - ca.repmat(y, M, 1)
            right = ca.repmat(ca.sin(th), M, 1) * rx - ca.repmat(ca.cos(th), M, 1) * ry
            e = e / (1 + ca.exp(-sign * right / self.side_width))
        S = ca.sum1(e) + 1e-300                              # (1, T)
        d = -self.tau * ca.log(S)
        w = e / ca.repmat(S, M, 1) / dist
        nx = ca.sum1(w * (ca.repmat(x, M, 1) - ca.repmat(pts[0, :].T, 1, T)))
        ny = ca.sum1(w * (ca.repmat(y, M, 1) - ca.repmat(pts[1, :].T, 1, T)))
        tx, ty = sign * ny, -sign * nx                        # boundary on ``side``
        norm = ca.sqrt(nx**2 + ny**2 + self.eps)
        px = ca.horzcat(X[self._ix, 0], x)
        py = ca.horzcat(X[self._iy, 0], y)
        step = (ca.diff(px, 1, 1) * tx + ca.diff(py, 1, 1) * ty) / norm
        has = ca.fmin(ca.sum1(f), 1.0)                      # 0 without followed points
        return has * ca.sum2(self.C_clear * (d - self.clearance) ** 2
                             - self.C_progress * step)
