"""Odometry localization and the actuator model (``sim.localization``: its ``source``,
``odometry`` and ``fix``; ``sim.actuator``).

Exact equality only where one computation is repeated in one process (the same config and
seed twice); the rest compares with tolerances against the analytic answer.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from mpclab.core.errors import ConfigError
from mpclab.plants.kinematic_car import KinematicCar
from mpclab.plants.zumo import Zumo
from mpclab.record import files as record
from mpclab.world.actuators import Actuator
from mpclab.world.sim_world import SimWorld

ZUMO = ["+experiment=zumo_bug2"]


def _drive(world: SimWorld, x: np.ndarray, inputs: list[np.ndarray]) -> list[tuple]:
    """Hold each input for one period; ``[(true state, what the controller sees)]`` after
    each."""
    world.reset(len(inputs[0]))
    seen = [(x, world.measure(x))]
    for u in inputs:
        tm = world.timing(u, u[None, :], 0.0)
        x = world.advance(x, tm)
        seen.append((x, world.measure(x)))
    return seen


def _wiggle(n: int) -> list[np.ndarray]:
    return [np.array([5 + 4 * math.sin(0.3 * k), 5 - 3 * math.cos(0.2 * k)]) for k in range(n)]


@pytest.mark.parametrize("extra", [{}, {"latency": 30}, {"actuator": {"time_constant_s": 0.05}},
                                   {"actuator": {"rate_limit": 40.0, "time_constant_s": 0.02}}],
                         ids=["plain", "latency", "lag", "lag_and_rate_limit"])
def test_odometry_with_the_plants_parameters_is_the_truth(extra):
    world = SimWorld(Zumo(), dt=0.1, localization={"source": "odometry"}, **extra)
    for x, seen in _drive(world, np.array([0.1, 0.2, 0.3]), _wiggle(40)):
        np.testing.assert_allclose(seen, x, atol=1e-9)


def test_dead_reckoning_is_generic_over_plants():
    """The car's inputs are not wheel speeds: its odometry integrates the model's rhs."""
    plant = KinematicCar()
    world = SimWorld(plant, dt=0.1, localization={"source": "odometry"})
    inputs = [np.array([0.5 * math.cos(0.1 * k), 0.2 * math.sin(0.3 * k)]) for k in range(30)]
    for x, seen in _drive(world, np.array([0.0, 0.0, 0.1, 1.0, 0.0]), inputs):
        np.testing.assert_allclose(seen, x, atol=1e-9)
    other = SimWorld(plant, dt=0.1, localization={"source": "odometry"}, plant_params={"l": 1.1})
    x, seen = _drive(other, np.array([0.0, 0.0, 0.1, 1.0, 0.0]), inputs)[-1]
    assert abs(seen[2] - x[2]) > 1e-3  # a longer wheelbase turns less than the model believes


def test_a_larger_wheel_drives_five_percent_further_than_the_odometry_believes():
    world = SimWorld(Zumo(), dt=0.2, localization={"source": "odometry"}, plant_params={"r": 0.021})
    x, seen = _drive(world, np.zeros(3), [np.array([5.0, 5.0])] * 50)[-1]
    # 10 s at 5 rad/s: the model's wheel 0.020 * 50 = 1.00 m, the true one 1.05 m
    assert seen[0] == pytest.approx(1.0, rel=1e-9)
    assert x[0] == pytest.approx(1.05, rel=1e-9)
    assert (x[0] - seen[0]) / x[0] == pytest.approx(1 - 0.020 / 0.021, rel=1e-9)
    assert world.describe()["localization_error_final_m"] == pytest.approx(0.05, rel=1e-6)


def test_encoder_counts_err_by_at_most_one_step():
    q = 2 * math.pi / 1200  # a 1200-count wheel encoder [rad]
    world = SimWorld(Zumo(), dt=0.1, localization={
        "source": "odometry", "odometry": {"quantum": {"u1": q, "u2": q}}})
    worst = 0.0
    for x, seen in _drive(world, np.zeros(3), [np.array([3.3, 3.3])] * 40):
        worst = max(worst, abs(seen[0] - x[0]))
        assert x[0] - seen[0] >= -1e-12  # a count lags the true angle, never leads it
    assert 0 < worst <= 0.02 * q + 1e-12  # one count of the wheel's travel, r * q


def test_slip_and_encoder_noise_make_the_estimate_drift_and_repeat():
    conf = {"slip_std": 0.05, "input_std": {"u1": 0.2}}
    a = _drive(SimWorld(Zumo(), dt=0.1, seed=3,
                        localization={"source": "odometry", "odometry": conf}),
               np.zeros(3), _wiggle(30))
    b = _drive(SimWorld(Zumo(), dt=0.1, seed=3,
                        localization={"source": "odometry", "odometry": conf}),
               np.zeros(3), _wiggle(30))
    for (xa, sa), (xb, sb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(sa, sb)
        np.testing.assert_array_equal(xa, xb)
    assert np.abs(a[-1][1] - a[-1][0]).max() > 1e-3


def test_an_exact_fix_with_gain_one_resets_position_and_heading():
    world = SimWorld(Zumo(), dt=0.1, plant_params={"r": 0.021},
                     localization={"source": "odometry", "fix": {"period_s": 0.5}})
    seen = _drive(world, np.zeros(3), _wiggle(20))
    for k, (x, est) in enumerate(seen):
        if k % 5 == 0:  # t = 0, 0.5, 1.0, ...: just after a fix
            np.testing.assert_allclose(est, x, atol=1e-12)
        else:
            assert np.abs(est - x).max() > 1e-6
    assert world.describe()["localization_fixes"] == 4


def test_a_fix_with_a_smaller_gain_moves_part_of_the_way():
    plant = Zumo()
    world = SimWorld(plant, dt=0.1, plant_params={"r": 0.021}, localization={
        "source": "odometry", "fix": {"period_s": 1.0, "gain": 0.25, "std": {"position": 0}}})
    before = SimWorld(plant, dt=0.1, localization={"source": "odometry"}, plant_params={"r": 0.021})
    x, est = _drive(world, np.zeros(3), _wiggle(10))[-1]
    _, free = _drive(before, np.zeros(3), _wiggle(10))[-1]
    np.testing.assert_allclose(est[:2], free[:2] + 0.25 * (x[:2] - free[:2]), atol=1e-12)
    assert est[2] == pytest.approx(free[2], abs=1e-12)  # the heading was not measured


def test_the_lags_step_response_is_exponential():
    T, dt, c = 0.05, 0.1, 10.0
    act = Actuator(time_constant_s=T)
    act.reset(2)
    pieces, out = act.respond([(np.array([c, c]), dt)], dt)
    assert sum(d for _, d in pieces) == pytest.approx(dt)
    assert max(d for _, d in pieces) <= T / 4 + 1e-12
    t = np.cumsum([d for _, d in pieces])
    travel = np.cumsum([u[0] * d for u, d in pieces])
    np.testing.assert_allclose(travel, c * (t - T * (1 - np.exp(-t / T))), rtol=1e-12)
    np.testing.assert_allclose(out, c * (1 - math.exp(-dt / T)), rtol=1e-12)


def test_the_zumo_behind_a_lag_travels_what_the_lag_lets_it():
    r, T, c = 0.02, 0.05, 10.0
    world = SimWorld(Zumo(), dt=0.1, actuator={"time_constant_s": T})
    rows = _drive(world, np.zeros(3), [np.array([c, c])] * 5)
    for k, (x, _) in enumerate(rows):
        t = 0.1 * k
        assert x[0] == pytest.approx(r * c * (t - T * (1 - math.exp(-t / T))), abs=1e-12)
    np.testing.assert_allclose(world.actuator.output, c * (1 - math.exp(-0.5 / T)), rtol=1e-9)


def test_a_rate_limit_ramps_then_holds():
    act = Actuator(rate_limit=50.0)
    act.reset(2)
    pieces, out = act.respond([(np.array([10.0, -2.0]), 0.3)], 0.1)
    np.testing.assert_allclose(out, [10.0, -2.0])
    t = np.cumsum([d for _, d in pieces])
    travel = np.cumsum([u * d for u, d in pieces], axis=0)
    # wheel 1 ramps for 0.2 s (10 / 50), wheel 2 for 0.04 s; then each holds its command
    ramp = np.minimum(t, 0.2)
    np.testing.assert_allclose(travel[:, 0], 25 * ramp**2 + 10 * (t - ramp), atol=1e-12)
    ramp2 = np.minimum(t, 0.04)
    np.testing.assert_allclose(travel[:, 1], -25 * ramp2**2 - 2 * (t - ramp2), atol=1e-12)
    assert pieces[-1][1] == pytest.approx(0.1)  # once reached: one piece


def test_a_closed_loop_run_logs_commanded_and_actual_inputs_and_repeats(run_cfg):
    world = [*ZUMO, "sim.localization.source=odometry", "sim.plant_params.r=0.021",
             "sim.localization.odometry.slip_std=0.02", "sim.localization.fix.period_s=1.0",
             "sim.localization.fix.std.position=0.005", "sim.actuator.time_constant_s=0.05",
             "scenario.t_max=3.0", "seed=7"]
    a, _ = run_cfg(world, name="a")
    b, _ = run_cfg(world, name="b")
    timing = [c for c in record.TIMING_COLUMNS if c in a.steps]
    pd.testing.assert_frame_equal(a.steps.drop(columns=timing), b.steps.drop(columns=timing))
    calls = record.controller_steps(a.steps)
    assert {"actual_u1", "actual_u2", "meas_x", "meas_theta"} <= set(calls)
    assert calls["actual_u1"].iloc[0] == 0.0  # at rest before the first command
    lagged = (calls[["u1", "u2"]].shift() - calls[["actual_u1", "actual_u2"]].to_numpy()).iloc[1:]
    assert np.abs(lagged.to_numpy()).max() > 0  # the wheels had not reached the command
    s = a.summary
    assert s["sim_localization"] == "odometry" and s["localization_fixes"] >= 2
    assert s["sim_actuator"] == {"time_constant_s": 0.05, "rate_limit": None}
    assert 0 < s["localization_error_max_m"] < 0.1


def test_the_default_world_adds_nothing(run_cfg):
    result, _ = run_cfg([*ZUMO, "scenario.t_max=1.0"])
    assert not [c for c in result.steps if c.startswith(("meas_", "actual_"))]
    s = result.summary
    assert s["sim_localization"] == "truth" and s["sim_actuator"] is None
    assert s["localization_error_max_m"] is None


@pytest.mark.parametrize("options, match", [
    ({"localization": {"source": "gps"}},
     "sim.localization.source: unknown choice 'gps'; valid: truth, odometry"),
    ({"localization": {"fix": {"period_s": 1.0}}},
     "only with sim.localization.source=odometry"),
    ({"localization": {"odometry": {"slip_std": 0.1}}},
     "only with sim.localization.source=odometry"),
    ({"localization": {"source": "odometry", "fix": {"period_s": 0}}},
     "sim.localization.fix.period_s: expected a finite number > 0, got 0"),
    ({"localization": {"source": "odometry", "fix": {"period_s": 1, "gain": 1.5}}},
     r"sim.localization.fix.gain: expected a number in \(0, 1\], got 1.5"),
    ({"localization": {"source": "odometry", "fix": {"period_s": 1, "std": {"z": 1}}}},
     "unknown key 'z' in sim.localization.fix.std"),
    ({"localization": {"source": "odometry", "odometry": {"quantum": {"u1": 0}}}},
     "sim.localization.odometry.quantum.u1: expected a finite number > 0, got 0"),
    ({"localization": {"source": "odometry", "odometry": {"input_std": {"v": 0.1}}}},
     "unknown key 'v' in sim.localization.odometry.input_std"),
    ({"actuator": {"time_constant_s": -0.1}},
     "sim.actuator.time_constant_s: expected a finite number > 0, got -0.1"),
    ({"actuator": {"rate_limit": "fast"}},
     "sim.actuator.rate_limit: expected a finite number > 0, got 'fast'"),
    ({"actuator": {"lag": 0.1}}, "unknown key 'lag' in sim.actuator"),
])
def test_bad_values_name_the_key_the_value_and_what_is_valid(options, match):
    with pytest.raises(ConfigError, match=match):
        SimWorld(Zumo(), dt=0.1, **options)
