"""Where the robot believes it is (``sim.localization``, ``sim.localization.odometry``,
``sim.localization.fix``).

``truth`` (the default): the controller and the supervisor see the true state (plus
``sim.noise``, if any). ``odometry``: they see a **dead-reckoning estimate**, started at the
true initial state and advanced by integrating the *controller's* model (the plant's
``rhs`` with its nominal parameters, e.g. the Zumo's ``r = 0.020``) with the inputs the
actuators actually applied, as the encoders measure them, over the same pieces of constant
input the simulated plant integrates (whose parameters may differ: ``sim.plant_params``).
For the Zumo that is wheel odometry; for a plant whose inputs are not wheel speeds (the
car's acceleration and steering rate) it is the general form, dead reckoning. With matched
parameters, no encoder error and no disturbance the estimate is the true state; with a
wheel 5 % larger than the model's it drifts: the robot drives 5 % further than it believes.

Encoder errors (``sim.localization.odometry``), drawn per control period from the run's seed:

* ``slip_std``: each input's measured value is multiplied by ``1 + N(0, slip_std^2)``
  (wheel slip, one draw per input per period);
* ``input_std.<input>``: ``N(0, std^2)`` added to that input's measured value (one draw per
  input per period, held over the period);
* ``quantum.<input>``: the encoder counts the integral of the input (a wheel's angle [rad])
  in steps of ``quantum``; each piece's measured input is the counted travel over the piece
  divided by its length (the count's error never exceeds one step, and does not grow).

**Absolute fix** (``sim.localization.fix``): every ``period_s`` of simulated time (at the
first controller call at or after each multiple of it) a sensor measures the true state's
entries named in ``std`` (``position`` and ``heading`` stand for those of any plant; empty:
both, exactly) with ``N(0, std^2)`` noise, and the estimate moves the fraction ``gain`` of
the way to it: ``x_hat <- x_hat + gain (z - x_hat)`` for those entries only (the heading's
difference wrapped to ``[-pi, pi)``); the other entries keep the odometry's value.
``gain = 1`` resets them to the fix; a smaller gain is a complementary filter (a Kalman
update with a fixed gain). No covariance is kept.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from enum import StrEnum
from typing import Any

import numpy as np

from mpclab.core.errors import ConfigError, check_keys, number
from mpclab.plants.base import FloatArray, Plant


class Localization(StrEnum):
    truth = "truth"        # the true state
    odometry = "odometry"  # dead reckoning with the model's parameters


def by_state(plant: Plant, given: Mapping[str, Any], key: str) -> dict[int, float]:
    """Values >= 0 by state label -> ``{state index: value}``. Two roles stand for labels of
    any plant: ``position`` (both coordinates) and ``heading``; a label given as well wins."""
    roles = {"position": list(plant.position), "heading": [plant.heading] if plant.heading else []}
    check_keys(given, [*plant.states, *roles], key)
    out: dict[int, float] = {}
    for role, labels in roles.items():
        if role in given:
            for label in labels:
                out[plant.state_index(label)] = number(given[role], f"{key}.{role}", at_least=0)
    for label, value in given.items():
        if label not in roles:
            out[plant.state_index(label)] = number(value, f"{key}.{label}", at_least=0)
    return out


def state_stds(plant: Plant, given: Mapping[str, Any], key: str) -> FloatArray:
    """Standard deviations by state label (see :func:`by_state`) -> a vector over the
    plant's states, zero where none is given."""
    std = np.zeros(plant.nx)
    for i, value in by_state(plant, given, key).items():
        std[i] = value
    return std


def _by_input(plant: Plant, given: Mapping[str, Any], key: str, above: bool) -> FloatArray:
    check_keys(given, plant.inputs, key)
    out = np.zeros(plant.nu)
    for label, value in given.items():
        out[plant.input_index(label)] = number(
            value, f"{key}.{label}", **({"above": 0} if above else {"at_least": 0}))
    return out


