"""BARN worlds read from the challenge's files (the three shipped training worlds), placed for
the plant, and scored as the challenge scores them."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import CONF, compose_cfg
from mpclab.config.instantiate import build
from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo
from mpclab.record.stats import bootstrap_mean
from mpclab.tables.groups import group_table
from mpclab.world.barn import (
    TEST_WORLDS,
    TRAIN_WORLDS,
    BarnScenario,
    plant_top_speed,
    read_world,
    score,
)

SHIPPED = (1, 151, 299)
#: the Zumo as the experiments bound it (wheels within +-10 rad/s: 0.2 m/s at the top)
ZUMO = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})


@pytest.mark.parametrize("index", SHIPPED)
def test_the_a_star_path_keeps_the_challenges_clearance_in_our_frame(index) -> None:
    """The challenge's fact, checked in the frame this reader puts the cells in: every A*
    path cell keeps 0.375 m from every cylinder surface, and no more (one cell off in the
    mapping would break either)."""
    world = read_world(CONF / "barn", index)
    text = (CONF / "barn" / f"world_{index}.world").read_text()
    models = set(re.findall(r"<model name='(unit_cylinder_\d+)'>", text))
    assert len(world.cylinders) == len(models) and np.allclose(world.cylinders[:, 2], 0.075)
    cells = world.path[1:-1]
    gap = (np.linalg.norm(cells[:, None, :] - world.cylinders[None, :, :2], axis=2)
           - world.cylinders[None, :, 2])
    assert gap.min() == pytest.approx(0.375, abs=1e-9)
    np.testing.assert_allclose(world.path[0], (-2.25, 3.0))
    np.testing.assert_allclose(world.path[-1], (-2.25, 13.0))
    # the path's length is at least the straight line from start to goal
    assert world.path_length >= 10.0


def test_the_score_is_the_challenges() -> None:
    ot = 4.0
    assert score(True, 1.0, ot) == pytest.approx(0.5)      # faster than 2 OT: clipped
    assert score(True, 16.0, ot) == pytest.approx(0.25)
    assert score(True, 100.0, ot) == pytest.approx(0.125)  # slower than 8 OT: clipped
    assert score(False, 16.0, ot) == 0.0
    assert score(True, None, ot) == 0.0


def test_the_world_is_placed_at_scale_with_the_challenges_rules() -> None:
    plant = ZUMO
    s = 0.25
    scen = BarnScenario(plant, world=1, scale=s)
    world = read_world(CONF / "barn", 1)
    v = plant_top_speed(plant, scen.x0)
    assert v == pytest.approx(0.02 * 10.0)  # wheel radius times the wheels' bound
    ix, iy = plant.state_index("x"), plant.state_index("y")
    np.testing.assert_allclose(scen.x0[[ix, iy]], (s * -2.25, s * 3.0))
    assert scen.x0[plant.state_index("theta")] == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(scen.goal[[ix, iy]], (s * -2.25, s * 13.0))
    np.testing.assert_allclose(scen.obstacles[:, :2], s * world.cylinders[:, :2])
    np.testing.assert_allclose(scen.obstacles[:, 2], s * 0.075)
    # 1 m of success radius and 100 s of time limit, scaled in space and in time
    assert scen.arrival_threshold == pytest.approx((s * 1.0) ** 2)
    assert scen.t_max == pytest.approx(100.0 * s * 2.0 / v)
    assert scen.optimal_time_s == pytest.approx(s * world.path_length / v)
    # the start is clear, and one step short of the success radius is not arrived
    assert scen.clearance(scen.x0) > 0
    near = scen.goal.copy()
    near[iy] -= s * 1.0 - 1e-3
    far = scen.goal.copy()
    far[iy] -= s * 1.0 + 1e-3
    assert scen.arrived(near) and not scen.arrived(far)


def test_barn_metrics_follow_the_status() -> None:
    scen = BarnScenario(ZUMO, world=151)
    steps = _still_steps(scen)
    won = scen.metrics(steps, {"status": "arrived", "arrival_time_s": 3 * scen.optimal_time_s})
    assert won["barn_success"] and not won["barn_collision"] and not won["barn_timeout"]
    assert won["barn_score"] == pytest.approx(1 / 3)
    for status, key in (("collision", "barn_collision"), ("timeout", "barn_timeout"),
                        ("stalled", "barn_timeout")):
        lost = scen.metrics(steps, {"status": status, "arrival_time_s": None})
        assert lost[key] and not lost["barn_success"] and lost["barn_score"] == 0.0


def _still_steps(scen: BarnScenario):
    plant = scen.plant
    row = {label: float(v) for label, v in zip(plant.states, scen.x0, strict=True)}
    row |= {label: 0.0 for label in plant.inputs} | {"t": 0.0}
    return pd.DataFrame([row, row | {"t": 0.2}])


def _copy(tmp_path: Path, index: int = 1) -> Path:
    (tmp_path / "path_files").mkdir()
    shutil.copy(CONF / "barn" / f"world_{index}.world", tmp_path)
    shutil.copy(CONF / "barn" / "path_files" / f"path_{index}.npy", tmp_path / "path_files")
    return tmp_path


def test_a_missing_truncated_or_foreign_file_is_one_clear_error(tmp_path) -> None:
    with pytest.raises(ConfigError, match="scenario.barn_dir: no folder"):
        read_world(tmp_path / "nowhere", 1)
    folder = _copy(tmp_path)
    with pytest.raises(ConfigError, match=r"scenario.world: no world file .*world_2\.world"):
        read_world(folder, 2)
    world = folder / "world_1.world"
    text = world.read_text()
    world.write_text(text[: len(text) // 2])
    with pytest.raises(ConfigError, match="not a complete SDF file"):
        read_world(folder, 1)
    world.write_text("<html><body>a web page</body></html>")
    with pytest.raises(ConfigError, match="not a Gazebo SDF world"):
        read_world(folder, 1)
    world.write_text("<sdf version='1.6'><world name='default'></world></sdf>")
    with pytest.raises(ConfigError, match="holds no cylinder"):
        read_world(folder, 1)
    world.write_text(text)
    path = folder / "path_files" / "path_1.npy"
    np.save(path, np.zeros((5, 3), dtype=int))
    with pytest.raises(ConfigError, match="not BARN's path"):
        read_world(folder, 1)
    path.write_bytes(b"not numpy")
    with pytest.raises(ConfigError, match="not a NumPy array file"):
        read_world(folder, 1)


def test_the_scenario_refuses_a_bad_world_index_by_name() -> None:
    cfg = compose_cfg(["+experiment=zumo_bug2", "scenario=barn", "scenario.world=2"])
    with pytest.raises(ConfigError, match="scenario.world: no world file"):
        build(cfg.scenario, "scenario", plant=ZUMO)
    for bad in (-1, 300, 1.5):
        with pytest.raises(ConfigError, match="scenario.world: expected a world index"):
            BarnScenario(ZUMO, world=bad)


def test_the_challenges_test_worlds_are_refused_unless_asked_for(tmp_path) -> None:
    assert len(TEST_WORLDS) == 50 and len(TRAIN_WORLDS) == 250 and 294 in TEST_WORLDS
    with pytest.raises(ConfigError, match="scenario.world=6: one of the challenge's test"):
        BarnScenario(ZUMO, world=6, barn_dir=str(tmp_path))
    # asked for, it is read like any other (here: no such file in an empty folder)
    with pytest.raises(ConfigError, match="no world file"):
        BarnScenario(ZUMO, world=6, barn_dir=str(tmp_path), test_worlds=True)


def test_barn_runs_from_the_command_and_its_summary_holds_the_barn_fields(run_cfg) -> None:
    result, _ = run_cfg(["+experiment=zumo_bug2", "scenario=barn", "scenario.world=299",
                         "+ci=smoke"])
    s = result.summary
    assert s["scenario"] == "barn" and s["barn_world"] == 299 and s["status"] == "timeout"
    assert s["barn_timeout"] and not s["barn_success"] and s["barn_score"] == 0.0
    assert s["barn_optimal_time_s"] > 0 and s["barn_top_speed"] == pytest.approx(0.2)


def test_the_grouped_table_has_barns_rates_and_mean_score() -> None:
    statuses = ["arrived"] * 6 + ["collision", "timeout", "stalled", "arrived"]
    scores = [0.4, 0.3, 0.45, 0.2, 0.35, 0.5, 0.0, 0.0, 0.0, None]  # one run wrote none
    df = pd.DataFrame({"backend": "casadi:fatrop", "scenario": "barn", "status": statuses,
                       "barn_score": scores, "run_dir": [f"r{i}" for i in range(10)],
                       "arrival_time_s": 1.0, "scenario.world": range(1, 11)})
    df.attrs["params"] = ["scenario.world"]  # the sweep's worlds: pooled, as the challenge's
    table = group_table(df, {f"r{i}": np.array([1.0]) for i in range(10)})
    assert len(table) == 1 and "scenario.world" not in table
    g = table.iloc[0]
    assert g["success_rate"] == pytest.approx(0.7) and g["collision_rate"] == pytest.approx(0.1)
    assert g["barn_timeout_rate"] == pytest.approx(0.2)
    assert g["barn_timeout_low"] < 0.2 < g["barn_timeout_high"]
    assert g["barn_score_mean"] == pytest.approx(2.2 / 10)
    assert g["barn_score_low"] < g["barn_score_mean"] < g["barn_score_high"]


def test_the_bootstrap_interval_of_a_mean_matches_the_normal_one_for_a_large_sample() -> None:
    x = np.random.default_rng(3).normal(1.0, 2.0, size=2000)
    lo, hi = bootstrap_mean(x)
    half = 1.959964 * x.std(ddof=1) / math.sqrt(x.size)
    assert lo == pytest.approx(x.mean() - half, abs=0.1 * half)
    assert hi == pytest.approx(x.mean() + half, abs=0.1 * half)
    assert bootstrap_mean([0.3]) == (pytest.approx(0.3), pytest.approx(0.3))
    assert all(math.isnan(v) for v in bootstrap_mean([]))


def test_the_training_sweep_lists_exactly_the_training_worlds() -> None:
    doc = yaml.safe_load((CONF / "sweep" / "barn_train.yaml").read_text())
    listed = str(doc["hydra"]["sweeper"]["params"]["scenario.world"]).split(",")
    assert tuple(int(v) for v in listed) == TRAIN_WORLDS
