"""The obstacle margin, derived from the bounds the world states (``summary.json``'s ``margin``).

The obstacle constraint keeps every predicted position a distance ``R`` from every point
the range sensor detected (:class:`mpclab.constraints.obstacle.ObstacleDistance`). ``R`` is
the sum of parts, each computed from what the run's configs state, at build time, before
the controller is built:

* ``robot_radius``: the robot's disc (``scenario.robot_radius``).
* ``rays``: how much nearer the true surface of a disc obstacle can be to the next
  predicted position than the nearest point the rays found on it. The rays (``n_rays`` of
  them, ``max_range`` long) sample a disc's surface; between two of them the surface bulges
  towards the robot, and the robot, having moved up to ``travel`` (its farthest move in one
  period at the input bounds) since the scan, may face that bulge. The worst case over the
  disc's place, the rays' angle and the position reached, among positions that keep ``R``
  from the detected points, is found on a grid, for every obstacle radius the scenario
  states (``scenario.layout``: its discs, walls and random discs' radii). A disc that no
  ray meets is not covered: ``blind_range`` says how near one can come unseen.
* ``between_samples``: the constraint holds at the sampled positions; between two of them
  the path may pass nearer a point: for a straight move of ``c`` between two positions that
  keep ``R``, ``R - sqrt(R^2 - c^2 / 4)``, plus how far the path bows off its chord (the
  worst over a grid of constant inputs in the input bounds, integrated by the plant model).
* ``noise``: the range noise (``sim.noise.range_std``) and the position random walk over
  one period (``sim.disturbance.state_std``, per square-root second), as one Gaussian along
  the line to the obstacle, at the one-sided quantile of ``sim.noise.confidence``. Noise on
  the pose the controller sees moves the robot and the points placed from it together: the
  detected geometry relative to the robot, all the constraint uses, does not change, and it
  takes no part.
* ``latency``: how far the position after one period can be from the model's prediction
  when the input acts ``tau`` late (the previous input holds until then), the worst over the
  input bounds' corners, ``tau`` the stated latency's largest (a fixed latency, a recorded
  profile's maximum, times ``sim.timing.latency_scale``, at most one period); with delay
  compensation the error of the expected latency against the largest and the smallest.
  ``one_sample`` predicts exactly: 0. ``measured`` and ``modelled`` latencies are not stated
  before the run: ``not_covered`` says so.
* ``model_mismatch``: the simulated plant's parameters (``sim.plant_params``, ``substeps``)
  against the model's: the largest difference of one period's position over a grid of inputs.
* ``estimate``: 0, for the reason given under ``noise``: points are placed from the estimate
  the controller plans from (odometry, an EKF), so its error moves both together.

``rays`` and ``between_samples`` grow with ``R``: the total is their fixed point. What the
budget does not cover (actuator lags, a disc between the rays, unstated latencies) is listed
in ``not_covered``.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import numpy as np

from mpclab.constraints.obstacle import NoRoom
from mpclab.core.errors import ConfigError
from mpclab.plants.base import FloatArray, Plant
from mpclab.world.latency import Latency
from mpclab.world.sensor import ray_disc_distances

#: inputs per bound interval of the grid the travel and the path's bow are taken over
_INPUT_GRID = 5
#: pieces a period's path is cut into to find how far it bows off its chord
_PATH_PIECES = 8


@dataclass(frozen=True)
class MarginBudget:
    """The parts of the obstacle margin [m] and their total (module docstring)."""

    robot_radius: float
    rays: float
    between_samples: float
    noise: float
    latency: float
    model_mismatch: float
    estimate: float = 0.0
    #: the one-sided confidence the noise part is taken at
    confidence: float = 0.95
    #: the farthest move in one period at the input bounds [m]
    travel: float = 0.0
    #: how near the robot can come to the smallest stated disc that no ray meets [m]
    blind_range: float | None = None
    #: what the budget does not cover, in words
    not_covered: tuple[str, ...] = field(default=())

    PARTS = ("robot_radius", "rays", "between_samples", "noise", "latency",
             "model_mismatch", "estimate")

    @property
    def total(self) -> float:
        return float(sum(getattr(self, p) for p in self.PARTS))

    def parts(self) -> dict[str, float]:
        return {p: float(getattr(self, p)) for p in self.PARTS}

    def describe(self) -> dict[str, Any]:
        """The summary's ``margin``: the parts, the total and what they rest on."""
        return {"total_m": self.total, **{f"{k}_m": v for k, v in self.parts().items()},
                "confidence": self.confidence, "travel_m": self.travel,
                "blind_range_m": self.blind_range, "not_covered": list(self.not_covered)}

    def sentence(self) -> str:
        """``0.0712 m = robot_radius 0.05 + rays 0.0137 + ...`` (the non-zero parts)."""
        parts = " + ".join(f"{k} {v:.4g}" for k, v in self.parts().items() if v > 0)
        return f"{self.total:.4g} m = {parts}"


