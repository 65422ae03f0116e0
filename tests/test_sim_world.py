"""The ``sim`` group: latency with a deadline, noise, disturbance, model mismatch, substeps.

Exact equality appears only where one computation is repeated in one process (the same
config and seed twice, the nominal loop against the plant's own step): that is what
reproducibility means. Everything else compares with tolerances.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_rerun import read_rrd, temporal, verify

from conftest import compose_cfg
from mpclab.core.errors import bad_input_message
from mpclab.plants.kinematic_car import KinematicCar
from mpclab.record import files as record
from mpclab.recorders import rerun_blueprint as ent
from mpclab.runner.single_run import build_run
from mpclab.world.sim_world import SimWorld

CAR = ["+experiment=car_cvxpy"]


def _log(result: object) -> pd.DataFrame:
    return result.steps.drop(columns=[c for c in record.TIMING_COLUMNS if c in result.steps])


def test_nominal_loop_integrates_the_controllers_model(run_cfg):
    """sim=nominal: every next state is the plant's own RK4 step from the logged input, and
    the log has no world columns (the step log as before the sim group existed)."""
    result, _ = run_cfg(CAR)
    steps, plant = result.steps, KinematicCar()
    X = steps[list(plant.states)].to_numpy()
    U = steps[list(plant.inputs)].to_numpy()
    for k in range(len(steps) - 1):
        assert np.array_equal(X[k + 1], plant.step(X[k], U[k], 0.1))
    assert not [c for c in steps if c.startswith(("meas_", "applied_", "latency"))]
    assert result.summary["sim"] == "nominal" and result.summary["deadline_misses"] == 0


def test_fixed_latency_integrates_across_the_switch(run_cfg):
    result, _ = run_cfg([*CAR, "sim.latency=30"])
    steps, plant = result.steps, KinematicCar()
    X = steps[list(plant.states)].to_numpy()
    U = steps[list(plant.inputs)].to_numpy()
    applied_before = np.zeros(plant.nu)  # nothing acts before the first input
    for k in range(3):
        expect = plant.step(plant.step(X[k], applied_before, 0.03), U[k], 0.07)
        np.testing.assert_allclose(X[k + 1], expect, rtol=1e-12, atol=1e-12)
        applied_before = U[k]
    calls = record.controller_steps(steps)
    np.testing.assert_allclose(calls["latency_s"], 0.03)
    np.testing.assert_allclose(calls["switch_t"], calls["t"] + 0.03)
    assert not calls["deadline_miss"].any()
    # 30 ms late on a 100 ms period: the car still arrives (3.4 s measured against 2.5 s:
    # its plan brakes hard at the end, and a late brake overshoots)
    assert result.summary["arrived"] and result.summary["arrival_time_s"] >= 2.5 - 1e-9


def test_missed_deadlines_hold_the_input_and_are_counted(run_cfg):
    result, _ = run_cfg([*CAR, "sim.latency=150", "scenario.t_max=1.0"])
    calls = record.controller_steps(result.steps)
    assert calls["deadline_miss"].all() and calls["switch_t"].isna().all()
    applied = calls[[f"applied_{u}" for u in KinematicCar.inputs]].to_numpy()
    assert np.abs(applied).max() == 0.0  # the car never got an input: it was never on time
    s = result.summary
    assert s["status"] == "timeout" and s["deadline_misses"] == s["n_steps"] == 10
    assert s["latency_median_ms"] == pytest.approx(150.0)


def test_deadline_policies():
    plant = KinematicCar()
    plan = np.arange(10.0).reshape(5, 2)  # u_pred: 5 inputs of 2
    for policy, expect in (("hold", [plan[0], plan[0], plan[0]]),
                           ("plan", [plan[1], plan[2], plan[3]])):
        w = SimWorld(plant, dt=0.1, latency="measured", timing={"deadline_policy": policy})
        w.reset(plant.nu)
        tm = w.timing(plan[0], plan, 0.01)
        assert not tm.missed
        w.advance(np.zeros(plant.nx), tm)
        for want in expect:
            tm = w.timing(plan[0] + 100, plan + 100, 0.5)  # too late: never acts
            assert tm.missed
            np.testing.assert_array_equal(tm.applied, want)
            w.advance(np.zeros(plant.nx), tm)


def test_noise_is_seeded_and_has_the_given_size(run_cfg):
    noisy = [*CAR, "sim.noise.state_std.position=0.01", "sim.noise.state_std.theta=0.02"]
    a, _ = run_cfg([*noisy, "seed=4"], name="a")
    b, _ = run_cfg([*noisy, "seed=4"], name="b")
    c, _ = run_cfg([*noisy, "seed=5"], name="c")
    assert _log(a).equals(_log(b))  # the same config and seed: the same log, noise included
    assert not np.allclose(a.steps["meas_px"].dropna(), c.steps["meas_px"].dropna())
    calls = record.controller_steps(a.steps)
    err = calls[["meas_px", "meas_py", "meas_theta"]].to_numpy() - \
        calls[["px", "py", "theta"]].to_numpy()
    assert np.all(np.abs(err[:, :2]) < 0.01 * 5) and np.all(np.abs(err[:, 2]) < 0.02 * 5)
    assert np.abs(err).min() > 0  # every reading is perturbed
    assert (err[:, 0] != err[:, 1]).all()  # independently per label


def test_disturbance_scales_with_the_period():
    plant = KinematicCar()
    w = SimWorld(plant, dt=0.04, seed=1, disturbance={"state_std": {"px": 0.5}})
    w.reset(plant.nu)
    still = np.zeros(plant.nx)
    tm = w.timing(np.zeros(plant.nu), np.zeros((1, plant.nu)), 0.0)
    jumps = np.array([w.advance(still, tm) for _ in range(4000)])
    # a random walk of 0.5 per square-root second: 0.5 * sqrt(0.04) = 0.1 per period
    assert np.std(jumps[:, 0]) == pytest.approx(0.1, rel=0.1)
    assert np.abs(jumps[:, 1:]).max() == 0.0


def test_mismatch_and_substeps_make_another_plant():
    cfg = compose_cfg(["+experiment=zumo_bug2", "recorder=none", "sim.plant_params.r=0.021",
                       "sim.substeps=4"])
    run = build_run(cfg)
    model, sim = run.plant, run.world.plant
    assert model.params.r == pytest.approx(0.02) and sim.params.r == pytest.approx(0.021)
    assert sim.substeps == 4 * model.substeps
    x, u = np.zeros(3), np.array([5.0, 5.0])
    # straight ahead at the same wheel speed: 5 % larger wheels go 5 % further
    assert sim.step(x, u, 0.2)[0] == pytest.approx(1.05 * model.step(x, u, 0.2)[0], rel=1e-9)
    assert run.world.describe()["sim_plant_params"] == {"r": pytest.approx(0.021)}


def test_bug2_arrives_with_a_larger_wheel_and_position_noise(run_cfg):
    """The issue's robustness case: 5 % wheel-radius mismatch, 5 mm position noise."""
    result, _ = run_cfg(["+experiment=zumo_bug2", "sim.plant_params.r=0.021",
                         "sim.noise.state_std.position=0.005", "sim.noise.range_std=0.005"])
    s = result.summary
    assert s["status"] == "arrived", s
    assert s["min_clearance_m"] > 0
    assert "meas_x" in result.steps


