"""How the simulated world differs from the controller's model (the ``sim`` config group).

``sim=nominal`` is the ideal loop: the controller sees the true state, its input acts at the
instant the state was measured, and the simulator integrates the controller's own model.
:class:`SimWorld` adds, each on its own key:

* **latency** (``latency``: ``none``, ``measured``, a number of ms, ``one_sample`` or
  ``recorded``; ``timing.latency_scale``): the input computed from the state at ``t_k`` acts from
  ``t_k + tau``; the input applied before it holds until then, and the step is integrated
  in two pieces across the switch. ``one_sample`` is the fixed one-sample delay of embedded
  loops: the controller computes during ``[t_k, t_k+1)`` from the state predicted at
  ``t_k+1`` and its input acts from ``t_k+1``, however long the solve took. ``recorded``
  draws each latency, seeded, from a recorded distribution (``timing.latency_profile``: a CSV or
  Parquet file with a ``latency_s`` column, e.g. a run's ``steps.parquet``), so that a run
  repeats exactly; ``measured`` is the run's own solve time, which differs from run to run
  (the part of the call before its input, ``feedback_s``, for a controller that prepares
  its next solve after it: the real-time iteration); ``modelled`` is each call's time on the
  board the controller models (``Controller.board_time_model``: the scheduled controller's
  generated C on the F401RE, ``sim=embedded_m4``).
  A solve whose ``tau`` exceeds the **deadline** (``timing.deadline_ms``, default the
  control period) is a deadline miss, and ``timing.deadline_policy`` says what happens:
  ``hold`` (its input never acts; the applied one holds), ``plan`` (its input never acts;
  the next input of the last plan that met its deadline does) or ``late_apply`` (its input
  acts when it is ready, and the board is busy until then: the next solve starts at the
  first sample after it, the samples between are skipped). With
  ``timing.delay_compensation`` the controller computes from the state its model predicts
  when the input will act (on by default under ``one_sample``).
* **measurement noise** (``noise.state_std.<label>``, or ``.position`` and ``.heading`` for
  any plant's, ``noise.range_std``): the controller
  and the supervisor see a noisy state; range readings are taken from the true pose, get
  noise, and become obstacle points placed from the *measured* pose. The obstacle margin
  covers the range noise at the one-sided quantile ``noise.confidence`` (default 0.95;
  :mod:`mpclab.world.margin`).
* **process disturbance** (``disturbance.state_std.<label>``, per square-root second): a
  random walk added to the true state, ``N(0, std^2 dt)`` per control period.
* **model mismatch** (``plant_params.<name>``, ``substeps``): the simulated plant has other
  parameters (and a finer integrator) than the one the controller predicts with; the same
  ``rhs``.
* **localization** (``localization.source``: ``truth``, ``odometry`` or ``ekf``;
  ``localization.odometry``, ``localization.fix``, ``localization.ekf``): the state the
  controller and the supervisor see is the true one or a dead-reckoning estimate integrated
  with the model's parameters, optionally reset towards an absolute fix, or that estimate
  corrected by the fixes in an extended Kalman filter (:mod:`mpclab.world.localization`);
  the noise above is added to it.
* **actuators** (``actuator.time_constant_s``, ``actuator.rate_limit``): the plant sees the
  output of a first-order lag and/or a rate limit of the command, not the command itself
  (:mod:`mpclab.world.actuators`).

Every draw comes from generators seeded by the run's seed (streams of their own, so a
scenario's random layout does not change when noise is switched on, nor the noise when a
recorded latency or the odometry's errors are).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import numpy as np

from mpclab.config.registry import component, group_schema, schema_from_init
from mpclab.core.errors import ConfigError, check_keys, number, parse_choice
from mpclab.core.options import group
from mpclab.plants.base import FloatArray, Plant
from mpclab.world.actuators import Actuator
from mpclab.world.latency import DeadlinePolicy, Latency, latency_profile_s, parse_latency
from mpclab.world.localization import Ekf, Fix, Localization, Odometry, state_stds

#: the spawn keys of the world's random streams under the run's seed: noise and
#: disturbance, recorded latencies, the odometry's errors and fixes
_STREAM = 7
_LATENCY_STREAM = 8
_ODOMETRY_STREAM = 9


@dataclass
class NoiseConf:
    state_std: dict[str, float] = field(default_factory=dict)
    range_std: float = 0.0
    confidence: float = 0.95   # the obstacle margin covers the noise at this quantile


@dataclass
class DisturbanceConf:
    state_std: dict[str, float] = field(default_factory=dict)


def _nested(cls: type, name: str, injected: tuple[str, ...] = ()) -> type:
    """The schema of a nested option group: one field per option of ``cls``'s constructor
    (its injected ``model``, ``plant``, ``rng`` and ``injected`` left out), as a
    component's."""
    derived = schema_from_init(cls, ("model", "plant", "rng", *injected))
    schema = dataclasses.make_dataclass(name, [
        (f.name, f.type, dataclasses.field(default=f.default, default_factory=f.default_factory))
        for f in dataclasses.fields(derived) if f.name != "_target_"])
    schema.__module__ = __name__  # importable by name: configs holding it pickle
    return schema