def _input_grid(plant: Plant, n: int = _INPUT_GRID) -> FloatArray:
    """Inputs on a grid of ``n`` per input over the input bounds ``(m, nu)``."""
    lo, hi = np.asarray(plant.u_lb, dtype=float), np.asarray(plant.u_ub, dtype=float)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        free = [u for u, a, b in zip(plant.inputs, lo, hi, strict=True)
                if not (math.isfinite(a) and math.isfinite(b))]
        raise ConfigError(
            f"plant.input_bounds: the obstacle margin's motion between samples needs finite "
            f"bounds on every input; {', '.join(free)} unbounded (plant.input_bounds.<input>="
            "[lo, hi])")
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi, strict=True)]
    return np.array(list(itertools.product(*axes)), dtype=float)


def _corners(plant: Plant) -> FloatArray:
    return _input_grid(plant, 2)


def _position(plant: Plant, x: FloatArray) -> FloatArray:
    return np.array([x[plant.state_index(s)] for s in plant.position])


def _path(plant: Plant, x0: FloatArray, u: FloatArray, dt: float) -> FloatArray:
    """Positions ``(pieces + 1, 2)`` along one period under the constant input ``u``."""
    points, x = [_position(plant, x0)], x0
    for _ in range(_PATH_PIECES):
        x = plant.step(x, u, dt / _PATH_PIECES)
        points.append(_position(plant, x))
    return np.array(points)


def _chord_and_bow(path: FloatArray) -> tuple[float, float]:
    """The straight distance from the path's start to its end, and the farthest the path
    strays from that segment."""
    a, b = path[0], path[-1]
    ab = b - a
    length = float(np.hypot(*ab))
    if length < 1e-12:
        return 0.0, float(np.max(np.hypot(*(path - a).T)))
    s = np.clip((path - a) @ ab / length**2, 0.0, 1.0)
    off = path - (a + s[:, None] * ab)
    return length, float(np.max(np.hypot(off[:, 0], off[:, 1])))


def motion(plant: Plant, x0: FloatArray, dt: float) -> tuple[float, list[tuple[float, float]]]:
    """``(travel, [(chord, bow), ...])``: the farthest one period's move at the input bounds
    and every grid input's chord and bow (module docstring)."""
    moves = [_chord_and_bow(_path(plant, x0, u, dt)) for u in _input_grid(plant)]
    return max(c for c, _ in moves), moves


def between_samples(R: float, moves: Iterable[tuple[float, float]]) -> float:
    """How much nearer than ``R`` a path can pass a point both its ends keep ``R`` from."""
    worst = 0.0
    for chord, bow in moves:
        half = min(chord / 2, R)
        worst = max(worst, R - math.sqrt(R * R - half * half) + bow)
    return worst