def test_realistic_preset_is_recorded(run_cfg):
    result, out = run_cfg(["+experiment=car_cvxpy", "sim=realistic", "recorder=rerun"])
    assert result.summary["sim"] == "realistic"
    assert result.summary["sim_latency"] == "recorded"
    verify(out / "run.rrd")
    rows = read_rrd(out / "run.rrd")
    n = result.summary["n_steps"]
    assert len(temporal(rows, ent.MEASURED)) == n
    assert len(temporal(rows, ent.LATENCY)) == n


@pytest.mark.parametrize("override, words", [
    ("sim.latency=fast", ["sim.latency", "fast", "measured", "one_sample"]),
    ("sim.latency=-5", ["sim.latency", "-5"]),
    ("sim.timing.latency_scale=0", ["sim.timing.latency_scale", "> 0"]),
    ("sim.timing.deadline_ms=500", ["sim.timing.deadline_ms", "100 ms"]),
    ("sim.timing.deadline_policy=skip",
     ["sim.timing.deadline_policy", "skip", "hold", "plan", "late_apply"]),
    ("sim.noise.state_std.pz=0.1", ["sim.noise.state_std", "pz", "px"]),
    ("sim.noise.state_std.px=-1", ["sim.noise.state_std.px", "-1"]),
    ("sim.noise.range_std=nan", ["sim.noise.range_std", "nan"]),
    ("sim.disturbance.state_std.vv=1", ["sim.disturbance.state_std", "vv"]),
    ("sim.plant_params.Lr=1", ["sim.plant_params", "Lr"]),
    ("sim.substeps=0", ["sim.substeps", "0"]),
])
def test_bad_sim_values_are_refused_by_name(override, words):
    with pytest.raises(Exception) as err:  # by Hydra while it composes, or by the world
        build_run(compose_cfg([*CAR, "recorder=none", override]))
    message = bad_input_message(err.value)
    assert message is not None, f"{override}: not read as bad input: {err.value!r}"
    for word in words:
        assert word in message, (override, message)
