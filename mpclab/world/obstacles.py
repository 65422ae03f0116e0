"""Disc obstacles: single discs and walls as rows of discs (random ones: ``random_layout``).

Every layout is an array ``(n, 3)`` of discs: centre x, centre y, radius [m].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.core.errors import ConfigError, check_keys, number

FloatArray = npt.NDArray[np.float64]


@dataclass
class WallConf:
    """A straight row of discs from ``start`` to ``end`` (both included)."""

    start: list[float] = field(default_factory=lambda: [0.0, 0.0])
    end: list[float] = field(default_factory=lambda: [0.0, 0.0])
    spacing: float = 0.05       # centre-to-centre [m]; below 2 radii the row has no gap


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


def obstacle_discs(
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
            raise ConfigError(f"scenario.layout.discs[{i}] must be [x, y], got {list(d)}")
        parts.append(np.array([[number(d[0], f"scenario.layout.discs[{i}][0]"),
                                number(d[1], f"scenario.layout.discs[{i}][1]"), float(radius)]]))
    for i, w in enumerate(walls):
        check_keys(w, ("start", "end", "spacing"), where=f"scenario.layout.walls[{i}]")
        parts.append(wall(w["start"], w["end"], float(w.get("spacing", 0.05)), radius))
    return np.concatenate(parts, axis=0)