@functools.lru_cache(maxsize=64)
def _ray_table(radius: float, n_rays: int, max_range: float,
               travel: float) -> tuple[FloatArray, FloatArray]:
    """For one disc radius: every sampled case's distance from the position reached to the
    nearest detected point (``dq``, descending) and the least true distance to the disc's
    surface among the cases with at least that ``dq`` (``dtrue``): the ray part at ``R`` is
    ``R - dtrue`` at the last ``dq >= R``."""
    dphi = 2 * math.pi / n_rays
    radii = np.linspace(0.0, travel, 9)
    heads = np.linspace(0.0, 2 * math.pi, 72, endpoint=False)
    P = np.stack([(radii[:, None] * np.cos(heads)).ravel(),
                  (radii[:, None] * np.sin(heads)).ravel()], axis=1)      # positions reached
    dq_all, dt_all = [], []
    for centre in np.linspace(radius + 1e-4, max_range + radius, 60):
        dtrue = np.hypot(P[:, 0] - centre, P[:, 1]) - radius
        disc = np.array([[centre, 0.0, radius]])
        for offset in np.linspace(0.0, dphi, 16, endpoint=False):
            ang = offset + dphi * np.arange(n_rays)
            t = ray_disc_distances((0.0, 0.0), ang, disc)  # the sensor's own geometry
            hit = t <= max_range
            if not hit.any():
                continue
            Q = np.stack([np.cos(ang[hit]), np.sin(ang[hit])], axis=1) * t[hit, None]
            dq = np.min(np.hypot(P[:, None, 0] - Q[None, :, 0], P[:, None, 1] - Q[None, :, 1]),
                        axis=1)
            dq_all.append(dq)
            dt_all.append(dtrue)
    if not dq_all:
        return np.zeros(0), np.zeros(0)
    dq, dtrue = np.concatenate(dq_all), np.concatenate(dt_all)
    order = np.argsort(-dq)
    return dq[order], np.minimum.accumulate(dtrue[order])


def rays(R: float, radii: Iterable[float], n_rays: int, max_range: float,
         travel: float) -> float:
    """The ray part at margin ``R``: the worst over the stated disc ``radii`` (module
    docstring)."""
    worst = 0.0
    for radius in radii:
        dq, dtrue = _ray_table(round(float(radius), 6), int(n_rays), round(float(max_range), 6),
                               round(float(travel), 6))
        k = int(np.searchsorted(-dq, -R, side="right"))  # cases with dq >= R: the first k
        if k > 0:
            worst = max(worst, R - float(dtrue[k - 1]))
    return worst


def blind_range(radius: float, n_rays: int) -> float:
    """The least distance from the sensor to the surface of a disc of ``radius`` that can
    lie between two neighbouring rays, unseen."""
    return radius / math.sin(math.pi / n_rays) - radius


def position_error(plant: Plant, x0: FloatArray, dt: float,
                   pieces: Any, reference: Any) -> float:
    """The largest distance between the positions after the input pieces ``pieces(u_old,
    u_new)`` and ``reference(u_old, u_new)`` ``[(input, duration), ...]``, over the input
    bounds' corners."""
    worst = 0.0
    for u_old in _corners(plant):
        for u_new in _corners(plant):
            ends = []
            for plan in (pieces(u_old, u_new), reference(u_old, u_new)):
                x = np.asarray(x0, dtype=float)
                for u, duration in plan:
                    if duration > 0:
                        x = plant.step(x, u, duration)
                ends.append(_position(plant, x))
            worst = max(worst, float(np.hypot(*(ends[0] - ends[1]))))
    return worst


def latency(world: Any, plant: Plant, x0: FloatArray, dt: float) -> tuple[float, str | None]:
    """The latency part, or 0 and what is not covered (module docstring)."""
    kind = world.latency
    if kind is Latency.none or kind is Latency.one_sample:
        return 0.0, None
    if kind in (Latency.measured, Latency.modelled):
        return 0.0, f"sim.latency={kind.value}: not stated before the run"
    if world.profile_s is not None:
        taus = np.asarray(world.profile_s) * world.latency_scale
        lo, hi = float(np.min(taus)), float(np.max(taus))
    else:
        lo = hi = world.fixed_latency_s * world.latency_scale
    lo, hi = min(lo, dt), min(hi, dt)
    if world.predicts:
        expected = min(world.expected_latency_s(), dt)
        cases = [(tau, expected) for tau in (lo, hi)]
    else:
        cases = [(hi, 0.0)]
    worst = 0.0
    for tau, assumed in cases:
        worst = max(worst, position_error(
            plant, x0, dt,
            lambda a, b, tau=tau: [(a, tau), (b, dt - tau)],
            lambda a, b, assumed=assumed: [(a, assumed), (b, dt - assumed)]))
    return worst, None


