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

**EKF** (``source: ekf``, :class:`Ekf`): the odometry's prediction, with one unknown scale
per input appended to the state (the model answers the measured input ``u`` with
``u (1 + s)``: a wheel radius known to ``sim.localization.ekf.model_rel_std``, 5 %, learnt
from the fixes) and the covariance ``P`` carried through the model's step Jacobians. The
process noise is stated, not tuned: the encoders' errors (``input_std``, ``slip_std``, and
``quantum`` as a rounding of ``q^2/6`` per period) and the simulated random walk
(``sim.disturbance``). The correction is the fix above, as a measurement ``z = H x + v`` with
``v ~ N(0, diag(std^2))``, in Joseph form; ``gain`` is not used. The covariance feeds the
arrival rule the supervisor sees (the estimate arrives when it is inside the arrival radius by
the position's one-sided ``sim.noise.confidence`` quantile); it takes no part in the obstacle
margin, whose points are placed from the same estimate (:mod:`mpclab.world.margin`). The run
record has the estimate's largest position standard deviation and its consistency: the mean
normalized estimation error squared (2 for a consistent filter) and the fraction of periods
whose error lies inside the 95 % ellipse.
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
    ekf = "ekf"            # the odometry's prediction, corrected by the fixes in an EKF


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

    def measure(self, pieces: Sequence[tuple[FloatArray, float]],
                ) -> list[tuple[FloatArray, float]]:
        """What the encoders measure of the period's ``pieces`` ``[(applied input,
        duration)]``: ``[(measured input, duration)]``, the pieces of no length left out."""
        nu = self.model.nu
        scale = 1 + self.slip_std * self.rng.standard_normal(nu) if self.slip_std > 0 else 1.0
        noise = (self.input_std * self.rng.standard_normal(nu) if self.input_std.any()
                 else 0.0)
        return [(self._count(np.asarray(u, dtype=float), duration) * scale + noise, duration)
                for u, duration in pieces if duration > 0]

    def advance(self, pieces: Sequence[tuple[FloatArray, float]]) -> FloatArray:
        """The estimate after the period's ``pieces`` ``[(applied input, duration)]``."""
        x = self.estimate
        for seen, duration in self.measure(pieces):
            x = self.model.step(x, seen, duration)
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

    def measure(self, t: float, x: FloatArray) -> FloatArray | None:
        """The fix at time ``t`` of the true state ``x`` (its entries :attr:`index`, with
        noise), or None when none is due."""
        if t < self._next_s - 1e-9:
            return None
        while self._next_s <= t + 1e-9:
            self._next_s += self.period_s
        self.count += 1
        return x[self.index] + self.std * self.rng.standard_normal(len(self.index))

    def innovation(self, z: FloatArray, estimate: FloatArray) -> FloatArray:
        """``z`` less the estimate's measured entries, the heading's wrapped to [-pi, pi)."""
        gap = np.asarray(z, dtype=float) - estimate[self.index]
        if self.heading is not None:
            wrap = self.index == self.heading
            gap[wrap] = (gap[wrap] + math.pi) % (2 * math.pi) - math.pi
        return gap

    def correct(self, t: float, x: FloatArray, estimate: FloatArray) -> FloatArray:
        """The estimate at time ``t`` (the true state ``x``): moved the fraction ``gain``
        towards a fix if one is due."""
        z = self.measure(t, x)
        if z is None:
            return estimate
        out = estimate.copy()
        out[self.index] += self.gain * self.innovation(z, estimate)
        return out

    def describe(self) -> dict[str, Any]:
        return {"period_s": self.period_s, "gain": self.gain} if self.configured else {}



class Ekf:
    """An extended Kalman filter over the controller's model (``sim.localization.source=ekf``;
    see the module docstring). Its state is the plant's with one scale per input appended:
    the model's response to the measured input ``u`` is to ``u (1 + s)`` (a wheel whose
    radius differs from the model's), a constant with the prior standard deviation
    ``model_rel_std``, learnt from the fixes.

    Parameters
    ----------
    model
        Injected: the controller's model (its step and Jacobians).
    odometry
        Injected: the encoders, whose measured inputs drive the prediction.
    fix
        Injected: the pose measurements the filter corrects with (their period and noise).
    walk_std
        Injected: the stated random walk of the true state, per square-root second
        (``sim.disturbance.state_std``), a part of the process noise.
    model_rel_std
        The prior standard deviation of each input's scale (a wheel radius known to this
        fraction): the filter's statement, not an error the simulation adds.
    """

    def __init__(self, model: Plant, odometry: Odometry, fix: Fix, walk_std: FloatArray,
                 model_rel_std: float = 0.05) -> None:
        self.model, self.odometry, self.fix = model, odometry, fix
        self.walk_var = np.asarray(walk_std, dtype=float) ** 2
        self.model_rel_std = number(model_rel_std, "sim.localization.ekf.model_rel_std",
                                    at_least=0)
        self.nx, self.nu = model.nx, model.nu
        self.P = np.zeros((self.nx + self.nu, self.nx + self.nu))
        self.scale = np.zeros(self.nu)
        self._pos = [model.state_index(s) for s in model.position]

    def reset(self) -> None:
        """Started at the true state (as the odometry), the scales unknown."""
        self.P[:] = 0.0
        self.P[self.nx:, self.nx:] = np.eye(self.nu) * self.model_rel_std**2
        self.scale[:] = 0.0

    def predict(self, pieces: Sequence[tuple[FloatArray, float]], dt: float) -> FloatArray:
        """The estimate after the period's ``pieces`` ``[(applied input, duration)]``, from
        the odometry's, integrated with the encoders' measured inputs scaled, and its
        covariance: the period's input errors are held over it, so each enters through its
        pieces' input Jacobians carried to the period's end."""
        nx, nu = self.nx, self.nu
        A_all = np.eye(nx)
        G_add, G_rel = np.zeros((nx, nu)), np.zeros((nx, nu))
        x = self.odometry.estimate
        for seen, duration in self.odometry.measure(pieces):
            u = seen * (1 + self.scale)
            A, B = self.model.jacobians(x, u, duration)
            A_all = A @ A_all
            G_add = A @ G_add + B
            G_rel = A @ G_rel + B * seen[None, :]
            x = self.model.step(x, u, duration)
        odo = self.odometry
        q = np.where(odo.quantum > 0, odo.quantum, 0.0)
        add_var = odo.input_std**2 + q**2 / (6 * dt**2)  # two counts' rounding a period
        F = np.eye(nx + nu)
        F[:nx, :nx], F[:nx, nx:] = A_all, G_rel
        Q = np.zeros_like(self.P)
        Q[:nx, :nx] = (G_add @ np.diag(add_var) @ G_add.T
                       + G_rel @ G_rel.T * odo.slip_std**2 + np.diag(self.walk_var * dt))
        self.P = F @ self.P @ F.T + Q
        return x

    def correct(self, estimate: FloatArray, z: FloatArray) -> FloatArray:
        """The estimate (and the scales) after the fix ``z`` of the entries ``fix.index``
        (Joseph form)."""
        idx = self.fix.index
        H = np.zeros((len(idx), self.nx + self.nu))
        H[np.arange(len(idx)), idx] = 1.0
        R = np.diag(np.maximum(self.fix.std, 1e-9) ** 2)
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        step = K @ self.fix.innovation(z, estimate)
        self.scale = self.scale + step[self.nx:]
        I_KH = np.eye(self.nx + self.nu) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T
        return estimate + step[:self.nx]

    def position_std(self) -> float:
        """The largest standard deviation of the position estimate [m] (the covariance's
        position block's largest eigenvalue, square-rooted)."""
        block = self.P[np.ix_(self._pos, self._pos)]
        return float(np.sqrt(max(np.linalg.eigvalsh(block)[-1], 0.0)))

    def nees(self, estimate: FloatArray, x: FloatArray) -> float | None:
        """The position's normalized estimation error squared ``e' P^-1 e`` (chi-square
        with 2 degrees of freedom for a consistent filter); None while ``P`` is singular."""
        block = self.P[np.ix_(self._pos, self._pos)]
        if np.linalg.eigvalsh(block)[0] <= 1e-18:
            return None
        e = (np.asarray(estimate) - np.asarray(x))[self._pos]
        return float(e @ np.linalg.solve(block, e))
