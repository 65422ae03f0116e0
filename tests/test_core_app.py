"""The Hydra app: configs compose, bad input is named, the loop runs and records."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException, MissingConfigException
from omegaconf.errors import ConfigKeyError

from conftest import CONF, ROOT, compose_cfg
from mpclab.core.errors import ConfigError
from mpclab.record import files as record
from mpclab.runner.single_run import build_run

EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
SUMMARY_KEYS = {
    "experiment", "plant", "controller", "scenario", "seed", "status", "arrived",
    "arrival_time_s", "n_steps", "sim_time_s", "compute_total_s", "compute_median_ms",
    "compute_p95_ms", "compute_max_ms", "rtf", "min_clearance_m", "solver_failures", "versions",
}


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_experiment_composes(name: str) -> None:
    cfg = compose_cfg([f"+experiment={name}"])
    assert cfg.name == name
    for group in ("plant", "controller", "objective", "scenario", "supervisor", "recorder"):
        assert "_target_" in cfg[group], group


def _error_text(excinfo: pytest.ExceptionInfo) -> str:
    """The whole message chain, as Hydra prints it."""
    parts, exc = [], excinfo.value
    while exc is not None:
        parts.append(str(exc))
        exc = exc.__cause__ or exc.__context__
    return "\n".join(parts)


def test_typo_in_override_names_the_key() -> None:
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(["+experiment=car_cvxpy", "controller.horizn=5"])
    assert "Key 'horizn' not in 'CvxpyMPCConf'" in _error_text(err)
    assert "controller.horizn" in _error_text(err)


def test_typo_in_a_yaml_file_names_the_key(tmp_path: Path) -> None:
    conf = tmp_path / "conf"
    shutil.copytree(CONF, conf)
    (conf / "experiment" / "typo.yaml").write_text(
        "# @package _global_\ndefaults:\n  - override /controller: cvxpy\n"
        "name: typo\ncontroller:\n  horizom: 12\n"
    )
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        with pytest.raises((ConfigCompositionException, ConfigKeyError)) as err:
            compose(config_name="config", overrides=["+experiment=typo"])
    assert "horizom" in _error_text(err)


def test_wrong_type_names_key_and_type() -> None:
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(["+experiment=car_cvxpy", "controller.horizon=ten"])
    text = _error_text(err)
    assert "Value 'ten' of type 'str' could not be converted to Integer" in text
    assert "controller.horizon" in text


def test_unknown_enum_value_lists_the_choices() -> None:
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(["+experiment=car_cvxpy", "controller.solver=ECOS"])
    assert "Invalid value 'ECOS', expected one of [CLARABEL, OSQP]" in _error_text(err)


def test_unknown_plant_lists_the_choices() -> None:
    with pytest.raises(MissingConfigException) as err:
        compose_cfg(["+experiment=car_cvxpy", "plant=kinematic_cr"])
    text = _error_text(err)
    assert "Could not find 'plant/kinematic_cr'" in text
    assert "Available options in 'plant'" in text and "kinematic_car" in text


def test_typo_in_plant_param_names_the_key() -> None:
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(["+experiment=car_cvxpy", "plant.params.wheelbase=2"])
    assert "Key 'wheelbase' not in 'KinematicCarParams'" in _error_text(err)


def test_typo_in_an_objective_term_names_key_path_and_valid_keys() -> None:
    cfg = compose_cfg(["+experiment=car_cvxpy", "+objective.terms.tracking.stat_weights={px: 1}"])
    with pytest.raises(ConfigError) as err:
        build_run(cfg)
    text = str(err.value)
    assert "unknown key 'stat_weights' in objective.terms.tracking" in text
    assert "Did you mean 'state_weights'?" in text
    assert "input_weights, state_weights, terminal_weights" in text


def test_unknown_label_in_scenario_is_named() -> None:
    cfg = compose_cfg(["+experiment=car_cvxpy", "+scenario.start.speed=1"])
    with pytest.raises(ConfigError, match="scenario.start: unknown state label 'speed'"):
        build_run(cfg)


def test_car_cvxpy_reaches_the_goal_and_writes_the_run_record(run_cfg) -> None:
    result, out = run_cfg(["+experiment=car_cvxpy"], figures=True)
    s = json.loads((out / record.SUMMARY).read_text())
    assert SUMMARY_KEYS <= set(s)
    assert s["status"] == "arrived" and s["arrived"] is True
    assert s["arrival_time_s"] <= 3.5  # the study's buggy linearization needed 11.4 s
    assert s["solver_failures"] == 0
    assert s["experiment"] == "car_cvxpy" and s["plant"] == "kinematic_car"
    assert s["controller"] == "cvxpy" and s["scenario"] == "car_to_origin"
    steps = pd.read_parquet(out / record.STEPS)
    for col in ("t", "px", "py", "theta", "v", "phi", "a", "phi_dot", "solve_time_s",
                "status", "mode", "cost"):
        assert col in steps.columns
    # the final row is the state at arrival, and it satisfies the stop rule
    last = steps.iloc[-1]
    assert last["status"] == record.FINAL
    assert last["px"] ** 2 + last["py"] ** 2 + last["v"] ** 2 < 1
    assert s["n_steps"] == len(steps) - 1
    assert last["t"] == pytest.approx(s["arrival_time_s"])
    # inputs and the steering bound hold on every step
    calls = steps.iloc[:-1]
    assert calls["a"].abs().max() <= 10 + 1e-6 and calls["phi_dot"].abs().max() <= 3 + 1e-6
    assert steps["phi"].abs().max() <= np.pi / 4 + 1e-6
    hz = pd.read_parquet(out / record.HORIZONS)
    assert hz["step"].nunique() == s["n_steps"] and len(hz) == s["n_steps"] * 11
    for png in ("path.png", "series.png"):
        assert (out / png).stat().st_size > 10_000


def test_two_runs_of_one_config_give_identical_step_logs(run_cfg) -> None:
    _, a = run_cfg(["+experiment=car_cvxpy"], name="a")
    _, b = run_cfg(["+experiment=car_cvxpy"], name="b")
    sa, sb = pd.read_parquet(a / record.STEPS), pd.read_parquet(b / record.STEPS)
    timing = list(record.TIMING_COLUMNS)
    pd.testing.assert_frame_equal(sa.drop(columns=timing, errors="ignore"),
                                  sb.drop(columns=timing, errors="ignore"))
    pd.testing.assert_frame_equal(
        pd.read_parquet(a / record.HORIZONS), pd.read_parquet(b / record.HORIZONS)
    )


def test_injected_solver_failures_are_survived_and_counted(run_cfg, monkeypatch) -> None:
    import cvxpy as cp

    from mpclab.controllers.cvxpy.mpc import CvxpyMPC

    real = CvxpyMPC._solve
    calls = {"n": 0}

    def flaky(self, t, x, ctx):
        calls["n"] += 1
        if calls["n"] in (4, 5, 9):
            raise cp.error.SolverError("injected")
        return real(self, t, x, ctx)

    monkeypatch.setattr(CvxpyMPC, "_solve", flaky)
    result, out = run_cfg(["+experiment=car_cvxpy"])
    s = result.summary
    assert s["status"] == "arrived"
    assert s["solver_failures"] == 3
    steps = pd.read_parquet(out / record.STEPS)
    assert list(steps.index[steps["fallback"]]) == [3, 4, 8]
    assert steps.loc[3, "status"] == "exception"
    assert steps.loc[3, "solver_status"] == "SolverError"


def test_module_entry_point_runs_from_the_repository_root(tmp_path: Path) -> None:
    out = tmp_path / "cli"
    proc = subprocess.run(
        [sys.executable, "-m", "mpclab", "+experiment=car_cvxpy", "+ci=smoke",
         f"hydra.run.dir={out}"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert (out / ".hydra" / "config.yaml").exists()
    assert json.loads((out / record.SUMMARY).read_text())["experiment"] == "car_cvxpy"


def test_help_lists_what_there_is_to_run_and_what_a_bare_run_composes() -> None:
    out = subprocess.run([sys.executable, "-m", "mpclab", "--help"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    text = out.stdout
    for name in ("zumo_bug2", "car_cvxpy", "bicycle_scheduled",  # experiments
                 "casadi_fatrop", "zumo_dead_end", "kinematic_car", "bug2", "realistic",
                 "mpclab.objectives.rate.InputRate"):  # choices and a term type
        assert name in text, name
    assert "schema/" not in text  # Hydra's internal schema entries are not choices
    assert "Without +experiment=NAME a run composes the bare defaults" in text
    # the config shown is the one a bare run composes (the car), not an experiment's
    assert "name: run" in text and "kinematic_car.KinematicCar" in text