class Odometry:
    """The encoders and the dead reckoning (see the module docstring).

    Parameters
    ----------
    model
        Injected: the controller's model (its nominal parameters integrate the estimate).
    rng
        Injected: the odometry's random stream.
    input_std
        Encoder noise by input label [input unit], per control period.
    slip_std
        Relative error of each measured input, per control period.
    quantum
        Encoder resolution by input label: the step its integral is counted in.
    """

    def __init__(self, model: Plant, rng: np.random.Generator,
                 input_std: Mapping[str, float] | None = None, slip_std: float = 0.0,
                 quantum: Mapping[str, float] | None = None) -> None:
        self.model, self.rng = model, rng
        self.input_std = _by_input(model, input_std or {},
                                   "sim.localization.odometry.input_std", False)
        self.slip_std = number(slip_std, "sim.localization.odometry.slip_std", at_least=0)
        self.quantum = _by_input(model, quantum or {}, "sim.localization.odometry.quantum", True)
        #: any encoder error at all (else the measured inputs are the applied ones)
        self.configured = bool(self.input_std.any() or self.slip_std > 0 or self.quantum.any())
        self.estimate = np.zeros(model.nx)
        self._travel = np.zeros(model.nu)   # the true integral of each input
        self._counted = np.zeros(model.nu)  # ... as the encoder counted it

    def reset(self, x0: FloatArray) -> None:
        self.estimate = np.asarray(x0, dtype=float).copy()
        self._travel[:] = 0.0
        self._counted[:] = 0.0

    def advance(self, pieces: Sequence[tuple[FloatArray, float]]) -> FloatArray:
        """The estimate after the period's ``pieces`` ``[(applied input, duration)]``."""
        nu = self.model.nu
        scale = 1 + self.slip_std * self.rng.standard_normal(nu) if self.slip_std > 0 else 1.0
        noise = (self.input_std * self.rng.standard_normal(nu) if self.input_std.any()
                 else 0.0)
        x = self.estimate
        for u, duration in pieces:
            if duration <= 0:
                continue
            seen = self._count(np.asarray(u, dtype=float), duration)
            x = self.model.step(x, seen * scale + noise, duration)
        self.estimate = x
        return x

    def _count(self, u: FloatArray, duration: float) -> FloatArray:
        """The input the encoders measure over a piece of ``duration`` (exact where no
        ``quantum`` is given)."""
        if not self.quantum.any():
            return u
        self._travel += u * duration
        q = np.where(self.quantum > 0, self.quantum, 1.0)
        counted = np.where(self.quantum > 0, np.floor(self._travel / q) * q, self._travel)
        seen = (counted - self._counted) / duration
        self._counted = counted
        return seen

    def describe(self) -> dict[str, Any]:
        model = self.model
        return {
            "slip_std": self.slip_std,
            "input_std": {u: float(s) for u, s in zip(model.inputs, self.input_std, strict=True)
                          if s > 0},
            "quantum": {u: float(q) for u, q in zip(model.inputs, self.quantum, strict=True)
                        if q > 0},
        }


class Fix:
    """The absolute fix blended into the estimate (see the module docstring).

    Parameters
    ----------
    plant
        Injected: the controller's model (its state labels).
    rng
        Injected: the odometry's random stream.
    period_s
        Time between fixes [s]; ``None``: no fix.
    std
        The measured states and the fix's noise, by state label (``position``,
        ``heading`` for any plant); empty: position and heading, exactly.
    gain
        The fraction of the way the estimate moves to the fix, in ``(0, 1]``.
    """

    def __init__(self, plant: Plant, rng: np.random.Generator, period_s: float | None = None,
                 std: Mapping[str, float] | None = None, gain: float = 1.0) -> None:
        key = "sim.localization.fix"
        self.rng = rng
        self.period_s = None if period_s is None else number(period_s, f"{key}.period_s",
                                                             above=0)
        given = dict(std or {}) or {"position": 0.0, "heading": 0.0}
        entries = by_state(plant, given, f"{key}.std")
        self.index = np.array(sorted(entries), dtype=int)
        self.std = np.array([entries[i] for i in self.index])
        self.gain = number(gain, f"{key}.gain", above=0)
        if self.gain > 1:
            raise ConfigError(f"{key}.gain: expected a number in (0, 1], got {gain!r}")
        self.heading = None if plant.heading is None else plant.state_index(plant.heading)
        self.configured = self.period_s is not None
        self.count = 0
        self._next_s = math.inf

    def reset(self) -> None:
        self.count = 0
        self._next_s = math.inf if self.period_s is None else self.period_s

    def correct(self, t: float, x: FloatArray, estimate: FloatArray) -> FloatArray:
        """The estimate at time ``t`` (the true state ``x``): moved towards a fix if one is
        due."""
        if t < self._next_s - 1e-9:
            return estimate
        while self._next_s <= t + 1e-9:
            self._next_s += self.period_s
        z = x[self.index] + self.std * self.rng.standard_normal(len(self.index))
        gap = z - estimate[self.index]
        if self.heading is not None:
            wrap = self.index == self.heading
            gap[wrap] = (gap[wrap] + math.pi) % (2 * math.pi) - math.pi
        out = estimate.copy()
        out[self.index] += self.gain * gap
        self.count += 1
        return out

    def describe(self) -> dict[str, Any]:
        return {"period_s": self.period_s, "gain": self.gain} if self.configured else {}
