"""Warm sweep workers: reused components repeat a run.

A sweep worker reuses the plant, objective and controller of an earlier job of the same
structure (mpclab.runner.component_cache). That must be invisible in the results: a run on a reused
controller is the run a freshly built one makes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpclab.record import files as record
from mpclab.runner.component_cache import ComponentCache, structure_key
from mpclab.runner.single_run import compose, run_experiment

JOBS = [
    ["+experiment=zumo_bug2", "scenario=zumo_random", "seed=3", "recorder=none"],
    ["+experiment=zumo_bug2", "scenario=zumo_random", "seed=4", "recorder=none",
     "controller.horizon=12", "+extra_key=1"],
    ["+experiment=car_cvxpy", "controller=casadi", "seed=1", "+tag=a", "~tag"],
    ["+experiment=car_cvxpy", "seed=2", "figures.enabled=false"],
]


def _steps(run_dir: Path) -> pd.DataFrame:
    steps = record.read_steps(run_dir)
    return steps.drop(columns=[c for c in record.TIMING_COLUMNS if c in steps])


@pytest.mark.slow
@pytest.mark.parametrize("experiment", ["zumo_bug2", "car_cvxpy", "bicycle_scheduled"])
def test_a_reused_controller_repeats_a_fresh_run(tmp_path: Path, experiment: str) -> None:
    base = [f"+experiment={experiment}", "+ci=smoke", "recorder=none", "progress=false"]
    if experiment == "zumo_bug2":
        base.append("scenario=zumo_random")
    cache = ComponentCache()
    for seed in (0, 1):  # seed 1 runs on the controller seed 0 built and used
        run_experiment(compose([*base, f"seed={seed}"]), tmp_path / f"warm{seed}", cache=cache)
    assert (cache.hits, cache.misses) == (1, 1)
    run_experiment(compose([*base, "seed=1"]), tmp_path / "fresh")
    warm, fresh = _steps(tmp_path / "warm1"), _steps(tmp_path / "fresh")
    assert list(warm.columns) == list(fresh.columns) and len(warm) == len(fresh)
    numbers = warm.select_dtypes("number").columns
    assert np.allclose(warm[numbers], fresh[numbers], rtol=1e-6, atol=1e-8, equal_nan=True)
    assert (warm["status"] == fresh["status"]).all()


def test_structure_key_ignores_what_does_not_shape_the_controller() -> None:
    a = compose(["+experiment=car_cvxpy", "seed=0"])
    b = compose(["+experiment=car_cvxpy", "seed=5", "scenario.t_max=3.0", "recorder=none"])
    c = compose(["+experiment=car_cvxpy", "controller.horizon=12"])
    assert structure_key(a) == structure_key(b) != structure_key(c)
