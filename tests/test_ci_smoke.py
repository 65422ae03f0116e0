"""``+ci=smoke`` shrinks every experiment in ``conf/experiment/`` (found when the tests run).

Each experiment, composed with ``+ci=smoke``, must run to a run record without error in one
simulated second at most, with no recorder and no figures.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import CONF, compose_cfg
from mpclab.recorders.base import Recorder
from mpclab.runner.single_run import run_experiment

EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
SMOKE_T_MAX = 1.0


def test_experiments_are_found() -> None:
    assert "car_cvxpy" in EXPERIMENTS


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_smoke_shrinks_and_runs(name: str, tmp_path: Path) -> None:
    full = compose_cfg([f"+experiment={name}"])
    cfg = compose_cfg([f"+experiment={name}", "+ci=smoke"])
    assert cfg.scenario.t_max == min(SMOKE_T_MAX, full.scenario.t_max) == SMOKE_T_MAX
    assert cfg.recorder._target_.endswith(f"{Recorder.__module__}.{Recorder.__qualname__}")
    assert not cfg.figures.enabled and not cfg.progress
    s = run_experiment(cfg, tmp_path).summary
    assert s["status"] != "error", s["error"]
    dt = cfg.controller.dt
    assert s["sim_time_s"] <= SMOKE_T_MAX + 1e-9 and s["n_steps"] <= round(SMOKE_T_MAX / dt)
    written = {p.name for p in tmp_path.iterdir()}
    assert {"steps.parquet", "summary.json"} <= written
    assert not [f for f in written if f.endswith((".png", ".rrd"))], written
