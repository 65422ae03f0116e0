"""Boundary following as geometry: a path along a boundary at a set clearance.

The boundary is a set of points (the detected points of the obstacle being followed). At a
position ``p`` the field is the boundary's tangent, turned so that the boundary lies on the
robot's ``side``, plus a correction along the boundary's normal that restores the
``clearance``::

    v(p) = t(p) + gain clip((clearance - d(p)) / clearance, -1, 1) n(p)

where ``d`` is the distance to the nearest point and ``n`` the unit vector from the points
to ``p`` (soft-minimum weighted, so that the field does not jump between two points of a
sparse scan). Its streamline from ``p`` keeps the clearance along straight stretches, rounds
a convex corner (an end of a wall) on a circle of that radius, and turns away before a
concave one (another part of the boundary comes nearer). The gain is high (5 by default):
where several parts of a boundary are about the clearance away (a junction of walls), a
weak correction leaves the tangents to circle the spot, and the path with them. Sampled at a speed times the controller's period, the streamline is a reference
over the horizon: a controller tracking it follows the boundary.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class Side(StrEnum):
    """The side of the robot the followed boundary stays on."""

    right = "right"
    left = "left"


def nearest(p: FloatArray, points: FloatArray, tau: float = 0.01) -> tuple[float, FloatArray]:
    """``(d, n)``: the distance from ``p`` ``(2,)`` to the nearest of ``points`` ``(n, 2)``
    (``n >= 1``) and the mean of the unit vectors from them to ``p``, weighted as a soft
    minimum of the distances weighs them (smoothing length ``tau``; shorter than 1 where
    near points lie on opposite sides)."""
    rel = p[None, :] - points
    dist = np.maximum(np.linalg.norm(rel, axis=1), 1e-9)
    w = np.exp(-(dist - dist.min()) / tau)
    n = ((w / w.sum())[:, None] * rel / dist[:, None]).sum(axis=0)
    return float(dist.min()), n


def boundary_field(
    p: FloatArray, points: FloatArray, clearance: float, side: Side, gain: float = 5.0,
) -> FloatArray:
    """The unit direction of the field at ``p`` ``(2,)`` along ``points`` ``(n, 2)``
    (``gain``: the weight of the correction toward the clearance)."""
    d, n = nearest(p, points)
    n = n / max(float(np.linalg.norm(n)), 1e-12)
    t = np.array([n[1], -n[0]]) if side is Side.right else np.array([-n[1], n[0]])
    v = t + gain * float(np.clip((clearance - d) / clearance, -1.0, 1.0)) * n
    return v / max(float(np.linalg.norm(v)), 1e-12)


def streamline(
    p: FloatArray, points: FloatArray, clearance: float, side: Side, spacing: float, n: int,
    gain: float = 5.0, step: float = 0.01,
) -> FloatArray:
    """``(n + 1, 3)``: ``p`` and the points every ``spacing`` of arc length along the field's
    streamline from it (steps of at most ``step``, midpoint rule), each with the direction
    of travel there [rad] (the first: the direction at ``p``)."""
    q = np.asarray(p, dtype=float).reshape(2).copy()
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    sub = max(1, int(np.ceil(spacing / step)))
    h = spacing / sub

    def field(at: FloatArray) -> FloatArray:
        return boundary_field(at, pts, clearance, side, gain)

    v = field(q)
    out = [(q[0], q[1], np.arctan2(v[1], v[0]))]
    for _ in range(n):
        for _ in range(sub):
            v = field(q + 0.5 * h * field(q))
            q = q + h * v
        out.append((q[0], q[1], np.arctan2(v[1], v[0])))
    return np.array(out)


class ObstacleMemory:
    """Detected points remembered in the world frame, grouped into obstacles.

    A point is kept once per grid cell of ``cell``; two points nearer than ``link`` belong
    to one obstacle (the robot cannot pass between them), and the obstacles are the
    connected sets: :attr:`labels` gives each point its obstacle, and a point that links
    obstacles merges them. Unlike one scan, the memory keeps the part of a boundary that has
    left the sensor's view, so the boundary followed stays the obstacle that was hit, and
    another obstacle joins it only by a gap the robot cannot pass.
    """

    def __init__(self, link: float, cell: float = 0.01) -> None:
        self.link, self.cell = float(link), float(cell)
        self.points = np.zeros((0, 2))
        #: ``(n_points,)``: the obstacle of each point
        self.labels = np.zeros(0, dtype=int)
        self._cells: dict[tuple[int, int], int] = {}

    def add(self, detections: FloatArray) -> np.ndarray:
        """Remember ``detections`` ``(n, 2)``; return each one's point index ``(n,)``."""
        det = np.asarray(detections, dtype=float).reshape(-1, 2)
        ids = np.empty(len(det), dtype=int)
        for k, q in enumerate(det):
            key = (int(np.floor(q[0] / self.cell)), int(np.floor(q[1] / self.cell)))
            if key not in self._cells:
                i = len(self.points)
                near = self.labels[np.linalg.norm(self.points - q, axis=1) < self.link]
                self.labels[np.isin(self.labels, near)] = i  # the obstacles it links: one
                self.points = np.vstack([self.points, q])
                self.labels = np.append(self.labels, i)
                self._cells[key] = i
            ids[k] = self._cells[key]
        return ids

    def obstacle(self, i: int) -> np.ndarray:
        """Mask ``(n_points,)`` of the points of point ``i``'s obstacle."""
        return self.labels == self.labels[i]
