"""Disc obstacles: single discs, walls as rows of discs, and random layouts.

Every layout is an array ``(n, 3)`` of discs: centre x, centre y, radius [m].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.errors import ConfigError, check_keys, number

FloatArray = npt.NDArray[np.float64]


@dataclass
class WallConf:
    """A straight row of discs from ``start`` to ``end`` (both included)."""

    start: list[float] = field(default_factory=lambda: [0.0, 0.0])
    end: list[float] = field(default_factory=lambda: [0.0, 0.0])
    spacing: float = 0.05       # centre-to-centre [m]; below 2 radii the row has no gap


@dataclass
class RandomLayoutConf:
    """Random walls drawn from the run's seed (``n_walls: 0``: none)."""

    n_walls: int = 0
    length: list[float] = field(default_factory=lambda: [0.2, 0.5])    # [min, max] [m]
    region: list[float] = field(default_factory=lambda: [0.1, 0.7, 0.2, 1.0])  # x0 x1 y0 y1
    keep_clear: float = 0.15    # wall discs' centres stay this far from the start [m]
    goal_clear: float = 0.2     # ... and this far from the goal [m]
    min_gap: float = 0.35       # centre distance between discs of different walls [m]
    across: bool = True         # the first wall crosses the start-goal segment
    max_tries: int = 2000


def wall(start: Sequence[float], end: Sequence[float], spacing: float, radius: float) -> FloatArray:
    """Discs ``(n, 3)`` along the segment ``start -> end``, at most ``spacing`` apart."""
    if float(spacing) <= 0:
        raise ConfigError(f"wall spacing must be > 0, got {spacing}")
    a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    if a.shape != (2,) or b.shape != (2,):
        raise ConfigError(f"a wall needs start and end as [x, y], got {list(start)}, {list(end)}")
    n = int(np.ceil(np.linalg.norm(b - a) / float(spacing) - 1e-9)) + 1
    s = np.linspace(0.0, 1.0, n)[:, None]
    centres = a + s * (b - a)
    return np.column_stack([centres, np.full(n, float(radius))])


def layout(
    discs: Sequence[Sequence[float]],
    walls: Sequence[Mapping[str, Any]],
    radius: float,
) -> FloatArray:
    """The discs ``(n, 3)`` of single discs ``[[x, y], ...]`` and walls (see :class:`WallConf`)."""
    if float(radius) <= 0:
        raise ConfigError(f"obstacle radius must be > 0, got {radius}")
    parts = [np.zeros((0, 3))]
    for i, d in enumerate(discs):
        if len(d) != 2:
            raise ConfigError(f"scenario.discs[{i}] must be [x, y], got {list(d)}")
        parts.append(np.array([[number(d[0], f"scenario.discs[{i}][0]"),
                                number(d[1], f"scenario.discs[{i}][1]"), float(radius)]]))
    for i, w in enumerate(walls):
        check_keys(w, ("start", "end", "spacing"), where=f"scenario.walls[{i}]")
        parts.append(wall(w["start"], w["end"], float(w.get("spacing", 0.05)), radius))
    return np.concatenate(parts, axis=0)


def random_walls(
    rng: np.random.Generator,
    conf: Mapping[str, Any],
    radius: float,
    spacing: float,
    start: Sequence[float],
    goal: Sequence[float],
) -> FloatArray:
    """``conf["n_walls"]`` random straight walls, clear of ``keep_away`` points and each other.

    A wall's centre is uniform in ``region``, its angle uniform, its length uniform in
    ``length``; draws that come within ``keep_clear`` of the start, ``goal_clear`` of the
    goal or ``min_gap`` of another wall are redrawn (at most ``max_tries`` draws in all).
    With ``across``, the first wall crosses the segment from start to goal (at 38..45 % of
    the way, its middle third on the crossing) turned at most 30 degrees from square to it,
    so that it blocks the straight way.
    """
    c = RandomLayoutConf(**dict(conf))
    if c.n_walls <= 0:
        return np.zeros((0, 3))
    x0, x1, y0, y1 = (float(v) for v in c.region)
    a, b = np.asarray(start, dtype=float)[:2], np.asarray(goal, dtype=float)[:2]
    walls: list[FloatArray] = []
    for _ in range(int(c.max_tries)):
        if len(walls) == c.n_walls:
            break
        half = rng.uniform(*c.length) / 2
        if c.across and not walls:
            ang = np.arctan2(*(b - a)[::-1]) + np.pi / 2 + rng.uniform(-1, 1) * np.deg2rad(30)
            u = np.array([np.cos(ang), np.sin(ang)])
            centre = a + rng.uniform(0.38, 0.45) * (b - a) + rng.uniform(-1, 1) * half / 3 * u
        else:
            ang = rng.uniform(0.0, np.pi)
            u = np.array([np.cos(ang), np.sin(ang)])
            centre = rng.uniform([x0, y0], [x1, y1])
        w = wall(centre - half * u, centre + half * u, spacing, radius)
        if _min_dist(w[:, :2], a[None]) < c.keep_clear:
            continue
        if _min_dist(w[:, :2], b[None]) < c.goal_clear:
            continue
        if any(_min_dist(w[:, :2], o[:, :2]) < c.min_gap for o in walls):
            continue
        walls.append(w)
    if len(walls) < c.n_walls:
        raise ConfigError(
            f"could not place {c.n_walls} random walls in {c.max_tries} draws; "
            "enlarge scenario.random.region or lower keep_clear / goal_clear / min_gap"
        )
    return np.concatenate(walls, axis=0)


def _min_dist(a: FloatArray, b: FloatArray) -> float:
    if len(a) == 0 or len(b) == 0:
        return float("inf")
    return float(np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)))
