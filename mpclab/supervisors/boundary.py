"""Boundary following as geometry: the path along a boundary at a set clearance.

The boundary is a set of points (the remembered detected points of the obstacle being
followed). The path at ``clearance`` from it is the level set ``d(q) = clearance`` of the
distance ``d`` from a position ``q`` to the nearest point, walked with the boundary on the
robot's ``side``. It keeps the clearance along straight stretches, rounds a convex corner (an
end of a wall) on a circle of that radius, and cuts a concave one; and it never passes
between two points less than twice the clearance apart, the gap the obstacle memory treats as
closed (its discs of that radius overlap), so the boundary followed is the outline of the
obstacle as the memory links it. The level set is traced on a grid of ``cell`` about the
robot (marching squares, by ``contourpy``), so a pocket or a junction of walls is traced
around rather than circled.

The robot joins the level line whose nearest point is nearest to it, counting a line that
runs against its heading as farther (in a corridor both walls' lines are near: the one with
its wall on the followed side is taken). A pocket whose way out is narrower than twice the
clearance (a gap the robot passed before the memory linked its sides) is a closed line
around the robot with free space inside; there the clearance is lowered, down to ``least``,
until the line leads out. A pocket the robot is not in is never joined.

Sampled at a speed times the controller's period, the path is a reference over the horizon:
a controller tracking it follows the boundary.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import contourpy
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class Side(StrEnum):
    """The side of the robot the followed boundary stays on."""

    right = "right"
    left = "left"


#: how much farther a level line whose direction is opposite to the robot's heading counts
#: when the robot chooses the line to join [m] (half of it at right angles)
AGAINST_HEADING = 0.05


@dataclass(frozen=True)
class DistanceGrid:
    """The distance to the nearest of some points, sampled on a square grid."""

    xs: FloatArray
    ys: FloatArray
    #: ``(len(ys), len(xs))``, capped at ``cap``
    dist: FloatArray
    cell: float
    #: the distance's gradient on the grid, ``(2, len(ys), len(xs))`` (x then y; central
    #: differences)
    slope: FloatArray

    @classmethod
    def around(cls, points: FloatArray, centre: FloatArray, radius: float, cell: float,
               cap: float) -> DistanceGrid:
        """The grid of ``cell`` over the square of half-side ``radius`` about ``centre``:
        each point lowers the distances within ``cap`` of it (a window of the grid)."""
        xs = np.arange(centre[0] - radius, centre[0] + radius + cell, cell)
        ys = np.arange(centre[1] - radius, centre[1] + radius + cell, cell)
        dist = np.full((len(ys), len(xs)), float(cap))
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        reach = int(np.ceil(cap / cell))
        ci = np.rint((pts[:, 0] - xs[0]) / cell).astype(int)
        cj = np.rint((pts[:, 1] - ys[0]) / cell).astype(int)
        i0, i1 = np.maximum(ci - reach, 0), np.minimum(ci + reach + 1, len(xs))
        j0, j1 = np.maximum(cj - reach, 0), np.minimum(cj + reach + 1, len(ys))
        for n in np.flatnonzero((i0 < i1) & (j0 < j1)):
            window = dist[j0[n]:j1[n], i0[n]:i1[n]]
            near = np.hypot(xs[None, i0[n]:i1[n]] - pts[n, 0], ys[j0[n]:j1[n], None] - pts[n, 1])
            np.minimum(window, near, out=window)
        gy, gx = np.gradient(dist, cell)
        return cls(xs, ys, dist, cell, np.stack([gx, gy]))

    def gradient(self, at: FloatArray) -> FloatArray:
        """``(k, 2)``: the distance's gradient at the grid nodes nearest ``at`` ``(k, 2)``."""
        i = np.clip(np.rint((at[:, 0] - self.xs[0]) / self.cell).astype(int), 0, len(self.xs) - 1)
        j = np.clip(np.rint((at[:, 1] - self.ys[0]) / self.cell).astype(int), 0, len(self.ys) - 1)
        return self.slope[:, j, i].T

    def level_lines(self, level: float, side: Side) -> list[FloatArray]:
        """The level lines ``d = level`` (< the cap), each ``(k, 2)`` without repeated
        vertices and oriented with the points on ``side`` (a closed line: first = last)."""
        gen = contourpy.contour_generator(self.xs, self.ys, self.dist, line_type="Separate")
        lines = []
        for line in gen.lines(level):
            line = np.asarray(line, dtype=float)
            line = line[np.r_[True, np.linalg.norm(np.diff(line, axis=0), axis=1) > 1e-9]]
            if len(line) < 2:
                continue
            # orient: the points on the followed side of most steps
            step = np.diff(line, axis=0)
            mid = 0.5 * (line[1:] + line[:-1])
            away = self.gradient(mid)                         # the way d grows
            left = step[:, 0] * away[:, 1] - step[:, 1] * away[:, 0]
            on_right = float(np.sum(left > 0)) >= 0.5 * len(left)
            lines.append(line if on_right == (side is Side.right) else line[::-1])
        return lines