def model_mismatch(world: Any, plant: Plant, x0: FloatArray, dt: float) -> float:
    """The largest distance between one period's end position of the simulated plant and
    of the model, over the input grid (0 when they are the same)."""
    if not world.plant_params and world.substeps == 1:
        return 0.0
    worst = 0.0
    for u in _input_grid(plant):
        a = _position(plant, plant.step(np.asarray(x0, float), u, dt))
        b = _position(plant, world.plant.step(np.asarray(x0, float), u, dt))
        worst = max(worst, float(np.hypot(*(a - b))))
    return worst


def noise(world: Any, dt: float, position_walk_std: float) -> float:
    """The noise part: one-sided quantile of the range noise and the walk over a period."""
    z = NormalDist().inv_cdf(world.confidence)
    return z * math.sqrt(world.range_std**2 + position_walk_std**2 * dt)


def derive(plant: Plant, scenario: Any, world: Any, dt: float) -> MarginBudget:
    """The margin for ``plant`` in ``scenario`` (an obstacle scenario: its robot radius,
    sensor and stated obstacle radii) under ``world`` (a
    :class:`~mpclab.world.sim_world.SimWorld`), at control period ``dt``."""
    x0 = np.asarray(scenario.x0, dtype=float)
    travel, moves = motion(plant, x0, dt)
    radii = tuple(scenario.stated_obstacle_radii())
    sensor = scenario.sensor
    ix = [plant.state_index(s) for s in plant.position]
    walk = float(max(world.walk_std[ix])) if len(ix) else 0.0
    other = [s for i, s in enumerate(plant.states)
             if world.state_std[i] > 0 and i not in ix and s != plant.heading]
    not_covered = []
    lat, lat_missing = latency(world, plant, x0, dt)
    if lat_missing:
        not_covered.append(lat_missing)
    if other:
        not_covered.append(f"sim.noise.state_std on {', '.join(other)}")
    if world.actuated:
        not_covered.append("sim.actuator: the lag or rate limit of the inputs")
    fixed = dict(robot_radius=float(scenario.robot_radius), noise=noise(world, dt, walk),
                 latency=lat, model_mismatch=model_mismatch(world, plant, x0, dt))
    R = sum(fixed.values())
    ray = sample = 0.0
    for _ in range(50):  # the fixed point of R = fixed + rays(R) + between_samples(R)
        ray = rays(R, radii, sensor.n_rays, sensor.max_range, travel) if radii else 0.0
        sample = between_samples(R, moves)
        new = sum(fixed.values()) + ray + sample
        if abs(new - R) < 1e-7:
            R = new
            break
        R = new
    blind = None
    if radii:  # a disc unseen between two rays, which one period can bring within R
        smallest = min(radii)
        unseen = min(blind_range(smallest, sensor.n_rays), sensor.max_range)
        blind = max(unseen - travel, 0.0)
        if blind < R:
            not_covered.append(
                f"a disc of radius {smallest:g} m between two rays: unseen until {unseen:.3g} "
                f"m away, {blind:.3g} m after one period")
    return MarginBudget(rays=ray, between_samples=sample, confidence=world.confidence,
                        travel=travel, blind_range=blind, not_covered=tuple(not_covered),
                        **fixed)


def check_room(scenario: Any, distance: float, budget: MarginBudget | None,
               policy: NoRoom, seed: int) -> str | None:
    """Refuse (``no_room=refuse``: :class:`ConfigError`) a layout in which the robot cannot
    reach the goal keeping ``distance`` (``budget``'s total, or stated: ``budget`` None)
    from every obstacle; under ``no_room=run`` return the warning instead. None where there
    is room."""
    if scenario.way_to_goal(distance):
        return None
    what = f"{distance:.4g} m (stated)" if budget is None else budget.sentence()
    message = (
        f"scenario {scenario.name!r} (seed {seed}): the obstacle margin {what} leaves no way "
        f"from the start to the goal (the robot would keep {distance - scenario.robot_radius:.3g}"
        f" m from every obstacle); lower sim.noise, sim.latency or sim.disturbance, compensate "
        f"the latency (sim.timing.delay_compensation=true), state "
        f"objective.constraints.obstacles.distance=<metres>, or run it anyway with "
        f"objective.constraints.obstacles.no_room=run")
    if policy is NoRoom.refuse:
        raise ConfigError(message)
    return message
