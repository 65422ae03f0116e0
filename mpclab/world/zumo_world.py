"""A scenario with disc obstacles, a range sensor, collisions and a stall rule (Study B)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError, check_keys, number
from mpclab.plants.base import Plant
from mpclab.world.free_space import free_cells, reachable
from mpclab.world.obstacles import WallConf, obstacle_discs
from mpclab.world.random_layout import RandomLayoutConf, random_layout
from mpclab.world.scenario import FloatArray, Scenario, ScenarioConf
from mpclab.world.sensor import RangeSensor, SensorConf


@dataclass
class StallConf:
    """Stalled when over the last ``window_s`` the distance to the goal fell by less than
    ``min_progress_m`` and the robot stayed within ``max_displacement_m`` of where it was
    all that time (``null``: progress alone decides, so a detour away from the goal counts
    as a stall)."""

    window_s: float = 4.0
    min_progress_m: float = 0.01
    max_displacement_m: float | None = 0.05


@dataclass
class LayoutConf:
    """Where the obstacles are (``scenario.layout``)."""

    obstacle_radius: float = 0.05
    discs: list[list[float]] = field(default_factory=list)
    walls: list[WallConf] = field(default_factory=list)
    random: RandomLayoutConf = field(default_factory=RandomLayoutConf)
    extent: list[float] = field(default_factory=lambda: [-0.1, 1.3, -0.1, 1.3])


@dataclass
class RandomStartConf:
    """A start drawn from the run's seed (``scenario.random_start``)."""

    region: dict[str, list[float]] = field(default_factory=dict)
    clearance: float = 0.0


@dataclass
class ObstacleScenarioConf(ScenarioConf):
    _target_: str = "mpclab.world.zumo_world.ObstacleScenario"
    layout: LayoutConf = field(default_factory=LayoutConf)
    robot_radius: float = 0.05
    sensor: SensorConf = field(default_factory=SensorConf)
    stall: StallConf = field(default_factory=StallConf)
    random_start: RandomStartConf = field(default_factory=RandomStartConf)


def _draws_anything(random: Mapping[str, Any]) -> bool:
    """Whether a ``random`` section places any obstacle."""
    return any(float(random.get(key, 0) or 0) > 0
               for key in ("n_walls", "n_discs", "goal_wall", "corridor"))


def _random_radii(random: Mapping[str, Any], obstacle_radius: float) -> set[float]:
    """The disc radii a random layout may draw: its walls' and its isolated discs'."""
    out = set()
    if any(float(random.get(k, 0) or 0) > 0 for k in ("n_walls", "goal_wall", "corridor")):
        out.add(obstacle_radius)
    if float(random.get("n_discs", 0) or 0) > 0:
        lo, hi = (float(v) for v in random.get("disc_radius", RandomLayoutConf().disc_radius))
        out |= {float(r) for r in np.linspace(lo, hi, 4)}
    return out


