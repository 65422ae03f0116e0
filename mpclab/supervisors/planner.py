"""A path planned on the map of what the range sensor has seen, replanned as it grows.

Navigation stacks (ROS move_base, Nav2, the BARN challenge's entries) pair a local controller
with a global planner on a map built from the sensor. This supervisor is that planner for
mpclab's controllers: every detected point is remembered on a grid of ``cell``; space not
seen is taken as free (an optimistic planner, as D* Lite, Koenig and Likhachev 2002, is
used on unknown terrain), and whenever a new cell is seen, the shortest path to the goal is
searched again (Dijkstra from the goal over the grid's sixteen neighbours,
``scipy.sparse.csgraph.dijkstra``). A cell's cost grows as it nears a seen point: by
``comfort_weight`` times the shortfall from ``comfort`` (as a fraction), and by
``BLOCKED_COST`` times within ``inflation`` (the robot with its margin does not fit there:
a way through such cells is taken only when no other is known).
Blocked cells are costly, not removed: a robot that has come within ``inflation`` of a point
still has a way out, and a goal behind a gap it cannot pass is still approached.

The path, from the robot to the goal, sampled every ``path_speed`` times the controller's
period, is the reference over the horizon (a tracking term follows it), with the heading of
the path (unwrapped to the robot's). The controller's obstacle constraint, not the plan,
keeps the robot off the obstacles; the plan only says which way round them.

The grid spans the box around start and goal widened by ``pad`` on every side; its edge is
a wall for the plan. In a finite world whose goal can be reached, each replan either reaches
the goal or sees more of the world, so the robot gets there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType

import numpy as np

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError, number
from mpclab.core.lazy_import import lazy_import
from mpclab.objectives.base import Objective
from mpclab.plants.base import Plant
from mpclab.supervisors.base import Arrival, FloatArray, Supervisor, mode_terms
from mpclab.supervisors.boundary import walk

# scipy's image and graph modules: paid only by runs that plan (composing imports every
# supervisor's module)
sparse = lazy_import("scipy.sparse")
ndimage = lazy_import("scipy.ndimage")
csgraph = lazy_import("scipy.sparse.csgraph")

#: the cost factor of a cell within ``inflation`` of a seen point (doubled at the point): a
#: way through such cells is taken only when no other is known, and a robot inside them
#: leaves by the nearest way out
BLOCKED_COST = 1.0e4


class PlannerMode(StrEnum):
    #: tracking the planned path
    follow_path = "follow_path"
    #: the rest of the path shorter than ``arrive_range``: the go-to-goal terms
    arrive = "arrive"


#: the terms each mode switches on (conf/supervisor/planner.yaml names them for the Zumo)
MODES: Mapping[str, Sequence[str]] = MappingProxyType(
    {"follow_path": ("Jp", "J2", "dU"), "arrive": ("J1", "J2", "J3", "dU")})

#: the grid's sixteen neighbour steps (eight; each edge is undirected): the knight's moves
#: with the king's keep a grid path within 3 % of a straight line's length (8 % with the
#: king's alone) without cutting through cells it does not cost
_STEPS = ((0, 1), (1, 0), (1, 1), (1, -1), (1, 2), (2, 1), (1, -2), (2, -1))


@dataclass(frozen=True)
class Grid:
    """A square grid of ``cell`` over a box, ``shape = (rows along y, columns along x)``."""

    x0: float
    y0: float
    cell: float
    shape: tuple[int, int]

    @classmethod
    def around(cls, a: FloatArray, b: FloatArray, pad: float, cell: float) -> Grid:
        """The grid over the box around points ``a`` and ``b`` widened by ``pad``."""
        lo = np.minimum(a, b) - pad
        hi = np.maximum(a, b) + pad
        cols, rows = (np.ceil((hi - lo) / cell).astype(int) + 1)
        return cls(float(lo[0]), float(lo[1]), float(cell), (int(rows), int(cols)))

    def index(self, points: FloatArray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(row, col, inside)`` of each of ``points`` ``(k, 2)``."""
        col = np.rint((points[:, 0] - self.x0) / self.cell).astype(int)
        row = np.rint((points[:, 1] - self.y0) / self.cell).astype(int)
        inside = (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        return row, col, inside

    def centres(self, flat: np.ndarray) -> FloatArray:
        """``(k, 2)``: the centres of the cells with flat indices ``flat``."""
        row, col = np.divmod(flat, self.shape[1])
        return np.c_[self.x0 + col * self.cell, self.y0 + row * self.cell]

    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(a, b, length)``: every pair of neighbouring cells once, by flat index, with
        the distance between their centres in cells."""
        rows, cols = self.shape
        idx = np.arange(rows * cols).reshape(rows, cols)
        a, b, length = [], [], []
        for dy, dx in _STEPS:
            src = idx[0:rows - dy, max(0, -dx):cols - max(0, dx)]
            dst = idx[dy:rows, max(0, dx):cols - max(0, -dx)]
            a.append(src.ravel())
            b.append(dst.ravel())
            length.append(np.full(src.size, np.hypot(dx, dy)))
        return np.concatenate(a), np.concatenate(b), np.concatenate(length)


def cell_costs(seen: np.ndarray, cell: float, inflation: float, comfort: float,
               weight: float) -> np.ndarray:
    """The cost factor of each cell (1 far from seen cells) from the mask ``seen`` of the
    cells holding a detected point (module docstring)."""
    if not seen.any():
        return np.ones(seen.shape)
    dist = ndimage.distance_transform_edt(~seen) * cell
    shortfall = np.clip((comfort - dist) / max(comfort - inflation, 1e-9), 0.0, 1.0)
    cost = 1.0 + weight * shortfall
    blocked = dist < inflation
    cost[blocked] = BLOCKED_COST * (2.0 - dist[blocked] / inflation)
    return cost


@component("supervisor", "planner", injected=("plant", "objective"))
class MapPlanner(Supervisor):
    """A path to the goal planned on the sensed map (module docstring).

    Parameters
    ----------
    plant
        Injected; its ``position`` labels locate the robot in the state, its ``heading``
        (if any) gets the path's direction.
    modes
        ``{follow_path: [term, ...], arrive: [term, ...]}``: the terms active while
        following the path, and once the rest of it is shorter than ``arrive_range``.
    path_speed
        The path is sampled at this speed times the controller's period [m/s].
    inflation
        Cells nearer than this to a seen point are blocked for the plan (the robot's radius
        with the obstacle constraint's margin) [m].
    comfort
        Cells nearer than this cost more, up to ``1 + comfort_weight`` at ``inflation`` [m].
    comfort_weight
        How much more a cell at ``inflation`` costs than a free one.
    arrive_range
        The mode is ``arrive`` while the rest of the path is shorter than this [m].
    commitment
        Cells within ``comfort`` of the last path cost this fraction less (not blocked
        ones): another way is taken only when it is that much cheaper. Without it, an
        optimistic planner turns back each time the side it took proves longer than the
        unseen other side promises, and the robot dithers.
    cell
        The grid's cell [m].
    pad
        How far the grid reaches beyond the box around start and goal [m].
    objective
        Injected; the mode's terms must be its terms, and each of its terms in the mode.
    """

    def __init__(
        self,
        plant: Plant,
        modes: Mapping[str, Sequence[str]] = MODES,
        path_speed: float = 0.15,
        inflation: float = 0.07,
        comfort: float = 0.12,
        comfort_weight: float = 4.0,
        arrive_range: float = 0.1,
        commitment: float = 0.3,
        cell: float = 0.02,
        pad: float = 1.0,
        objective: Objective | None = None,
    ) -> None:
        self.modes = mode_terms(modes or MODES, PlannerMode, objective)
        self.path_speed = number(path_speed, "supervisor.path_speed", above=0)
        self.inflation = number(inflation, "supervisor.inflation", above=0)
        self.comfort = number(comfort, "supervisor.comfort", at_least=self.inflation)
        self.comfort_weight = number(comfort_weight, "supervisor.comfort_weight", at_least=0)
        self.arrive_range = number(arrive_range, "supervisor.arrive_range", at_least=0)
        self.commitment = number(commitment, "supervisor.commitment", at_least=0)
        if self.commitment >= 1:
            raise ConfigError(f"supervisor.commitment: expected a fraction in [0, 1), got "
                              f"{commitment!r}")
        self.cell = number(cell, "supervisor.cell", above=0)
        self.pad = number(pad, "supervisor.pad", above=0)
        self._ip = [plant.state_index(s) for s in plant.position]
        self._ith = plant.state_index(plant.heading) if plant.heading else None

    def reset(self, x0: FloatArray, goal: FloatArray, arrived: Arrival | None = None) -> None:
        start = np.asarray(x0, dtype=float)[self._ip]
        self._goal = np.asarray(goal, dtype=float)[self._ip]
        self._goal_state = np.asarray(goal, dtype=float).copy()
        self.grid = Grid.around(start, self._goal, self.pad, self.cell)
        self._edges = self.grid.edges()
        self.seen = np.zeros(self.grid.shape, dtype=bool)
        row, col, inside = self.grid.index(self._goal[None])
        if not inside[0]:
            raise ConfigError("supervisor=planner: the goal lies outside the planner's grid")
        self._goal_cell = int(row[0] * self.grid.shape[1] + col[0])
        self._next: np.ndarray | None = None  # per cell, the next cell toward the goal
        self._route: np.ndarray | None = None  # the cells within comfort of the last path
        self._p = start
        self._line = np.vstack([start, self._goal])
        self._heading: float | None = None

    def update(
        self, t: float, x: FloatArray, detections: FloatArray
    ) -> tuple[str, frozenset[str] | None]:
        self._p = np.asarray(x, dtype=float)[self._ip]
        self._heading = None if self._ith is None else float(np.asarray(x)[self._ith])
        det = np.asarray(detections, dtype=float).reshape(-1, 2)
        row, col, inside = self.grid.index(det)
        new = ~self.seen[row[inside], col[inside]]
        if new.any() or self._next is None:
            self.seen[row[inside], col[inside]] = True
            self._plan()
        self._line = smooth(self.path())
        left = float(np.sum(np.linalg.norm(np.diff(self._line, axis=0), axis=1)))
        mode = PlannerMode.arrive if left < self.arrive_range else PlannerMode.follow_path
        return mode.value, self.modes[mode]

    def _plan(self) -> None:
        """Search the grid from the goal: each cell's next cell on its cheapest way there."""
        a, b, length = self._edges
        cost = cell_costs(self.seen, self.cell, self.inflation, self.comfort,
                          self.comfort_weight)
        if self._route is not None and self.commitment > 0:
            cost[self._route & (cost < BLOCKED_COST)] *= 1.0 - self.commitment
        cost = cost.ravel()
        n = cost.size
        weights = length * 0.5 * (cost[a] + cost[b])
        graph = sparse.csr_matrix((weights, (a, b)), shape=(n, n))
        _, pred = csgraph.dijkstra(graph, directed=False, indices=self._goal_cell,
                                   return_predecessors=True)
        self._next = pred
        path = np.zeros(self.grid.shape, dtype=bool)
        row, col, inside = self.grid.index(self.path())
        path[row[inside], col[inside]] = True
        self._route = ndimage.distance_transform_edt(~path) * self.cell < self.comfort

    def path(self) -> FloatArray:
        """``(k, 2)``: the planned path from the robot's position to the goal."""
        row, col, inside = self.grid.index(self._p[None])
        if not inside[0] or self._next is None:
            return np.vstack([self._p, self._goal])
        cells = [int(row[0] * self.grid.shape[1] + col[0])]
        while cells[-1] != self._goal_cell and cells[-1] >= 0 and len(cells) <= self._next.size:
            cells.append(int(self._next[cells[-1]]))
        if cells[-1] < 0:  # no way (the grid cut in two): straight at the goal
            return np.vstack([self._p, self._goal])
        line = self.grid.centres(np.asarray(cells[1:-1], dtype=int))
        return np.vstack([self._p, line, self._goal])

    def target(self, t: float, horizon: int, dt: float) -> FloatArray | None:
        """The goal state with its position moved along the planned path,
        ``path_speed * dt`` a step, and its heading the path's direction."""
        ahead = walk(self._line, 0, self.path_speed * dt, horizon)
        ref = np.tile(self._goal_state, (horizon + 1, 1))
        ref[0, self._ip] = self._p
        ref[1:, self._ip] = ahead[:, :2]
        if self._ith is not None:  # the path's direction, unwrapped from the robot's heading
            here = self._heading if self._heading is not None else float(ahead[0, 2])
            along = np.unwrap(np.concatenate([[here], ahead[:, 2]]))[1:]
            ref[:, self._ith] = np.r_[along[0], along]
        return ref


def smooth(line: FloatArray, passes: int = 3) -> FloatArray:
    """``line`` ``(k, 2)`` with its inner vertices averaged with their neighbours ``passes``
    times (a grid path's stair steps rounded; the ends kept)."""
    out = np.asarray(line, dtype=float).copy()
    for _ in range(passes):
        if len(out) < 3:
            break
        out[1:-1] = 0.25 * out[:-2] + 0.5 * out[1:-1] + 0.25 * out[2:]
    return out