OdometryConf = _nested(Odometry, "OdometryConf")
FixConf = _nested(Fix, "FixConf")
EkfConf = _nested(Ekf, "EkfConf", ("odometry", "fix", "walk_std"))
ActuatorConf = _nested(Actuator, "ActuatorConf")


@dataclass(frozen=True)
class LoopTiming:
    """When an input acts and what the controller computes from (``sim.timing``; the kind
    of latency is ``sim.latency``).

    Parameters
    ----------
    latency_scale
        Factor on every latency (a slower target).
    latency_profile
        ``recorded``: a CSV or Parquet file with a ``latency_s`` column, read from the
        working folder, else from the config folder.
    deadline_ms
        A solve later than this misses its deadline [ms]; None: the control period.
    deadline_policy
        What a miss does: ``hold``, ``plan`` or ``late_apply`` (module docstring).
    delay_compensation
        The controller computes from the state its plant model predicts when the input
        will act (the expected latency, under the input in effect), the reference shifted
        by the same time; None: only under ``one_sample`` (the embedded loop's prediction
        of its next state).
    """

    latency_scale: float = 1.0
    latency_profile: str | None = None
    deadline_ms: float | None = None
    deadline_policy: DeadlinePolicy | str = DeadlinePolicy.hold
    delay_compensation: bool | None = None


LoopTimingConf = group_schema(LoopTiming)


@dataclass
class LocalizationConf:
    source: str = "truth"          # truth | odometry
    odometry: OdometryConf = field(default_factory=OdometryConf)  # type: ignore[valid-type]
    fix: FixConf = field(default_factory=FixConf)  # type: ignore[valid-type]
    ekf: EkfConf = field(default_factory=EkfConf)  # type: ignore[valid-type]


@dataclass
class SimConf:
    _target_: str = "mpclab.world.sim_world.SimWorld"
    name: str = "nominal"
    latency: Any = "none"   # none | measured | a number of ms | one_sample | recorded | modelled
    timing: LoopTimingConf = field(default_factory=LoopTimingConf)  # type: ignore[valid-type]
    noise: NoiseConf = field(default_factory=NoiseConf)
    disturbance: DisturbanceConf = field(default_factory=DisturbanceConf)
    plant_params: dict[str, float] = field(default_factory=dict)
    substeps: int = 1              # RK4 sub-intervals of the simulated plant per step
    localization: LocalizationConf = field(default_factory=LocalizationConf)
    actuator: ActuatorConf = field(default_factory=ActuatorConf)  # type: ignore[valid-type]


@dataclass
class Timing:
    """When a step's input acts: ``latency_s`` after the measurement, or never (a miss
    under ``hold`` or ``plan``); the loop's next controller call comes ``periods`` control
    periods later (more than one: ``late_apply``'s board was busy)."""

    latency_s: float
    missed: bool
    applied: FloatArray  # the input in effect after the switch
    late: bool = False  # a missed deadline whose input acts when it is ready (late_apply)
    periods: int = 1

    @property
    def switch_s(self) -> float:
        """When the step's input starts to act, after the measurement (NaN: never)."""
        return math.nan if self.missed and not self.late else self.latency_s