@component("scenario", "obstacles", ObstacleScenarioConf)
class ObstacleScenario(Scenario):
    """Start, goal and a world of disc obstacles seen through a range sensor.

    Parameters
    ----------
    plant
        Injected; its ``position`` and ``heading`` labels locate the robot.
    name, start, goal, arrival, t_max
        As :class:`~mpclab.world.scenario.Scenario`.
    layout
        Where the obstacles are (:class:`LayoutConf`): ``obstacle_radius`` (of every disc,
        [m]), ``discs`` (single discs ``[[x, y], ...]``), ``walls`` (rows of discs
        ``[{start: [x, y], end: [x, y], spacing: s}, ...]``), ``random`` (random walls and
        discs added from ``rng``, redrawn until solvable:
        :class:`~mpclab.world.random_layout.RandomLayoutConf`) and ``extent``
        (``[x0, x1, y0, y1]``, the field drawn in figures and random layouts, [m]).
    robot_radius
        The robot is a disc of this radius; overlapping an obstacle is a collision [m].
    sensor
        ``{n_rays, max_range, offset_deg}`` of the range sensor.
    stall
        ``{window_s, min_progress_m, max_displacement_m}`` (see :class:`StallConf`).
    random_start
        ``{region: {state label: [low, high]}, clearance}``: when ``region`` is given, those
        start values are drawn uniformly from ``rng`` (the run's seed), redrawn until the
        robot is at least ``clearance`` from every obstacle and not already at the goal.
    rng
        Injected random generator (from the run's ``seed``), used by ``random``.
    """

    def __init__(
        self,
        plant: Plant,
        name: str,
        start: Mapping[str, float],
        goal: Mapping[str, float],
        arrival: Mapping[str, Any],
        t_max: float = 30.0,
        layout: Mapping[str, Any] | None = None,
        robot_radius: float = 0.05,
        sensor: Mapping[str, Any] | None = None,
        stall: Mapping[str, Any] | None = None,
        random_start: Mapping[str, Any] | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        super().__init__(plant, name, start, goal, arrival, t_max)
        if plant.heading is None:
            raise ConfigError(f"scenario {name!r} needs a plant with a heading for its sensor")
        self._ip = [plant.state_index(s) for s in plant.position]
        self._ih = plant.state_index(plant.heading)
        self.robot_radius = number(robot_radius, "scenario.robot_radius", at_least=0)
        where = dict(layout or {})
        check_keys(where, [f.name for f in fields(LayoutConf)], "scenario.layout")
        obstacle_radius = where.get("obstacle_radius", LayoutConf.obstacle_radius)
        number(obstacle_radius, "scenario.layout.obstacle_radius", above=0)
        walls = where.get("walls") or ()
        spacing = min((float(w.get("spacing", 0.05)) for w in walls), default=0.05)
        obs = obstacle_discs(where.get("discs") or (), walls, obstacle_radius)
        radii = {float(r) for r in obs[:, 2]}
        self.extent = [float(v) for v in where.get("extent", LayoutConf().extent)]
        random = where.get("random")
        if random is not None and _draws_anything(random):
            if rng is None:
                raise ConfigError(f"scenario {name!r}: random obstacles need the run's rng")
            extra = random_layout(
                rng, random, obstacle_radius, spacing,
                start=self.x0[self._ip], goal=self.goal[self._ip],
                robot_radius=self.robot_radius, extent=self.extent, fixed=obs,
            )
            obs = np.concatenate([obs, extra], axis=0)
            radii |= _random_radii(random, float(obstacle_radius))
        self._radii = tuple(sorted(radii))
        #: obstacle discs (n, 3): centre x, centre y, radius [m]
        self.obstacles = obs
        self.sensor = RangeSensor(**dict(sensor or {}))
        self.stall_rule = StallConf(**dict(stall or {}))
        if self.stall_rule.window_s <= 0:
            raise ConfigError(
                f"scenario.stall.window_s must be > 0, got {self.stall_rule.window_s}"
            )
        start = dict(random_start or {})
        check_keys(start, [f.name for f in fields(RandomStartConf)], "scenario.random_start")
        if start.get("region"):
            if rng is None:
                raise ConfigError(f"scenario {name!r}: a random start needs the run's rng")
            self.x0 = self._random_start(dict(start["region"]),
                                         float(start.get("clearance", 0.0)), rng)
        for what, x in (("start", self.x0), ("goal", self.goal)):
            self._check_clear(what, x)

    def _check_clear(self, what: str, x: FloatArray) -> None:
        """Raise :class:`ConfigError` if the robot at ``x`` overlaps an obstacle."""
        gap = self.clearance(x)
        if gap < 0:
            p = np.asarray(x)[self._ip]
            i = int(np.argmin(np.linalg.norm(self.obstacles[:, :2] - p, axis=1)
                              - self.obstacles[:, 2]))
            cx, cy, r = self.obstacles[i]
            raise ConfigError(
                f"scenario.{what}: the robot (radius {self.robot_radius:g} m) at "
                f"({p[0]:g}, {p[1]:g}) overlaps the obstacle at ({cx:g}, {cy:g}) (radius "
                f"{r:g} m) by {-gap:.3g} m; a {what} must be clear of every obstacle"
            )

    def _random_start(
        self, region: dict[str, Sequence[float]], clearance: float, rng: np.random.Generator
    ) -> FloatArray:
        idx, lo, hi = [], [], []
        for label, (a, b) in region.items():
            try:
                idx.append(self.plant.state_index(label))
            except ValueError as exc:
                raise ConfigError(f"scenario.random_start.region: {exc}") from None
            lo.append(float(a))
            hi.append(float(b))
        for _ in range(10_000):
            x0 = self.x0.copy()
            x0[idx] = rng.uniform(lo, hi)
            if not self.arrived(x0) and not (self.clearance(x0) < clearance):
                return x0
        raise ConfigError(f"scenario {self.name!r}: no start in {region} keeps {clearance} m "
                          "from the obstacles")

    def stated_obstacle_radii(self) -> tuple[float, ...]:
        """The radii of the discs the layout states it may hold: its discs' and walls', and
        for random ones the walls' and isolated discs' (their range at four points), whatever
        this seed drew (the obstacle margin is derived from them: :mod:`mpclab.world.margin`)."""
        return self._radii

    def way_to_goal(self, keep: float, cell: float = 0.0025) -> bool:
        """Whether the robot's centre can go from the start to within the arrival radius of
        the goal keeping ``keep`` from every obstacle's surface, on a grid of ``cell`` (a
        passage is found from ``2 keep + cell`` wide; a start nearer than ``keep`` to an
        obstacle may first move away by up to ``keep``). True where the arrival rule weighs
        no position."""
        w = np.array([self._arrival_w[i] for i in self._ip])
        if not (w > 0).any():
            return True
        arrival = math.sqrt(self.arrival_threshold / float(w.max()))
        free, xs, ys = free_cells(self.obstacles, self.extent, keep, cell)
        gx, gy = np.meshgrid(xs, ys)
        (sx, sy), (ex, ey) = self.x0[self._ip], self.goal[self._ip]
        start = np.hypot(gx - sx, gy - sy) <= keep + cell
        goal = np.hypot(gx - ex, gy - ey) <= arrival
        return bool((reachable(free, start) & goal).any())

    # ---------------------------------------------------------------- world hooks
    def pose(self, x: FloatArray) -> FloatArray:
        """``(x, y, theta)`` of state ``x``."""
        x = np.asarray(x, dtype=float)
        return np.array([x[self._ip[0]], x[self._ip[1]], x[self._ih]])

    def detect(self, x: FloatArray) -> FloatArray:
        return self.sensor.detect(self.pose(x), self.obstacles)

    def ranges(self, x: FloatArray) -> FloatArray:
        """Range of every ray ``(n_rays,)`` [m], ``inf`` where a ray sees nothing."""
        return self.sensor.distances(self.pose(x), self.obstacles)

    def sense(
        self, x: FloatArray, believed: FloatArray | None = None,
        perturb: Callable[[FloatArray], FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Detected points and every ray's range, from one sensor evaluation at the true
        pose; the points placed from the ``believed`` pose, the ranges ``perturb``-ed."""
        pose = self.pose(x)
        ranges = self.sensor.distances(pose, self.obstacles)
        if perturb is not None:
            ranges = perturb(ranges)
        seen_from = pose if believed is None else self.pose(believed)
        return self.sensor.points(seen_from, ranges)[np.isfinite(ranges)], ranges

    def rays(self, x: FloatArray) -> FloatArray:
        """Ray end points ``(n_rays, 2)``: the hit point, or the point at maximum range."""
        return self.sensor.end_points(self.pose(x), self.obstacles)[0]

    def clearance(self, x: FloatArray) -> float:
        if len(self.obstacles) == 0:
            return float("nan")
        p = np.asarray(x, dtype=float)[self._ip]
        gaps = np.linalg.norm(self.obstacles[:, :2] - p, axis=1) - self.obstacles[:, 2]
        return float(gaps.min() - self.robot_radius)

    def collided(self, x: FloatArray) -> bool:
        return bool(len(self.obstacles)) and self.clearance(x) < 0

    def goal_distance(self, x: FloatArray) -> float:
        p = np.asarray(x, dtype=float)[self._ip]
        return float(np.linalg.norm(p - self.goal[self._ip]))

    def stalled(self, t: list[float], xs: list[FloatArray]) -> bool:
        rule = self.stall_rule
        if not t or t[-1] - t[0] < rule.window_s - 1e-9:
            return False
        i = int(np.searchsorted(np.asarray(t), t[-1] - rule.window_s - 1e-9))
        progress = self.goal_distance(xs[i]) - self.goal_distance(xs[-1])
        if progress >= rule.min_progress_m:
            return False
        if rule.max_displacement_m is None:
            return True
        # stayed near where it was the whole window: a robot that drove off and came back
        # (a U-turn at a blocked gap) moved, it did not stall
        window = np.asarray(xs[i:])[:, self._ip]
        moved = np.linalg.norm(window - window[0], axis=1).max()
        return bool(moved < rule.max_displacement_m)

    def metrics(self, steps: Any, outcome: Mapping[str, Any]) -> dict[str, Any]:
        """Besides the distances: how the path turned and how often each input changed sign
        (per simulated second; zero inputs skipped), the marks of a loop or of chatter."""
        xs = steps[list(self.plant.position)].to_numpy(dtype=float)
        g = self.goal[self._ip]
        heading = steps[self.plant.heading].to_numpy(dtype=float)
        turned = heading - heading[0]
        t_end = float(steps["t"].iloc[-1]) if len(steps) else 0.0
        flips = {}
        for label in self.plant.inputs:
            u = steps[label].to_numpy(dtype=float)
            sign = np.sign(u[np.isfinite(u) & (np.abs(u) > 1e-6)])
            n = int(np.sum(sign[1:] != sign[:-1]))
            flips[f"{label}_sign_changes_per_s"] = n / t_end if t_end > 0 else None
        return {
            "n_obstacles": int(len(self.obstacles)),
            "min_goal_distance_m": float(np.min(np.linalg.norm(xs - g, axis=1))),
            "path_length_m": float(np.sum(np.linalg.norm(np.diff(xs, axis=0), axis=1))),
            "heading_change_rad": float(turned[-1]),
            "max_heading_change_rad": float(np.max(np.abs(turned))),
            **flips,
        }

    # ---------------------------------------------------------------- figures
    def draw(self, ax: Any) -> None:
        """Obstacle discs (black) on a matplotlib axis, with the world's extent."""
        from matplotlib.patches import Circle

        for i, (cx, cy, r) in enumerate(self.obstacles):  # one legend entry: a patch
            ax.add_patch(Circle((cx, cy), r, color="k", alpha=0.85, lw=0,
                                label=None if i else "obstacles"))
        x0, x1, y0, y1 = self.extent
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
