"""Latency policies of the ``sim`` group: a late result applied when it is ready
(``late_apply``), the fixed one-sample delay, and the controller's delay compensation."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import compose_cfg
from mpclab.controllers.base import shift_by
from mpclab.core.errors import ConfigError
from mpclab.plants.kinematic_car import KinematicCar
from mpclab.record import files as record
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run
from mpclab.world.sim_world import SimWorld

BICYCLE_TURN = ["+experiment=bicycle_scheduled", "scenario=turn", "sim=embedded_stm32"]


def test_late_apply_acts_when_ready_and_skips_the_busy_samples():
    plant = KinematicCar()
    w = SimWorld(plant, dt=0.02, latency=33.8, timing={"deadline_policy": "late_apply"})
    w.reset(plant.nu)
    u = np.array([0.5, 0.1])
    tm = w.timing(u, np.tile(u, (4, 1)), 0.0)
    assert tm.missed and tm.late and tm.periods == 2  # busy until 33.8 ms: free at 40 ms
    assert tm.switch_s == pytest.approx(0.0338)
    (u0, d0), (u1, d1) = w.pieces(tm)
    np.testing.assert_array_equal(u0, np.zeros(plant.nu))
    np.testing.assert_array_equal(u1, u)
    assert d0 == pytest.approx(0.0338) and d0 + d1 == pytest.approx(0.04)
    x = w.advance(np.zeros(plant.nx), tm)
    expect = plant.step(plant.step(np.zeros(plant.nx), np.zeros(plant.nu), d0), u, d1)
    np.testing.assert_allclose(x, expect, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(w.applied, u)


def test_one_sample_delay_acts_at_the_next_sample_whatever_the_solve_took():
    plant = KinematicCar()
    w = SimWorld(plant, dt=0.1, latency="one_sample")
    w.reset(plant.nu)
    assert w.predicts and w.expected_latency_s() == pytest.approx(0.1)
    u = np.array([1.0, 0.0])
    tm = w.timing(u, np.tile(u, (3, 1)), 5.0)  # a solve far longer than the period
    assert not tm.missed and tm.latency_s == pytest.approx(0.1)
    [(held, span)] = w.pieces(tm)  # the period under the input before, the new one after
    np.testing.assert_array_equal(held, np.zeros(plant.nu))
    assert span == pytest.approx(0.1)
    w.advance(np.zeros(plant.nx), tm)
    np.testing.assert_array_equal(w.applied, u)
    assert w.describe()["sim_latency"] == "one_sample"


def test_late_apply_tracks_the_turn_where_hold_never_acts(run_cfg):
    """Study C's 33.8 ms at a 20 ms sample: under late_apply every input acts when ready
    and a solve runs every second sample; the car arrives."""
    result, _ = run_cfg([*BICYCLE_TURN, "sim.timing.deadline_policy=late_apply"])
    s = result.summary
    assert s["status"] == "arrived", s
    assert s["sim_deadline_policy"] == "late_apply"
    calls = record.controller_steps(result.steps)
    np.testing.assert_allclose(np.diff(calls["t"]), 0.04, atol=1e-9)
    assert calls["deadline_miss"].all()
    np.testing.assert_allclose(calls["switch_t"] - calls["t"], 0.0338, atol=1e-9)
    assert s["rms_position"] < 0.5


def test_one_sample_delay_tracks_the_turn(run_cfg):
    result, _ = run_cfg([*BICYCLE_TURN, "sim.latency=one_sample"])
    s = result.summary
    assert s["status"] == "arrived" and s["deadline_misses"] == 0, s
    calls = record.controller_steps(result.steps)
    np.testing.assert_allclose(calls["switch_t"] - calls["t"], 0.02, atol=1e-9)
    assert s["rms_position"] < 0.5


def test_shift_by_interpolates_and_holds_the_end():
    a = np.array([[0.0, 10.0], [1.0, 20.0], [2.0, 30.0]])
    np.testing.assert_allclose(shift_by(a, 0.5), [[0.5, 15.0], [1.5, 25.0], [2.0, 30.0]])
    np.testing.assert_allclose(shift_by(a, 0.0), a)


@pytest.mark.parametrize("experiment", ["car_casadi", "car_cvxpy"])
def test_delay_compensation_recovers_the_ideal_arrival(run_cfg, experiment):
    """90 ms of latency on a 100 ms period: compensated, the car arrives within 0.2 s of
    the ideal loop, with either backend."""
    ideal, _ = run_cfg([f"+experiment={experiment}"], name="ideal")
    late, _ = run_cfg([f"+experiment={experiment}", "sim.latency=90",
                       "sim.timing.delay_compensation=true", "scenario.t_max=6"], name="late")
    assert ideal.summary["arrived"] and late.summary["arrived"], late.summary
    assert late.summary["arrival_time_s"] <= ideal.summary["arrival_time_s"] + 0.2 + 1e-9


def test_previous_input_is_what_the_plant_received_on_a_miss():
    """Every deadline missed under hold: the plant never got an input, so the input-rate
    term's previous input stays zero though the controller's own plans are not."""
    run = build_run(compose_cfg(["+experiment=car_cvxpy", "recorder=none", "progress=false",
                                 "sim.latency=150", "scenario.t_max=0.5"]))
    simulate(run)
    ctrl = run.controller
    np.testing.assert_array_equal(ctrl.previous_input, np.zeros(run.plant.nu))
    assert np.abs(ctrl.previous_plan.u).max() > 0


def _log(result: object) -> object:
    return result.steps.drop(columns=[c for c in record.TIMING_COLUMNS if c in result.steps])


def test_realistic_bug2_repeats_exactly_with_the_same_seed(run_cfg):
    """The realistic preset draws its latencies, seeded, from a recorded profile: two runs
    of the same config and seed give the same step log, latencies included."""
    cfg = ["+experiment=zumo_bug2", "sim=realistic", "seed=3"]
    a, _ = run_cfg(cfg, name="a")
    b, _ = run_cfg(cfg, name="b")
    assert a.summary["sim_latency"] == "recorded"
    assert a.steps["latency_s"].notna().sum() > 10
    assert _log(a).equals(_log(b))


def test_recorded_latency_reads_a_runs_step_log(tmp_path):
    plant = KinematicCar()
    steps = tmp_path / "steps.parquet"
    pd.DataFrame({"t": [0.0, 0.1, 0.2], "latency_s": [0.01, 0.03, np.nan]}).to_parquet(steps)
    draws = []
    for seed in (5, 5, 6):
        w = SimWorld(plant, seed=seed, latency="recorded", timing={"latency_profile": str(steps)})
        w.reset(plant.nu)
        assert w.expected_latency_s() == pytest.approx(0.02)  # the median
        u = np.zeros((1, plant.nu))
        draws.append([w.timing(u[0], u, 9.0).latency_s for _ in range(40)])
    assert set(np.round(draws[0], 9)) == {0.01, 0.03}  # only recorded values, NaN dropped
    assert draws[0] == draws[1] and draws[0] != draws[2]  # seeded


@pytest.mark.parametrize("profile, words", [
    (None, ["sim.timing.latency_profile", "latency_s"]),
    ("no/such.csv", ["sim.timing.latency_profile", "no/such.csv"]),
    ("sim/nominal.yaml", ["sim.timing.latency_profile", ".csv or .parquet"]),
])
def test_a_bad_latency_profile_is_refused_by_name(profile, words):
    with pytest.raises(ConfigError) as err:
        SimWorld(KinematicCar(), latency="recorded", timing={"latency_profile": profile})
    for word in words:
        assert word in str(err.value), str(err.value)


def test_a_profile_without_latencies_is_refused(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,solve\n0,1\n")
    with pytest.raises(ConfigError, match="no latency_s column; columns: t, solve"):
        SimWorld(KinematicCar(), latency="recorded", timing={"latency_profile": str(bad)})