@component("sim", "sim", SimConf, open_keys=(
    "plant_params", "noise.state_std", "disturbance.state_std",
    "localization.odometry.input_std", "localization.odometry.quantum",
    "localization.fix.std"))
class SimWorld:
    """The simulated world around the controller (see the module docstring).

    Parameters
    ----------
    plant
        Injected: the controller's model; the simulated plant is a variant of it.
    seed
        Injected: the run's seed.
    dt
        Injected: the control period [s].
    name
        The preset's name, in the run record (``sim``).
    latency
        ``none``, ``measured``, a number of ms, ``one_sample``, ``recorded`` or
        ``modelled`` (module docstring).
    timing
        :class:`LoopTiming`: the latency's scale and profile, the deadline and its policy,
        delay compensation.
    noise
        ``{state_std: {label: std}, range_std, confidence}``: measurement noise, and the
        quantile the obstacle margin covers it at.
    disturbance
        ``{state_std: {label: std}}``: a random walk on the true state, per square-root
        second.
    plant_params
        ``{name: value}``: the simulated plant's parameters where they differ from the
        model's.
    substeps
        RK4 sub-intervals of the simulated plant per step.
    localization
        ``{source: truth | odometry, odometry: {...}, fix: {...}}``: the state the
        controller sees (:mod:`mpclab.world.localization`).
    actuator
        ``{time_constant_s, rate_limit}`` (:mod:`mpclab.world.actuators`).
    """

    def __init__(
        self,
        plant: Plant,
        seed: int = 0,
        dt: float = 0.1,
        name: str = "nominal",
        latency: Any = "none",
        timing: LoopTiming | Mapping[str, Any] = LoopTiming(),
        noise: Mapping[str, Any] | None = None,
        disturbance: Mapping[str, Any] | None = None,
        plant_params: Mapping[str, float] | None = None,
        substeps: int = 1,
        localization: Mapping[str, Any] | None = None,
        actuator: Mapping[str, Any] | None = None,
    ) -> None:
        self.name = str(name)
        self.dt = float(dt)
        self.latency, self.fixed_latency_s = parse_latency(latency)
        timing = group(LoopTiming, timing, "sim.timing")
        self.latency_scale = _positive(timing.latency_scale, "sim.timing.latency_scale")
        self.latency_profile = timing.latency_profile
        self.profile_s = (latency_profile_s(timing.latency_profile)
                          if self.latency is Latency.recorded else None)
        period_ms = 1e3 * self.dt
        self.deadline_s = (self.dt if timing.deadline_ms is None
                           else _positive(timing.deadline_ms, "sim.timing.deadline_ms") / 1e3)
        if self.deadline_s > self.dt * (1 + 1e-9):
            raise ConfigError(f"sim.timing.deadline_ms must be at most the control period "
                              f"({period_ms:g} ms), got {timing.deadline_ms}")
        self.policy = parse_choice(DeadlinePolicy, timing.deadline_policy,
                                   "sim.timing.deadline_policy")
        compensation = timing.delay_compensation
        if compensation is not None and not isinstance(compensation, bool):
            raise ConfigError(f"sim.timing.delay_compensation must be true, false or null, "
                              f"got {compensation!r}")
        #: whether the controller computes from the state predicted over the latency
        self.predicts = (self.latency is Latency.one_sample if compensation is None
                         else compensation)
        noise = dict(noise or {})
        check_keys(noise, [f.name for f in dataclasses.fields(NoiseConf)], "sim.noise")
        self.state_std = state_stds(plant, noise.get("state_std") or {}, "sim.noise.state_std")
        self.range_std = _nonneg(noise.get("range_std", 0.0), "sim.noise.range_std")
        self.confidence = number(noise.get("confidence", NoiseConf.confidence),
                                 "sim.noise.confidence", above=0)
        if self.confidence >= 1:
            raise ConfigError(f"sim.noise.confidence: expected a probability in (0, 1), got "
                              f"{self.confidence:g}")
        disturbance = dict(disturbance or {})
        check_keys(disturbance, ["state_std"], "sim.disturbance")
        self.walk_std = state_stds(plant, disturbance.get("state_std") or {},
                                   "sim.disturbance.state_std")
        if int(substeps) < 1:
            raise ConfigError(f"sim.substeps must be an integer >= 1, got {substeps}")
        self.substeps = int(substeps)
        self.plant_params = dict(plant_params or {})
        self.model = plant
        self.plant = plant.variant(self.plant_params, self.substeps, where="sim.plant_params")
        self.rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(_STREAM,)))
        located = _group(localization, LocalizationConf, "sim.localization")
        self.localization = parse_choice(Localization, located.get("source", "truth"),
                                         "sim.localization.source")
        odometry_rng = np.random.default_rng(
            np.random.SeedSequence(int(seed), spawn_key=(_ODOMETRY_STREAM,)))
        self.odometry = Odometry(plant, odometry_rng, **_group(
            located.get("odometry"), OdometryConf, "sim.localization.odometry"))
        self.fix = Fix(plant, odometry_rng, **_group(
            located.get("fix"), FixConf, "sim.localization.fix"))
        self.dead_reckoning = self.localization in (Localization.odometry, Localization.ekf)
        if not self.dead_reckoning and (self.odometry.configured or self.fix.configured):
            what = (f"sim.localization.odometry ({self.odometry.describe()})"
                    if self.odometry.configured
                    else f"sim.localization.fix.period_s={self.fix.period_s:g}")
            raise ConfigError(f"{what}: acts only with sim.localization.source=odometry or "
                              f"ekf, got sim.localization.source={self.localization.value}")
        ekf_options = _group(located.get("ekf"), EkfConf, "sim.localization.ekf")
        self.ekf = None
        if self.localization is Localization.ekf:
            if not self.fix.configured:
                raise ConfigError(
                    "sim.localization.source=ekf: the filter needs a measurement; set "
                    "sim.localization.fix.period_s=<s> (and sim.localization.fix.std.position, "
                    ".heading: its noise)")
            self.ekf = Ekf(plant, self.odometry, self.fix, self.walk_std, **ekf_options)
        elif {k: v for k, v in ekf_options.items() if v != getattr(EkfConf(), k)}:
            raise ConfigError(f"sim.localization.ekf ({ekf_options}): acts only with "
                              f"sim.localization.source=ekf, got "
                              f"sim.localization.source={self.localization.value}")
        self.actuator = Actuator(**_group(actuator, ActuatorConf, "sim.actuator"))
        #: what the world adds to the loop, decided once: state noise, input latency, a
        #: state the controller sees other than the true one (noise or odometry), actuators
        self.noisy = bool(self.state_std.any())
        self.delayed = self.latency is not Latency.none
        self.estimated = self.noisy or self.dead_reckoning
        self.actuated = self.actuator.active
        self._walk = bool(self.walk_std.any())
        self._plan: FloatArray | None = None  # the inputs of the last plan in time
        self._plan_age = 0
        self._latency_rng = np.random.default_rng(
            np.random.SeedSequence(int(seed), spawn_key=(_LATENCY_STREAM,)))
        self._expected_s = self.dt if self.latency is Latency.one_sample else \
            self.fixed_latency_s * self.latency_scale
        if self.profile_s is not None:
            self._expected_s = float(np.median(self.profile_s)) * self.latency_scale
        self.reset(plant.nu)

    # ---------------------------------------------------------------- what it adds

    def reset(self, nu: int) -> None:
        self._plan, self._plan_age = None, 0
        if self.latency in (Latency.measured, Latency.modelled):
            self._expected_s = 0.0
        self.applied = np.zeros(nu)
        self.actuator.reset(nu)
        self.fix.reset()
        self._t, self._started = 0.0, False
        self._errors: list[float] = []  # the estimate's position error after each period
        self._stds: list[float] = []    # the EKF's position standard deviation, and ...
        self._nees: list[float] = []    # ... its normalized estimation error squared

    def measure(self, x: FloatArray) -> FloatArray:
        """The state the controller sees at the true state ``x``: ``x`` itself, or the
        odometry's estimate (started at the first ``x``), plus the state noise."""
        if self.dead_reckoning and not self._started:
            self.odometry.reset(x)
            if self.ekf is not None:
                self.ekf.reset()
        self._started = True
        seen = self.odometry.estimate.copy() if self.dead_reckoning else x
        if not self.noisy:
            return seen
        return seen + self.state_std * self.rng.standard_normal(x.shape)

    def perturb_ranges(self, ranges: FloatArray) -> FloatArray:
        """Range readings with the sensor's noise (rays that see nothing stay ``inf``)."""
        if self.range_std <= 0:
            return ranges
        noisy = ranges + self.range_std * self.rng.standard_normal(ranges.shape)
        return np.where(np.isfinite(ranges), np.maximum(noisy, 0.0), ranges)

    def expected_latency_s(self) -> float:
        """The latency the coming solve's input is expected to act after: the fixed one,
        one period (``one_sample``), the recorded median or the last measured one (0 before
        the first)."""
        return self._expected_s

    def board_time(self, controller: Any) -> Any:
        """``controller``'s model of a call's time on its board (``sim.latency=modelled``),
        else None; a controller that models none is refused, naming the key."""
        if self.latency is not Latency.modelled:
            return None
        model = controller.board_time_model()
        if model is None:
            name = controller.registered_name or type(controller).__name__
            raise ConfigError(
                f"sim.latency=modelled: the {name} controller models no time on a board; "
                "valid: controller=scheduled with "
                "controller.codegen=true, or another sim.latency (none, measured, a number "
                "of ms, one_sample, recorded)")
        return model

    def timing(self, u: FloatArray, u_pred: FloatArray, solve_time_s: float,
               modelled_s: float | None = None) -> Timing:
        """When the input ``u`` (first of the plan ``u_pred``) acts, given the solve took
        ``solve_time_s`` (and, under ``modelled``, ``modelled_s`` on the board)."""
        if self.latency is Latency.none:
            tau = 0.0
        elif self.latency is Latency.measured:
            tau = solve_time_s * self.latency_scale
        elif self.latency is Latency.modelled:  # simulate passes the controller's model's
            tau = float(modelled_s) * self.latency_scale
        elif self.latency is Latency.one_sample:
            tau = self.dt
        elif self.profile_s is not None:
            tau = float(self._latency_rng.choice(self.profile_s)) * self.latency_scale
        else:
            tau = self.fixed_latency_s * self.latency_scale
        if self.latency in (Latency.measured, Latency.modelled):
            self._expected_s = tau
        if tau <= self.deadline_s or self.latency is Latency.one_sample:
            self._plan, self._plan_age = np.asarray(u_pred, dtype=float), 0
            return Timing(tau, False, np.asarray(u, dtype=float))
        if self.policy is DeadlinePolicy.late_apply:  # busy until ready, free at the next sample
            periods = max(1, math.ceil(tau / self.dt - 1e-9))
            self._plan, self._plan_age = np.asarray(u_pred, dtype=float), 0
            return Timing(tau, True, np.asarray(u, dtype=float), late=True, periods=periods)
        self._plan_age += 1
        held = self.applied
        if self.policy is DeadlinePolicy.plan and self._plan is not None:
            if self._plan_age < len(self._plan):
                held = self._plan[self._plan_age]
        return Timing(tau, True, held)

    def pieces(self, timing: Timing) -> list[tuple[FloatArray, float]]:
        """The inputs the plant sees until the next controller call, in order, with how
        long each holds ``[(input, duration [s])]``: the :meth:`commands`, or the actuators'
        response to them in short pieces."""
        return self.actuator.respond(self.commands(timing), self.dt)[0]

    def commands(self, timing: Timing) -> list[tuple[FloatArray, float]]:
        """The commands in effect until the next controller call ``[(input, duration)]``:
        the applied input until the switch, the new one after it (a missed deadline under
        ``hold`` or ``plan``: one input for the whole period; ``late_apply``: over as many
        periods as the board was busy)."""
        span, tau = self.dt * timing.periods, timing.latency_s
        if (timing.missed and not timing.late) or tau <= 0.0:
            return [(timing.applied, span)]
        if tau >= span:  # exactly at the end: the new input acts from the next call
            return [(self.applied, span)]
        return [(self.applied, tau), (timing.applied, span - tau)]

    def advance(self, x: FloatArray, timing: Timing) -> FloatArray:
        """The true state at the next controller call (one control period later, more under
        ``late_apply``): the :meth:`pieces` integrated one after the other, then the
        disturbance; the odometry integrates the same pieces, then takes a fix if one is
        due."""
        pieces, output = self.actuator.respond(self.commands(timing), self.dt)
        for u, duration in pieces:
            x = self.plant.step(x, u, duration)
        self.actuator.commit(output)
        dt = self.dt * timing.periods
        self.applied = timing.applied
        if self._walk:
            x = x + self.walk_std * math.sqrt(dt) * self.rng.standard_normal(x.shape)
        if self.dead_reckoning:
            self._t += dt
            if self.ekf is None:
                estimate = self.fix.correct(self._t, x, self.odometry.advance(pieces))
            else:
                estimate = self.ekf.predict(pieces, dt)
                z = self.fix.measure(self._t, x)
                if z is not None:
                    estimate = self.ekf.correct(estimate, z)
                self._stds.append(self.ekf.position_std())
                nees = self.ekf.nees(estimate, x)
                if nees is not None:
                    self._nees.append(nees)
            self.odometry.estimate = estimate
            at = [self.model.state_index(label) for label in self.model.position]
            self._errors.append(float(np.linalg.norm(self.odometry.estimate[at] - x[at])))
        return x

    def arrival_doubt(self) -> float:
        """How far inside the arrival radius the estimate must be for the robot to believe
        it arrived [m]: the EKF's position standard deviation at the one-sided quantile of
        ``noise.confidence``; 0 without an EKF."""
        if self.ekf is None:
            return 0.0
        return NormalDist().inv_cdf(self.confidence) * self.ekf.position_std()

    def _ekf_summary(self) -> dict[str, Any]:
        """The EKF's largest position standard deviation and its consistency (module
        docstring of :mod:`mpclab.world.localization`)."""
        if self.ekf is None:
            return {}
        nees = np.asarray(self._nees)
        return {
            "sim_ekf": {"model_rel_std": self.ekf.model_rel_std},
            # the input scales learnt (the model's input u acts as u (1 + s))
            "localization_input_scales": self.ekf.scale.tolist(),
            "localization_std_max_m": max(self._stds) if self._stds else None,
            "localization_nees_mean": float(nees.mean()) if len(nees) else None,
            "localization_inside_95": (float(np.mean(nees <= _chi2_2dof(0.95)))
                                       if len(nees) else None),
        }

    def describe(self) -> dict[str, Any]:
        """What the run record says of the world (the summary's ``sim_*`` keys)."""
        return {
            "sim": self.name,
            "sim_latency": (f"{1e3 * self.fixed_latency_s:g} ms"
                            if self.latency is Latency.fixed else self.latency.value),
            "sim_deadline_policy": self.policy.value,
            "sim_latency_scale": self.latency_scale,
            "sim_latency_profile": self.latency_profile if self.profile_s is not None else None,
            "sim_delay_compensation": self.predicts,
            "sim_plant_params": dict(self.plant_params),
            "sim_localization": self.localization.value,
            "sim_odometry": self.odometry.describe() if self.dead_reckoning else None,
            "sim_localization_fix": self.fix.describe() or None,
            "sim_actuator": self.actuator.describe() if self.actuated else None,
            # the estimate's position error [m], after every period and at the end
            "localization_error_max_m": max(self._errors) if self._errors else None,
            "localization_error_final_m": self._errors[-1] if self._errors else None,
            "localization_fixes": self.fix.count if self.fix.configured else None,
            **self._ekf_summary(),
        }


def _chi2_2dof(p: float) -> float:
    """The ``p`` quantile of the chi-square distribution with 2 degrees of freedom."""
    return -2.0 * math.log(1.0 - p)


def _nonneg(value: Any, key: str) -> float:
    return number(value, key, at_least=0)


def _positive(value: Any, key: str) -> float:
    return number(value, key, above=0)


def _group(given: Mapping[str, Any] | None, schema: type, key: str) -> dict[str, Any]:
    """A nested option group as keyword arguments; a key it does not have is an error."""
    options = dict(given or {})
    check_keys(options, [f.name for f in dataclasses.fields(schema)], key)
    return options
