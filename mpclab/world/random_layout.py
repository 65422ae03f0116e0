"""Random obstacle layouts drawn from the run's seed, hard cases included, always solvable.

A layout is random straight walls (rows of discs; the first may cross the way from start to
goal, with a gap in it), and, each with its own probability, a wall running past the goal, a
corridor the goal lies in, and small isolated discs (small enough to fall between the range
sensor's rays). A layout in which the robot disc cannot reach the goal from the start
(:func:`mpclab.world.free_space.connected`) is drawn again from the same generator, so the
layout of a seed is always the same and always solvable.

Distances to keep are stated, as they always were, between the centres of discs of the
scenario's ``obstacle_radius``; a smaller isolated disc keeps the same distance from its
surface (the same surface gap).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mpclab.core.errors import ConfigError, check_keys
from mpclab.world.free_space import connected
from mpclab.world.obstacles import FloatArray, wall


@dataclass
class RandomLayoutConf:
    """Random walls and discs drawn from the run's seed (``n_walls: 0``, ``n_discs: 0`` and
    every probability 0: none)."""

    n_walls: int = 0
    length: list[float] = field(default_factory=lambda: [0.2, 0.5])    # [min, max] [m]
    region: list[float] = field(default_factory=lambda: [0.1, 0.7, 0.2, 1.0])  # x0 x1 y0 y1
    keep_clear: float = 0.15    # wall discs' centres stay this far from the start [m]
    goal_clear: float = 0.2     # ... and this far from the goal [m]
    min_gap: float = 0.35       # centre distance between discs of different walls [m]
    across: bool = True         # the first wall crosses the start-goal segment
    max_tries: int = 2000       # draws per layout for its walls (a tenth per other part)
    gap: float = 0.0            # probability that the crossing wall has a gap ...
    gap_width: list[float] = field(default_factory=lambda: [0.11, 0.2])  # ... this wide [m]
    goal_wall: float = 0.0      # probability of a wall past the goal ...
    goal_wall_gap: list[float] = field(default_factory=lambda: [0.06, 0.15])  # its surface [m]
    corridor: float = 0.0       # probability that the goal lies in a corridor ...
    corridor_width: list[float] = field(default_factory=lambda: [0.13, 0.3])  # surfaces [m]
    corridor_length: list[float] = field(default_factory=lambda: [0.3, 0.6])  # [m]
    n_discs: int = 0            # isolated discs ...
    disc_radius: list[float] = field(default_factory=lambda: [0.015, 0.05])  # [m]
    disc_on_path: float = 0.0   # probability that a disc sits near the start-goal segment
    solvable: bool = True       # redraw a layout the robot cannot drive through ...
    clearance: float = 0.0      # ... keeping this much from every obstacle [m]
    cell: float = 0.005         # grid cell of that check [m]
    max_layouts: int = 500


def random_layout(
    rng: np.random.Generator,
    conf: Mapping[str, Any],
    radius: float,
    spacing: float,
    start: Sequence[float],
    goal: Sequence[float],
    robot_radius: float = 0.0,
    extent: Sequence[float] = (-0.1, 1.3, -0.1, 1.3),
    fixed: FloatArray | None = None,
) -> FloatArray:
    """Discs ``(n, 3)`` of a random layout (see the module docstring and
    :class:`RandomLayoutConf`); with ``solvable``, one the robot disc can drive through from
    ``start`` to ``goal`` within ``extent`` together with the ``fixed`` discs."""
    check_keys(conf, [f for f in RandomLayoutConf.__dataclass_fields__], "scenario.layout.random")
    c = RandomLayoutConf(**dict(conf))
    fixed = np.zeros((0, 3)) if fixed is None else np.asarray(fixed, dtype=float)
    for _ in range(max(1, int(c.max_layouts))):
        discs = _draw(rng, c, float(radius), float(spacing), start, goal)
        if discs is None:  # a part found no place among the others: draw again
            continue
        if not c.solvable or connected(np.concatenate([fixed, discs]), start, goal,
                                       robot_radius + float(c.clearance), extent,
                                       cell=float(c.cell)):
            return discs
    raise ConfigError(
        f"scenario.layout.random: no layout of {c.max_layouts} drawn places every part and lets "
        f"the robot (radius {robot_radius:g} m, clearance {c.clearance:g} m) reach the goal; "
        "lower n_walls / n_discs / "
        "min_gap or widen the gaps"
    )


def random_walls(
    rng: np.random.Generator, conf: Mapping[str, Any], radius: float, spacing: float,
    start: Sequence[float], goal: Sequence[float],
) -> FloatArray:
    """One draw of the layout, solvable or not (:func:`random_layout` without the check);
    ``ConfigError`` if a part finds no place."""
    c = RandomLayoutConf(**dict(conf))
    discs = _draw(rng, c, radius, spacing, start, goal)
    if discs is None:
        raise ConfigError(f"scenario.layout.random: a part found no place in {c.max_tries} draws; "
                          "enlarge region or lower keep_clear / goal_clear / min_gap")
    return discs


class _Placer:
    """Accepts parts that keep their distances from the start, the goal and each other."""

    def __init__(self, c: RandomLayoutConf, radius: float, a: FloatArray, b: FloatArray):
        self.c, self.radius, self.a, self.b = c, radius, a, b
        self.parts: list[FloatArray] = []

    def fits(self, part: FloatArray, near_goal: bool = False) -> bool:
        c, r0 = self.c, self.radius
        if _gap(part, self.a[None]) < c.keep_clear - r0:
            return False
        if not near_goal and _gap(part, self.b[None]) < c.goal_clear - r0:
            return False
        return all(_gap(part, o, both=True) >= c.min_gap - 2 * r0 for o in self.parts)

    def add(self, *parts: FloatArray) -> None:
        self.parts.extend(p for p in parts if len(p))


def _draw(
    rng: np.random.Generator, c: RandomLayoutConf, radius: float, spacing: float,
    start: Sequence[float], goal: Sequence[float],
) -> FloatArray | None:
    """One layout, or None if a part found no place in ``max_tries`` draws."""
    a, b = np.asarray(start, dtype=float)[:2], np.asarray(goal, dtype=float)[:2]
    x0, x1, y0, y1 = (float(v) for v in c.region)
    put = _Placer(c, radius, a, b)
    n_walls = 0
    for _ in range(int(c.max_tries)):  # the walls, drawn as they always were
        if n_walls == c.n_walls:
            break
        half = rng.uniform(*c.length) / 2
        if c.across and n_walls == 0:
            ang = np.arctan2(*(b - a)[::-1]) + np.pi / 2 + rng.uniform(-1, 1) * np.deg2rad(30)
            u = np.array([np.cos(ang), np.sin(ang)])
            centre = a + rng.uniform(0.38, 0.45) * (b - a) + rng.uniform(-1, 1) * half / 3 * u
        else:
            ang = rng.uniform(0.0, np.pi)
            u = np.array([np.cos(ang), np.sin(ang)])
            centre = rng.uniform([x0, y0], [x1, y1])
        w = wall(centre - half * u, centre + half * u, spacing, radius)
        if not put.fits(w):
            continue
        if c.across and n_walls == 0 and c.gap > 0 and rng.uniform() < c.gap:
            put.add(*_with_gap(rng, c, centre, u, half, a, b, spacing, radius))
        else:
            put.add(w)
        n_walls += 1
    if n_walls < c.n_walls:
        raise ConfigError(
            f"could not place {c.n_walls} random walls in {c.max_tries} draws; "
            "enlarge scenario.layout.random.region or lower keep_clear / goal_clear / min_gap"
        )
    placed = True
    if c.goal_wall > 0 and rng.uniform() < c.goal_wall:
        placed = _place(put, lambda: [_goal_wall(rng, c, b, spacing, radius)], c)
    if placed and c.corridor > 0 and rng.uniform() < c.corridor:
        placed = _place(put, lambda: _corridor(rng, c, b, spacing, radius), c)
    for _ in range(int(c.n_discs)):
        placed = placed and _place(put, lambda: [_disc(rng, c, a, b, radius)], c,
                                   near_goal=False)
    if not placed:
        return None
    return np.concatenate([np.zeros((0, 3)), *put.parts], axis=0)


def _place(put: _Placer, draw: Any, c: RandomLayoutConf, near_goal: bool = True) -> bool:
    """Draw ``draw()`` (a list of parts) until every part fits and add them (False: none
    fitted in ``max_tries`` draws); parts ``near_goal`` on purpose need not keep
    ``goal_clear``."""
    for _ in range(max(1, int(c.max_tries) // 10)):
        parts = draw()
        if all(put.fits(p, near_goal=near_goal) for p in parts):
            put.add(*parts)
            return True
    return False


def _with_gap(
    rng: np.random.Generator, c: RandomLayoutConf, centre: FloatArray, u: FloatArray,
    half: float, a: FloatArray, b: FloatArray, spacing: float, radius: float,
) -> list[FloatArray]:
    """The crossing wall in two, with a gap between the discs' surfaces of ``gap_width``
    about where the start-goal line crosses it (up to a third of the wall aside)."""
    width = rng.uniform(*c.gap_width)
    d = b - a
    cross = _cross(d, centre - a) / _cross(u, d)  # centre + cross u is on the line
    s = float(np.clip(cross + rng.uniform(-1, 1) * half / 3, -half, half))
    ends = (s - width / 2 - radius, s + width / 2 + radius)
    parts = []
    if ends[0] > -half:
        parts.append(wall(centre - half * u, centre + ends[0] * u, spacing, radius))
    if ends[1] < half:
        parts.append(wall(centre + ends[1] * u, centre + half * u, spacing, radius))
    return parts


def _goal_wall(
    rng: np.random.Generator, c: RandomLayoutConf, b: FloatArray, spacing: float,
    radius: float,
) -> FloatArray:
    """A wall whose surface passes ``goal_wall_gap`` from the goal, on a random side."""
    ang = rng.uniform(-np.pi, np.pi)
    n, t = np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])
    half = rng.uniform(*c.length) / 2
    mid = b + (rng.uniform(*c.goal_wall_gap) + radius) * n + rng.uniform(-0.5, 0.5) * half * t
    return wall(mid - half * t, mid + half * t, spacing, radius)


def _corridor(
    rng: np.random.Generator, c: RandomLayoutConf, b: FloatArray, spacing: float,
    radius: float,
) -> list[FloatArray]:
    """Two parallel walls ``corridor_width`` apart (surfaces), the goal between them."""
    ang = rng.uniform(-np.pi, np.pi)
    n, t = np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])
    half = rng.uniform(*c.corridor_length) / 2
    off = rng.uniform(-0.6, 0.6) * half  # the goal somewhere along it, not at an open end
    side = rng.uniform(*c.corridor_width) / 2 + radius
    return [wall(b + k * side * n + (off - half) * t, b + k * side * n + (off + half) * t,
                 spacing, radius) for k in (-1, 1)]


def _disc(
    rng: np.random.Generator, c: RandomLayoutConf, a: FloatArray, b: FloatArray,
    radius: float,
) -> FloatArray:
    """An isolated disc of radius in ``disc_radius``: near the start-goal segment (past its
    middle) with probability ``disc_on_path``, else anywhere in ``region``."""
    r = rng.uniform(*c.disc_radius)
    if c.disc_on_path > 0 and rng.uniform() < c.disc_on_path:
        d = b - a
        normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        centre = a + rng.uniform(0.55, 0.8) * d + rng.uniform(-0.06, 0.06) * normal
    else:
        x0, x1, y0, y1 = (float(v) for v in c.region)
        centre = rng.uniform([x0, y0], [x1, y1])
    return np.array([[centre[0], centre[1], r]])


def _cross(p: FloatArray, q: FloatArray) -> float:
    return float(p[0] * q[1] - p[1] * q[0])


def _gap(a: FloatArray, b: FloatArray, both: bool = False) -> float:
    """Least surface gap between the discs ``a`` ``(n, 3)`` and the points or discs ``b``."""
    if len(a) == 0 or len(b) == 0:
        return float("inf")
    d = np.linalg.norm(a[:, None, :2] - b[None, :, :2], axis=2) - a[:, None, 2]
    if both:
        d = d - b[None, :, 2]
    return float(np.min(d))
