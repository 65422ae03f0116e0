"""Clearance in continuous time: the closest the robot comes to an obstacle *between* samples.

A sampled clearance (the distance at ``t_k``) hides how close the robot came while its input
was held over the period. A differential-drive robot (the Zumo) with its wheel speeds held
moves on an exact circular arc (a straight segment when it does not turn), so the closest
point of that arc to each disc's centre is found in closed form: the point of the arc's
circle nearest the centre, if its angle lies in the swept range, or else an end point.
Under input latency the period is two pieces (the input before the switch, then the new
one), each an arc from where the previous one ended.

Plants whose motion is not such an arc are checked by dense sub-steps of their own RK4 step
until the robot moves at most ``2 tol`` between sub-samples; since the distance to a disc
changes no faster than the robot moves, the dense minimum is then within ``tol`` of the
continuous one (:data:`DENSE_TOL_M`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from mpclab.plants.base import Plant
from mpclab.plants.zumo import Zumo

FloatArray = npt.NDArray[np.float64]

#: below this turn over a piece [rad] the arc is taken as its chord (the two differ by
#: at most ``length * turn / 8``: under 1e-10 m for the Zumo's 4 cm per period)
_STRAIGHT_RAD = 1e-8
#: how far the dense check of a non-arc plant may lie above the continuous minimum [m]
DENSE_TOL_M = 2e-4
#: sub-samples per piece the dense check starts with, and at most refines to
_DENSE_START, _DENSE_MAX = 16, 4096


def segment_distance(p0: FloatArray, p1: FloatArray, centres: FloatArray) -> FloatArray:
    """Shortest distance from each point of ``centres`` ``(n, 2)`` to the segment
    ``p0 -> p1`` [m], ``(n,)``."""
    d = p1 - p0
    dd = float(d @ d)
    rel = centres - p0
    s = np.clip(rel @ d / dd, 0.0, 1.0) if dd > 0 else np.zeros(len(centres))
    return np.linalg.norm(rel - s[:, None] * d, axis=1)


def arc_distance(
    pose: Sequence[float], v: float, omega: float, duration: float, centres: FloatArray,
) -> FloatArray:
    """Shortest distance from each point of ``centres`` ``(n, 2)`` to the path of a unicycle
    starting at ``pose = (x, y, theta)`` with speed ``v`` [m/s] and turn rate ``omega``
    [rad/s] held for ``duration`` [s], ``(n,)`` [m].

    The path is the arc ``p(s) = m + R (sin(theta + omega s), -cos(theta + omega s))`` about
    ``m = p0 + R (-sin theta, cos theta)``, ``R = v / omega``; the point of the circle nearest
    a centre ``c`` lies at the angle of ``c - m``; it is on the path if that angle was swept,
    else the nearest point of the path is one of its ends.
    """
    x, y, theta = (float(a) for a in pose)
    p0 = np.array([x, y])
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    turn = omega * duration
    if abs(turn) < _STRAIGHT_RAD:
        p1 = p0 + v * duration * np.array([math.cos(theta), math.sin(theta)])
        return segment_distance(p0, p1, centres)
    radius = v / omega  # signed: > 0 turns left
    m = p0 + radius * np.array([-math.sin(theta), math.cos(theta)])
    p1 = m + radius * np.array([math.sin(theta + turn), -math.cos(theta + turn)])
    rel = centres - m
    ends = np.minimum(np.linalg.norm(centres - p0, axis=1), np.linalg.norm(centres - p1, axis=1))
    if radius == 0.0:  # turning on the spot: the path is one point
        return ends
    # angle of p(s) - m is a0 + omega s, a0 the angle of p0 - m
    a0 = math.atan2(p0[1] - m[1], p0[0] - m[0])
    nearest = np.arctan2(rel[:, 1], rel[:, 0])  # the circle's point nearest c
    swept = np.mod((nearest - a0) * math.copysign(1.0, omega), 2 * math.pi) <= abs(turn)
    on_circle = np.abs(np.linalg.norm(rel, axis=1) - abs(radius))
    return np.where(swept | (abs(turn) >= 2 * math.pi), np.minimum(on_circle, ends), ends)


class ContinuousClearance:
    """The least clearance of a robot disc to disc obstacles over one control period.

    Parameters
    ----------
    plant
        The simulated plant (its parameters, not the controller's model's).
    obstacles
        Discs ``(n, 3)``: centre x, centre y, radius [m].
    robot_radius
        The robot is a disc of this radius [m].
    """

    def __init__(self, plant: Plant, obstacles: FloatArray, robot_radius: float) -> None:
        self.plant = plant
        self.obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 3)
        self.robot_radius = float(robot_radius)
        self._ip = [plant.state_index(s) for s in plant.position]
        self._ih = None if plant.heading is None else plant.state_index(plant.heading)
        #: exact arcs (the Zumo), or dense sub-steps of the plant's own step
        self.exact = isinstance(plant, Zumo)
        #: how far the reported minimum may lie above the continuous one [m]
        self.tolerance_m = 0.0 if self.exact else DENSE_TOL_M

    def interval(self, x: FloatArray, pieces: Sequence[tuple[FloatArray, float]]) -> float:
        """Least clearance [m] from state ``x`` over the ``pieces`` ``[(input, duration)]``
        applied one after the other (NaN without obstacles). The state at a piece's start is
        the plant's own step from the previous one, as the simulator advances it."""
        if len(self.obstacles) == 0:
            return float("nan")
        centres, radii = self.obstacles[:, :2], self.obstacles[:, 2]
        least = float("inf")
        for u, duration in pieces:
            if duration <= 0:
                continue
            u = np.asarray(u, dtype=float)
            if self.exact:
                dist = arc_distance(self._pose(x), *self._zumo_twist(u), duration, centres)
                least = min(least, float(np.min(dist - radii)))
            else:
                least = min(least, self._dense(x, u, duration))
            x = self.plant.step(x, u, duration)
        return least - self.robot_radius

    def _pose(self, x: FloatArray) -> tuple[float, float, float]:
        return float(x[self._ip[0]]), float(x[self._ip[1]]), float(x[self._ih])

    def _zumo_twist(self, u: FloatArray) -> tuple[float, float]:
        """``(v, omega)`` of the Zumo's wheel speeds (the plant's ``rhs``, in numbers)."""
        r, d = float(self.plant.params.r), float(self.plant.params.d)
        return r * (u[0] + u[1]) / 2, r * (u[1] - u[0]) / (2 * d)

    def _dense(self, x: FloatArray, u: FloatArray, duration: float) -> float:
        """Least distance minus obstacle radius over dense sub-steps, refined until the robot
        moves at most ``2 tol`` between sub-samples."""
        n = _DENSE_START
        while True:
            h = duration / n
            xs = [np.asarray(x, dtype=float)]
            for _ in range(n):
                xs.append(self.plant.step(xs[-1], u, h))
            p = np.asarray(xs)[:, self._ip]
            chord = float(np.max(np.linalg.norm(np.diff(p, axis=0), axis=1)))
            if chord <= 2 * DENSE_TOL_M or n >= _DENSE_MAX:
                gaps = np.linalg.norm(p[:, None, :] - self.obstacles[None, :, :2], axis=2)
                return float(np.min(gaps - self.obstacles[None, :, 2]))
            n = min(_DENSE_MAX, int(math.ceil(n * chord / (2 * DENSE_TOL_M))))