def shorter_side(p: FloatArray, points: FloatArray, goal: FloatArray) -> Side:
    """The side to keep the obstacle ``points`` ``(m, 2)`` on, for a robot at ``p`` blocked
    on its way to ``goal``: the one that goes round the obstacle by its nearer tangent point.

    Seen from ``p``, the obstacle spans angles from the direction of the goal; its extreme
    point on each side is a tangent point ``T``, and the way round that side is estimated as
    ``|T - p| + |goal - T|`` (TangentBug's heuristic distance, Kamon, Rivlin and Rimon 1998,
    over what has been seen of the obstacle). Going round by the left tangent keeps the
    obstacle on the robot's right. An obstacle that reaches round behind the robot on one
    side has its tangent there, far from the goal, so that side is the long one. Ties: right.
    """
    q = np.asarray(p, dtype=float).reshape(2)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    to_goal = np.asarray(goal, dtype=float).reshape(2) - q
    if not len(pts) or not np.any(to_goal):
        return Side.right
    rel = pts - q
    angle = np.arctan2(to_goal[0] * rel[:, 1] - to_goal[1] * rel[:, 0], rel @ to_goal)
    cost = [float(np.linalg.norm(t - q) + np.linalg.norm(goal - t))
            for t in (pts[np.argmax(angle)], pts[np.argmin(angle)])]
    return Side.right if cost[0] <= cost[1] else Side.left


def encloses_free_space(line: FloatArray, side: Side) -> bool:
    """Whether a closed oriented level line has the free side inside (a pocket): walked
    with the boundary on the right it then turns counter-clockwise."""
    if len(line) < 4 or np.linalg.norm(line[0] - line[-1]) > 1e-6:
        return False
    area = 0.5 * float(np.sum(line[:-1, 0] * line[1:, 1] - line[1:, 0] * line[:-1, 1]))
    return area > 0 if side is Side.right else area < 0


def inside(p: FloatArray, polygon: FloatArray) -> bool:
    """Whether ``p`` lies inside the closed ``polygon`` ``(k, 2)`` (even-odd rule)."""
    x, y = polygon[:-1].T
    x2, y2 = polygon[1:].T
    crosses = (y > p[1]) != (y2 > p[1])
    at = x + (p[1] - y) * (x2 - x) / np.where(y2 != y, y2 - y, 1e-12)
    return bool(np.sum(crosses & (p[0] < at)) % 2)


def join(p: FloatArray, heading: FloatArray | None,
         lines: list[FloatArray]) -> tuple[int, int] | None:
    """``(line, vertex)``: where the robot at ``p`` joins the level lines (see the module
    docstring); None without lines."""
    best, where = np.inf, None
    for i, line in enumerate(lines):
        dist = np.linalg.norm(line - p, axis=1)
        if heading is not None:
            step = np.diff(line, axis=0, append=line[-1:] + (line[-1:] - line[-2:-1]))
            step /= np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-12)
            dist = dist + AGAINST_HEADING * 0.5 * (1.0 - step @ heading)
        j = int(np.argmin(dist))
        if dist[j] < best:
            best, where = float(dist[j]), (i, j)
    return where


def walk(line: FloatArray, start: int, spacing: float, n: int) -> FloatArray:
    """``(n, 3)``: the points every ``spacing`` of arc length along ``line`` after vertex
    ``start`` (around again on a closed line; held at the end of an open one), each with the
    line's direction there [rad]."""
    closed = np.linalg.norm(line[0] - line[-1]) < 1e-6
    seq = np.vstack([line[start:], line[1:start + 1]]) if closed else line[start:]
    if len(seq) < 2:
        seq = line[-2:]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(seq, axis=0), axis=1))]
    want = spacing * np.arange(1, n + 1)
    if closed and arc[-1] > 0:
        want = np.mod(want, arc[-1])
    want = np.minimum(want, arc[-1])
    k = np.clip(np.searchsorted(arc, want, side="right") - 1, 0, len(seq) - 2)
    frac = ((want - arc[k]) / np.maximum(arc[k + 1] - arc[k], 1e-12))[:, None]
    xy = seq[k] + frac * (seq[k + 1] - seq[k])
    d = seq[k + 1] - seq[k]
    return np.c_[xy, np.arctan2(d[:, 1], d[:, 0])]


def offset_path(
    p: FloatArray, points: FloatArray, clearance: float, side: Side, spacing: float, n: int,
    heading: float | None = None, least: float | None = None, cell: float = 0.005,
    anchor: FloatArray | None = None,
) -> FloatArray:
    """``(n + 1, 3)``: ``p`` and the points every ``spacing`` of arc length along the level
    line ``d = clearance`` of ``points`` ``(m, 2)`` that the robot at ``p`` with ``heading``
    [rad] joins, each with the direction of travel there [rad] (the first: the direction at
    the joining point). In a pocket the clearance is lowered by ``cell`` steps down to
    ``least`` (default: the clearance; module docstring). With ``anchor`` ``(2,)`` the
    line is joined nearest to it instead of to ``p``."""
    q = np.asarray(p, dtype=float).reshape(2)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    u = None if heading is None else np.array([np.cos(heading), np.sin(heading)])
    floor = clearance if least is None else min(least, clearance)
    radius = n * spacing + 2 * clearance + 3 * cell
    grid = DistanceGrid.around(pts, q, radius, cell, cap=clearance + 2 * cell)
    level, path = clearance, None
    while path is None:
        # a pocket the robot is not in is not a way on: it is walled off at this level
        lines, pockets = [], []
        for line in grid.level_lines(level, side):
            pocket = encloses_free_space(line, side)
            if not pocket or inside(q, line):
                lines.append(line)
                pockets.append(pocket)
        where = join(q if anchor is None else np.asarray(anchor, dtype=float), u, lines)
        if where is None:                       # no line: hold the position
            return np.tile(np.r_[q, heading or 0.0], (n + 1, 1))
        line = lines[where[0]]
        if not pockets[where[0]] or level - cell < floor - 1e-12:
            ahead = walk(line, where[1], spacing, n)
            path = np.vstack([np.r_[q, ahead[0, 2]], ahead])
        level -= cell
    return path


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
