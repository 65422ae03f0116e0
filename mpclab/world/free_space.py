"""Is a layout solvable? Start and goal connected in the free space of a robot disc.

The plane (the scenario's extent) is a grid of square cells; a cell is free when its centre
keeps ``robot_radius + margin`` from every obstacle disc, and the free cells are labelled by
4-connectivity. Two neighbouring free centres are ``cell`` apart, and the distance to a disc
changes no faster than one moves, so the straight step between them keeps at least
``robot_radius + margin - cell / 2``: with ``margin >= cell / 2`` a chain of free cells from
start to goal is a path the robot disc can drive without touching anything. The check is
conservative: a gap is certainly found passable from ``2 (robot_radius + margin) + cell``
wide (0.11 m for the Zumo with the defaults), and may be refused below that.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from mpclab.core.lazy_import import lazy_import

ndimage = lazy_import("scipy.ndimage")  # 0.25 s to import: paid by random layouts only

FloatArray = npt.NDArray[np.float64]


def free_cells(
    discs: FloatArray, extent: Sequence[float], keep: float, cell: float,
) -> tuple[npt.NDArray[np.bool_], FloatArray, FloatArray]:
    """``(free, xs, ys)``: whether each cell's centre keeps ``keep`` from every disc
    (``free[i, j]`` for the centre ``(xs[j], ys[i])``)."""
    x0, x1, y0, y1 = (float(v) for v in extent)
    xs = np.arange(x0 + cell / 2, x1, cell)
    ys = np.arange(y0 + cell / 2, y1, cell)
    free = np.ones((len(ys), len(xs)), dtype=bool)
    for cx, cy, r in np.asarray(discs, dtype=float).reshape(-1, 3):
        reach = r + keep
        j0, j1 = np.searchsorted(xs, [cx - reach, cx + reach])
        i0, i1 = np.searchsorted(ys, [cy - reach, cy + reach])
        if j0 >= j1 or i0 >= i1:
            continue
        dx = xs[j0:j1][None, :] - cx
        dy = ys[i0:i1][:, None] - cy
        free[i0:i1, j0:j1] &= dx**2 + dy**2 >= reach**2
    return free, xs, ys


def _fill_runs(free: npt.NDArray[np.bool_], reach: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """The free cells of every run of free cells along a row that holds a reached cell."""
    start = free.copy()
    start[:, 1:] &= ~free[:, :-1]  # a run starts where the cell to its left is not free
    ids = np.cumsum(start.ravel()).reshape(free.shape)
    hit = np.zeros(int(ids[-1, -1]) + 1, dtype=bool)
    hit[ids[reach & free]] = True
    return free & hit[ids]


def reachable(free: npt.NDArray[np.bool_], seeds: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """The free cells 4-connected to a free cell of ``seeds``: whole runs of free cells are
    filled along the rows, then along the columns, until nothing changes (as many rounds as
    the paths have turns; numpy alone: no scipy import for a run without a random layout)."""
    reach = free & seeds
    while True:
        grown = _fill_runs(free.T, _fill_runs(free, reach).T).T
        if np.array_equal(grown, reach):
            return reach
        reach = grown


def connected(
    discs: FloatArray, start: Sequence[float], goal: Sequence[float], robot_radius: float,
    extent: Sequence[float], cell: float = 0.005, margin: float | None = None,
) -> bool:
    """Whether a robot disc of ``robot_radius`` can drive from ``start`` to ``goal``
    (``[x, y]``) without touching a disc, staying inside ``extent = [x0, x1, y0, y1]``
    (see the module docstring; ``margin`` defaults to ``cell / 2``)."""
    margin = cell / 2 if margin is None else float(margin)
    free, xs, ys = free_cells(discs, extent, robot_radius + margin, cell)
    ends = []
    for p in (start, goal):
        j, i = int(np.argmin(np.abs(xs - p[0]))), int(np.argmin(np.abs(ys - p[1])))
        if not free[i, j]:
            return False
        ends.append((i, j))
    labels, _ = ndimage.label(free)  # 4-connectivity
    return bool(labels[ends[0]] == labels[ends[1]])
