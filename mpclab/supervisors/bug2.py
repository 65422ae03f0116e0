"""BUG2 (Lumelsky & Stepanov 1987) as objective-set switching (Study B, eqs. 9 and 10).

The m-line joins the start and the goal. In ``go_to_goal`` the robot uses the go-to-goal
terms until a detected point blocks the way (it lies in a corridor toward the goal, closer
than ``block_range``); then ``wall_follow`` (the right-hand-rule terms), remembering the hit
point. It leaves ``wall_follow`` when it is back on the m-line (within ``mline_tolerance``,
or crossing it between two steps) closer to the goal than the hit point by ``leave_margin``,
or (ours, ``goal_sight_range > 0``) when the goal is that near, closer than the hit point by
``leave_margin`` and no detected point lies in the corridor to it: a goal in sight beside a
wall is reached without following the wall on to the m-line. Either rule keeps BUG2's
progress argument: every leave point is closer to the goal than the hit point before it.
Which terms each mode switches on is configuration, not code.

The boundary followed is the obstacle that was hit: every detected point is remembered in
the world frame, and points less than ``boundary.run_link`` apart (a gap the robot cannot pass) are
one obstacle (:class:`~mpclab.supervisors.boundary.ObstacleMemory`); the obstacle of the
blocking point is the one followed (:meth:`followed`). With ``boundary.path_speed > 0`` the
supervisor follows the boundary itself: in ``wall_follow`` the controller's reference
over the horizon (:meth:`target`) is the path along the followed obstacle at ``clearance``
(:mod:`mpclab.supervisors.boundary`) sampled at ``path_speed``, for a tracking term.

A way can be blocked where no detected point lies in the corridor toward the goal (two
obstacles either side of it, closer together than the robot with its margin): with
``stuck.window > 0``, a robot in ``go_to_goal`` that has come less than ``stuck.progress``
nearer the goal over that window, with an obstacle detected within ``block_range``, counts
as having hit the obstacle nearest to it. A robot whose measured state meets the scenario's
arrival rule is where it thinks the goal is: it leaves ``wall_follow``, and it is never
stuck (it makes no progress because it is there). A drifting estimate can put it there
short of the true goal; the run then stalls there rather than following walls on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType
from typing import Any

import numpy as np

from mpclab.config.registry import component
from mpclab.constraints.obstacle import ObstacleDistance
from mpclab.core.errors import number, parse_choice
from mpclab.core.options import group
from mpclab.objectives.base import Objective
from mpclab.plants.base import Plant
from mpclab.supervisors.base import Arrival, FloatArray, Supervisor, mode_terms
from mpclab.supervisors.boundary import ObstacleMemory, Side, offset_path, shorter_side


class Bug2Mode(StrEnum):
    go_to_goal = "go_to_goal"
    wall_follow = "wall_follow"


class SideRule(StrEnum):
    """Which side of the robot the boundary followed after a hit stays on."""

    #: always the right (the study's right-hand rule)
    right = "right"
    #: always the left
    left = "left"
    #: at each hit, the side that goes round the obstacle the shorter way, as far as it has
    #: been seen (:func:`~mpclab.supervisors.boundary.shorter_side`)
    shorter = "shorter"


#: the study's modes (eqs. 9 and 10); experiments name theirs in conf/supervisor/bug2.yaml
MODES: Mapping[str, Sequence[str]] = MappingProxyType(
    {"go_to_goal": ("J1", "J2", "J3", "J4"), "wall_follow": ("J3", "J4", "J5")})


@dataclass(frozen=True)
class BoundaryFollowing:
    """How BUG2 follows the boundary it hit (``supervisor.boundary``).

    Parameters
    ----------
    path_speed
        > 0: in ``wall_follow``, the reference over the horizon is the path along the
        followed boundary, sampled at this speed [m/s]; 0: the scenario's (a term follows
        the wall).
    clearance
        The path's distance from the followed boundary's detected points [m].
    least_clearance
        In a pocket whose way out is narrower than twice ``clearance`` the path's distance
        is lowered down to this [m] (:mod:`~mpclab.supervisors.boundary`).
    side
        ``right`` or ``left``: the side of the robot the followed boundary stays on;
        ``shorter``: chosen at each hit, the side that goes round the obstacle hit by its
        nearer tangent point (:class:`SideRule`).
    run_link
        Detected points nearer than this to each other belong to one obstacle [m]; None:
        twice ``clearance`` as stated (a gap the path along a boundary cannot pass; a
        clearance raised by ``outside_margin`` leaves it: the robot still fits through).
    outside_margin
        The path runs at least this far outside the distance the objective's obstacle
        constraint keeps [m]: where that margin (derived from the world's bounds) comes
        nearer ``clearance``, both clearances are raised by the difference.
    """

    path_speed: float = 0.0
    clearance: float = 0.08
    least_clearance: float = 0.07
    side: SideRule | str = SideRule.right
    run_link: float | None = None
    outside_margin: float = 0.015


@dataclass(frozen=True)
class StuckRule:
    """When a robot going to the goal counts as stuck (``supervisor.stuck``; module
    docstring).

    Parameters
    ----------
    window
        > 0: the window of the rule [s]; 0: off.
    progress
        Less progress toward the goal than this over ``window`` is stuck [m].
    """

    window: float = 0.0
    progress: float = 0.02


@component("supervisor", "bug2", injected=("plant", "objective"))
class Bug2(Supervisor):
    """The BUG2 state machine over the objective's terms.

    Parameters
    ----------
    plant
        Injected; its ``position`` labels locate the robot in the state.
    modes
        ``{go_to_goal: [term, ...], wall_follow: [term, ...]}``: the terms active per mode.
    block_range
        A detected point blocks the way when it is ahead toward the goal closer than this [m].
    corridor_half_width
        ... and at most this far from the line toward the goal [m].
    mline_tolerance
        Distance from the m-line that counts as being on it [m].
    leave_margin
        How much closer to the goal than the hit point the leave point must be [m].
    goal_sight_range
        Also leave off the m-line when the goal is nearer than this and the corridor to it
        is free of detected points [m] (at most the sensor's range); 0: the m-line only.
    boundary
        How the boundary that was hit is followed (:class:`BoundaryFollowing`:
        ``path_speed``, ``clearance``, ``least_clearance``, ``side``, ``run_link``).
    stuck
        The stuck rule (:class:`StuckRule`: ``window``, ``progress``).
    objective
        Injected; every term a mode names must be one of its terms, and every one of its
        terms must be named by some mode (a term no mode names would be silently off).
    """

    def __init__(
        self,
        plant: Plant,
        modes: Mapping[str, Sequence[str]] = MODES,
        block_range: float = 0.2,
        corridor_half_width: float = 0.08,
        mline_tolerance: float = 0.05,
        leave_margin: float = 0.05,
        goal_sight_range: float = 0.0,
        boundary: BoundaryFollowing | Mapping[str, Any] = BoundaryFollowing(),
        stuck: StuckRule | Mapping[str, Any] = StuckRule(),
        objective: Objective | None = None,
    ) -> None:
        self.modes = mode_terms(modes or MODES, Bug2Mode, objective)
        self.block_range = number(block_range, "supervisor.block_range", above=0)
        self.corridor = number(corridor_half_width, "supervisor.corridor_half_width", above=0)
        self.mline_tol = number(mline_tolerance, "supervisor.mline_tolerance", above=0)
        self.leave_margin = number(leave_margin, "supervisor.leave_margin")
        self.sight = number(goal_sight_range, "supervisor.goal_sight_range (0: off)",
                            at_least=0)
        b = group(BoundaryFollowing, boundary, "supervisor.boundary")
        self.path_speed = number(b.path_speed, "supervisor.boundary.path_speed (0: off)",
                                 at_least=0)
        self.clearance = number(b.clearance, "supervisor.boundary.clearance", above=0)
        self.least_clearance = number(b.least_clearance, "supervisor.boundary.least_clearance",
                                      above=0)
        self.run_link = (2 * self.clearance if b.run_link is None
                         else number(b.run_link, "supervisor.boundary.run_link", above=0))
        outside = number(b.outside_margin, "supervisor.boundary.outside_margin", at_least=0)
        kept = [c.known_distance for c in (objective.constraints.values() if objective else ())
                if isinstance(c, ObstacleDistance) and c.known_distance is not None]
        raise_by = max([0.0, *(d + outside - self.clearance for d in kept)])
        self.clearance += raise_by
        self.least_clearance += raise_by
        self.side_rule = parse_choice(SideRule, b.side, "supervisor.boundary.side")
        #: the side followed now (chosen at each hit under ``side=shorter``)
        self.side = Side.left if self.side_rule is SideRule.left else Side.right
        rule = group(StuckRule, stuck, "supervisor.stuck")
        self.stuck_window = number(rule.window, "supervisor.stuck.window (0: off)",
                                   at_least=0)
        self.stuck_progress = number(rule.progress, "supervisor.stuck.progress", above=0)
        self._ip = [plant.state_index(s) for s in plant.position]
        self._ith = plant.state_index(plant.heading) if plant.heading else None
        self.mode = Bug2Mode.go_to_goal
        #: ((x_start, y_start), (x_goal, y_goal)), set by reset
        self.mline: tuple[tuple[float, float], tuple[float, float]] | None = None
        self.hit_point: FloatArray | None = None
        #: (t, x, y) of every switch into wall_follow
        self.hits: list[tuple[float, float, float]] = []
        self._last: FloatArray | None = None
        self._arrived: Arrival | None = None

    def reset(self, x0: FloatArray, goal: FloatArray, arrived: Arrival | None = None) -> None:
        self._arrived = arrived
        s = np.asarray(x0, dtype=float)[self._ip]
        g = np.asarray(goal, dtype=float)[self._ip]
        self.mline = ((float(s[0]), float(s[1])), (float(g[0]), float(g[1])))
        self._start, self._goal = s, g
        self._goal_state = np.asarray(goal, dtype=float).copy()
        self._progress = Window(self.stuck_window)  # the goal distance in go_to_goal
        self.mode = Bug2Mode.go_to_goal
        self.hit_point = None
        self.hits = []
        self._last: FloatArray | None = None
        self._heading: float | None = None
        self.memory = ObstacleMemory(self.run_link)
        self._member: int | None = None  # a point of the obstacle followed
        self._path: FloatArray | None = None  # the last path handed on by target

    def update(
        self, t: float, x: FloatArray, detections: FloatArray
    ) -> tuple[str, frozenset[str] | None]:
        if self.mline is None:
            raise RuntimeError("Bug2.update called before reset")
        p = np.asarray(x, dtype=float)[self._ip]
        det = np.asarray(detections, dtype=float).reshape(-1, 2)
        ids = self.memory.add(det)
        if self.mode is Bug2Mode.go_to_goal:
            block = self.blocking(p, det)
            if not len(block) and self.stuck(t, p, det) and not self.at_goal(x):
                block = np.arange(len(det))
            if len(block):
                self.mode = Bug2Mode.wall_follow
                self.hit_point = p.copy()
                self.hits.append((float(t), float(p[0]), float(p[1])))
                self._member = int(ids[block[np.argmin(np.linalg.norm(det[block] - p, axis=1))]])
                self._path = None
                if self.side_rule is SideRule.shorter:
                    obstacle = self.memory.points[self.memory.obstacle(self._member)]
                    self.side = shorter_side(p, obstacle, self._goal)
        elif self.at_goal(x) or self.can_leave(p, self._last) or self.goal_in_sight(p, det):
            self.mode = Bug2Mode.go_to_goal
            self.hit_point = None
            self._member = None
            self._progress.clear()
        self._last = p
        self._heading = None if self._ith is None else float(np.asarray(x)[self._ith])
        return self.mode.value, self.modes[self.mode]

    def at_goal(self, x: FloatArray) -> bool:
        """Whether the state ``x`` (as measured) meets the arrival rule given to :meth:`reset`
        (False without one)."""
        return self._arrived is not None and bool(self._arrived(np.asarray(x, dtype=float)))

    def followed(self, reach: float = 0.6) -> FloatArray:
        """``(n, 2)``: the remembered points of the obstacle followed within ``reach`` of
        the robot [m] (none in ``go_to_goal``)."""
        if self._member is None or self._last is None:
            return np.zeros((0, 2))
        pts = self.memory.points[self.memory.obstacle(self._member)]
        return pts[np.linalg.norm(pts - self._last, axis=1) < reach]

    def target(self, t: float, horizon: int, dt: float) -> FloatArray | None:
        """In ``wall_follow`` with ``path_speed > 0``: the goal state with its position
        moved along the followed boundary's path, ``path_speed * dt`` a step, and its
        heading the path's direction (unwrapped to the robot's); else None."""
        if self.path_speed <= 0 or self.mode is not Bug2Mode.wall_follow:
            return None
        points = self.followed()
        if not len(points):
            return None
        # join the path where the last one said the robot would be now, if it is near:
        # the line followed stays the same where two are about as near (in a gap)
        was = self._path
        anchor = (was[1, :2] if was is not None and
                  np.linalg.norm(was[1, :2] - self._last) < self.clearance else None)
        path = offset_path(self._last, points, self.clearance, self.side,
                           self.path_speed * dt, horizon, heading=self._heading,
                           least=self.least_clearance, anchor=anchor)
        self._path = path
        ref = np.tile(self._goal_state, (horizon + 1, 1))
        ref[:, self._ip] = path[:, :2]
        if self._ith is not None:  # unwrapped from the robot's heading
            ref[:, self._ith] = np.unwrap(np.concatenate([[self._heading], path[:, 2]]))[1:]
        return ref

    def stuck(self, t: float, p: FloatArray, detections: FloatArray) -> bool:
        """The stuck rule (module docstring): less than ``stuck.progress`` nearer the goal
        over the last ``stuck_window`` seconds in ``go_to_goal``, an obstacle detected
        within ``block_range``. Always False with ``stuck_window = 0``."""
        if self.stuck_window <= 0:
            return False
        before = self._progress.push(t, float(np.linalg.norm(self._goal - p)))
        near = len(detections) and float(
            np.min(np.linalg.norm(detections - p, axis=1))) < self.block_range
        if before is not None and before - self._progress.last < self.stuck_progress and near:
            self._progress.clear()
            return True
        return False

    # ------------------------------------------------------------------ geometry
    def blocking(self, p: FloatArray, detections: FloatArray,
                 reach: float | None = None) -> np.ndarray:
        """Indices of the detected points in the corridor from ``p`` toward the goal, at most
        ``reach`` ahead (default ``block_range``; never beyond the goal)."""
        det = np.asarray(detections, dtype=float).reshape(-1, 2)
        to_goal = self._goal - p
        dist = float(np.linalg.norm(to_goal))
        if len(det) == 0 or dist == 0:
            return np.zeros(0, dtype=int)
        u = to_goal / dist
        rel = det - p
        along = rel @ u
        across = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
        reach = min(self.block_range if reach is None else reach, dist)
        return np.flatnonzero((along > 0) & (along < reach) & (across < self.corridor))

    def blocked(self, p: FloatArray, detections: FloatArray, reach: float | None = None) -> bool:
        """Whether a detected point lies in the corridor toward the goal (:meth:`blocking`)."""
        return bool(len(self.blocking(p, detections, reach)))

    def goal_in_sight(self, p: FloatArray, detections: FloatArray) -> bool:
        """The goal within ``goal_sight_range``, the corridor to it free, and ``p`` closer to
        it than the hit point by ``leave_margin`` (off when ``goal_sight_range`` is 0)."""
        if self.sight <= 0 or self.hit_point is None:
            return False
        dist = float(np.linalg.norm(self._goal - p))
        closer = dist < float(np.linalg.norm(self._goal - self.hit_point)) - self.leave_margin
        return bool(dist < self.sight and closer and not self.blocked(p, detections, dist))

    def mline_side(self, p: FloatArray) -> float:
        """Signed distance from ``p`` to the line through start and goal (left > 0) [m]."""
        s, g = self._start, self._goal
        d = g - s
        n = float(np.linalg.norm(d))
        if n == 0:
            return float(np.linalg.norm(p - s))
        return float((d[0] * (p[1] - s[1]) - d[1] * (p[0] - s[0])) / n)

    def can_leave(self, p: FloatArray, previous: FloatArray | None = None) -> bool:
        """Back on the m-line, closer to the goal than the hit point by ``leave_margin``.

        On the m-line means within ``mline_tolerance`` of it, or having crossed it since
        ``previous`` (a step can jump over a narrow tolerance band).
        """
        if self.hit_point is None:
            return True
        closer = np.linalg.norm(self._goal - p) < (
            np.linalg.norm(self._goal - self.hit_point) - self.leave_margin
        )
        side = self.mline_side(p)
        on = abs(side) < self.mline_tol
        if previous is not None:
            on = on or side * self.mline_side(previous) < 0
        return bool(closer and on)


class Window:
    """The values pushed over the last ``span`` seconds."""

    def __init__(self, span: float) -> None:
        self.span = float(span)
        self._items: list[tuple[float, object]] = []

    def push(self, t: float, value: object) -> object | None:
        """Add ``value`` at ``t``; return the oldest value kept once the window spans
        ``span`` seconds, else None."""
        self._items.append((float(t), value))
        while len(self._items) > 1 and t - self._items[1][0] >= self.span - 1e-9:
            self._items.pop(0)
        t0, first = self._items[0]
        return first if t - t0 >= self.span - 1e-9 else None

    @property
    def last(self) -> object:
        return self._items[-1][1]

    def clear(self) -> None:
        self._items = []
