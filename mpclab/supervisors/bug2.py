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

The boundary followed is the obstacle that was hit: the detections are segmented into runs
(connected sets of points less than ``run_link`` apart: what the robot cannot pass
between); the run holding the blocking point is remembered at the hit and tracked step to
step (the runs within ``run_link`` of the points followed before, or else the nearest run:
a boundary that turns out to close a narrow gap joins it), and its mask is :attr:`follow`, which
the controller hands to the wall-following term.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import StrEnum
from types import MappingProxyType

import numpy as np

from mpclab.errors import ConfigError, number
from mpclab.objectives.base import Objective
from mpclab.plants.base import Plant
from mpclab.registry import component
from mpclab.supervisors.base import FloatArray, Supervisor


class Bug2Mode(StrEnum):
    go_to_goal = "go_to_goal"
    wall_follow = "wall_follow"


#: the study's modes (eqs. 9 and 10); experiments name theirs in conf/supervisor/bug2.yaml
MODES: Mapping[str, Sequence[str]] = MappingProxyType(
    {"go_to_goal": ("J1", "J2", "J3", "J4"), "wall_follow": ("J3", "J4", "J5")})


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
    run_link
        Detected points nearer than this to each other belong to one boundary [m].
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
        run_link: float = 0.15,
        objective: Objective | None = None,
    ) -> None:
        given = dict(modes or MODES)
        valid = [m.value for m in Bug2Mode]
        if sorted(given) != sorted(valid):
            raise ConfigError(
                f"supervisor.modes must name exactly the modes {valid}, got {sorted(given)}"
            )
        self.modes = {Bug2Mode(k): frozenset(str(t) for t in v) for k, v in given.items()}
        if objective is not None:
            check_modes(given, list(objective.terms))
        self.block_range = number(block_range, "supervisor.block_range", above=0)
        self.corridor = number(corridor_half_width, "supervisor.corridor_half_width", above=0)
        self.mline_tol = number(mline_tolerance, "supervisor.mline_tolerance", above=0)
        self.leave_margin = number(leave_margin, "supervisor.leave_margin")
        self.sight = number(goal_sight_range, "supervisor.goal_sight_range (0: off)",
                            at_least=0)
        self.run_link = number(run_link, "supervisor.run_link", above=0)
        self._ip = [plant.state_index(s) for s in plant.position]
        self.mode = Bug2Mode.go_to_goal
        #: ((x_start, y_start), (x_goal, y_goal)), set by reset
        self.mline: tuple[tuple[float, float], tuple[float, float]] | None = None
        self.hit_point: FloatArray | None = None
        #: (t, x, y) of every switch into wall_follow
        self.hits: list[tuple[float, float, float]] = []
        self._last: FloatArray | None = None

    def reset(self, x0: FloatArray, goal: FloatArray) -> None:
        s = np.asarray(x0, dtype=float)[self._ip]
        g = np.asarray(goal, dtype=float)[self._ip]
        self.mline = ((float(s[0]), float(s[1])), (float(g[0]), float(g[1])))
        self._start, self._goal = s, g
        self.mode = Bug2Mode.go_to_goal
        self.hit_point = None
        self.hits = []
        self._last: FloatArray | None = None
        self._followed: FloatArray | None = None
        self.follow = None

    def update(
        self, t: float, x: FloatArray, detections: FloatArray
    ) -> tuple[str, frozenset[str] | None]:
        if self.mline is None:
            raise RuntimeError("Bug2.update called before reset")
        p = np.asarray(x, dtype=float)[self._ip]
        det = np.asarray(detections, dtype=float).reshape(-1, 2)
        labels = runs(det, self.run_link)
        if self.mode is Bug2Mode.go_to_goal:
            if self.blocked(p, det):
                self.mode = Bug2Mode.wall_follow
                self.hit_point = p.copy()
                self.hits.append((float(t), float(p[0]), float(p[1])))
                block = self.blocking(p, det)
                near = block[np.argmin(np.linalg.norm(det[block] - p, axis=1))]
                self._followed = det[labels == labels[near]]
        elif self.can_leave(p, self._last) or self.goal_in_sight(p, det):
            self.mode = Bug2Mode.go_to_goal
            self.hit_point = None
        elif len(det):  # the runs that touch the one followed before, else the nearest
            gap = np.array([np.min(np.linalg.norm(
                det[labels == r][:, None] - self._followed[None], axis=2))
                for r in range(labels.max() + 1)])
            keep = np.flatnonzero(gap < self.run_link)
            keep = keep if keep.size else [int(np.argmin(gap))]
            self._followed = det[np.isin(labels, keep)]
        if self.mode is Bug2Mode.wall_follow and self._followed is not None:
            self.follow = np.array([float(np.any(np.all(np.isclose(d, self._followed), axis=1)))
                                    for d in det])
        else:
            self.follow, self._followed = None, None
        self._last = p
        return self.mode.value, self.modes[self.mode]

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


def runs(points: FloatArray, link: float) -> np.ndarray:
    """Label ``(n,)`` of each point's run: the connected sets of points less than ``link``
    apart (labels 0, 1, ... in order of first appearance)."""
    n = len(points)
    labels = np.full(n, -1)
    if n == 0:
        return labels
    near = np.linalg.norm(points[:, None] - points[None], axis=2) < link
    run = 0
    for i in range(n):
        if labels[i] >= 0:
            continue
        stack, labels[i] = [i], run
        while stack:
            j = stack.pop()
            for k in np.flatnonzero(near[j] & (labels < 0)):
                labels[k] = run
                stack.append(k)
        run += 1
    return labels


def check_modes(modes: Mapping[str, Sequence[str]], terms: Sequence[str]) -> None:
    """Raise :class:`ConfigError` unless the modes name only the objective's terms and every
    term is named by some mode."""
    for mode, names in modes.items():
        for name in names:
            if name not in terms:
                raise ConfigError(
                    f"supervisor.modes.{mode} names the term {name!r}, which the objective does "
                    f"not have; objective terms: {', '.join(terms)}"
                )
    used = {str(n) for names in modes.values() for n in names}
    unused = [t for t in terms if t not in used]
    if unused:
        raise ConfigError(
            f"objective term(s) {', '.join(map(repr, unused))} named by no supervisor mode "
            f"would never be active; add them to supervisor.modes "
            f"({'; '.join(f'{m}: {list(n)}' for m, n in modes.items())}) or remove them "
            "from objective.terms"
        )
