"""Scenarios: start, goal, stop rules and time limit, resolved against a plant's labels."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from mpclab.config.registry import component
from mpclab.core.errors import ConfigError, number
from mpclab.plants.base import Plant

FloatArray = npt.NDArray[np.float64]


@dataclass
class ArrivalConf:
    """Arrived when ``sum_i w_i (x_i - goal_i)^2 < threshold``."""

    weights: dict[str, float] = field(default_factory=dict)
    threshold: float = 1.0


@dataclass
class ScenarioConf:
    _target_: str = "mpclab.world.scenario.Scenario"
    name: str = "???"
    start: dict[str, float] = field(default_factory=dict)
    goal: dict[str, float] = field(default_factory=dict)
    arrival: ArrivalConf = field(default_factory=ArrivalConf)
    t_max: float = 30.0


@component("scenario", "scenario", ScenarioConf)
class Scenario:
    """Start and goal states, the arrival rule and the time limit.

    Parameters
    ----------
    plant
        Injected; labels in ``start``, ``goal`` and ``arrival.weights`` are its state labels.
    name
        Scenario name, written into the run record.
    start, goal
        ``{state label: value}``; labels not given are 0.
    arrival
        ``{"weights": {label: w}, "threshold": eps}``: arrived when the weighted squared
        distance to the goal is below ``eps``.
    t_max
        Simulated time limit [s]; reaching it ends the run with ``status: timeout``.
    """

    def __init__(
        self,
        plant: Plant,
        name: str,
        start: Mapping[str, float],
        goal: Mapping[str, float],
        arrival: Mapping[str, Any],
        t_max: float = 30.0,
    ) -> None:
        self.plant = plant
        self.name = name
        self.x0 = self._vector(start, "scenario.start")
        self.goal = self._vector(goal, "scenario.goal")
        weights = dict(arrival.get("weights", {}))
        for label, w in weights.items():
            number(w, f"scenario.arrival.weights.{label}", at_least=0)
        if not any(float(w) > 0 for w in weights.values()):
            raise ConfigError("scenario.arrival.weights: no positive weight, so no state decides "
                              f"arrival; got {weights or '{}'}")
        self._arrival_w = self._vector(weights, "scenario.arrival.weights")
        # a threshold <= 0 can never be met: the weighted squared distance is >= 0
        self.arrival_threshold = number(arrival.get("threshold", 1.0),
                                        "scenario.arrival.threshold", above=0)
        self.t_max = number(t_max, "scenario.t_max", above=0)

    def _vector(self, values: Mapping[str, float], where: str) -> FloatArray:
        v = np.zeros(self.plant.nx)
        for label, value in values.items():
            try:
                i = self.plant.state_index(label)
            except ValueError as exc:
                raise ConfigError(f"{where}: {exc}") from None
            v[i] = number(value, f"{where}.{label}")
        return v

    def arrival_distance(self, x: FloatArray) -> float:
        """The weighted squared distance the arrival rule compares with the threshold."""
        return float(np.sum(self._arrival_w * (x - self.goal) ** 2))

    def arrived(self, x: FloatArray, doubt: float = 0.0) -> bool:
        """Whether ``x`` meets the arrival rule; with ``doubt`` [m] (an estimate's uncertainty
        in position), whether it meets it with ``doubt`` to spare on the position's weights."""
        if doubt <= 0:
            return self.arrival_distance(x) < self.arrival_threshold
        w = max((float(self._arrival_w[self.plant.state_index(s)]) for s in self.plant.position),
                default=0.0)
        reach = math.sqrt(self.arrival_threshold) - doubt * math.sqrt(w)
        return reach > 0 and math.sqrt(self.arrival_distance(x)) < reach

    def target(self, t: float, horizon: int, dt: float) -> FloatArray:
        """Reference over the horizon ``(horizon+1, nx)``: here the goal held."""
        return np.tile(self.goal, (horizon + 1, 1))

    #: obstacle discs ``(n, 3)``: centre x, centre y, radius [m] (none here)
    obstacles: FloatArray = np.zeros((0, 3))
    #: the vehicle is a disc of this radius for :meth:`clearance` [m]
    robot_radius: float = 0.0

    def metrics(self, steps: Any, outcome: Mapping[str, Any]) -> dict[str, Any]:
        """Scenario-specific figures for ``summary.json``, from the step log and the loop's
        ``outcome`` (its summary: ``status``, ``arrival_time_s``, ...)."""
        return {}

    # The world hooks the loop calls each step; a scenario without obstacles or stall rule
    # sees nothing, never collides and never stalls.
    def detect(self, x: FloatArray) -> FloatArray:
        """Detected obstacle points ``(n, 2)`` seen from state ``x``."""
        return np.zeros((0, 2))

    def ranges(self, x: FloatArray) -> FloatArray:
        """Range sensor reading per ray ``(n_rays,)``, ``inf`` where nothing is seen."""
        return np.zeros(0)

    def sense(
        self, x: FloatArray, believed: FloatArray | None = None,
        perturb: Callable[[FloatArray], FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """``(detected points, ranges)`` from one sensor reading at the true state ``x`` (what
        the loop asks each step). ``perturb`` adds the sensor's noise to the ranges;
        ``believed``, the state the robot thinks it is in, places the points (default ``x``).
        Without a sensor: nothing seen."""
        return self.detect(x), self.ranges(x)

    def collided(self, x: FloatArray) -> bool:
        return False

    def clearance(self, x: FloatArray) -> float:
        """Distance from the vehicle's boundary to the nearest obstacle [m] (NaN: none)."""
        return float("nan")

    def stalled(self, t: list[float], xs: list[FloatArray]) -> bool:
        """Whether the run so far (times and states before this step) has stalled."""
        return False
