"""Warm sweep workers: a shared tree gives Hydra's config, reused components repeat a run.

A sweep worker composes each job from a tree shared by the jobs that differ only in values
(mpclab.sweeps.compose) and reuses the plant, objective and controller of an earlier job of
the same structure (mpclab.warm). Both must be invisible in the results: the config is
Hydra's own, and a run on a reused controller is the run a freshly built one makes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import ConfigCompositionException
from hydra.types import RunMode
from omegaconf import OmegaConf

from conftest import CONF
from mpclab import record
from mpclab.experiment import compose, run_experiment
from mpclab.registry import register_all
from mpclab.sweeps.compose import JobComposer
from mpclab.warm import ComponentCache, structure_key

JOBS = [
    ["+experiment=zumo_bug2", "scenario=zumo_random", "seed=3", "recorder=none"],
    ["+experiment=zumo_bug2", "scenario=zumo_random", "seed=4", "recorder=none",
     "controller.horizon=12", "+extra_key=1"],
    ["+experiment=car_cvxpy", "controller=casadi", "seed=1", "+tag=a", "~tag"],
    ["+experiment=car_cvxpy", "seed=2", "figures.enabled=false"],
]


@pytest.fixture
def loader():
    register_all()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        yield GlobalHydra.instance().config_loader()


def test_a_shared_tree_gives_hydras_job_config(loader) -> None:
    master = loader.load_configuration(
        "config", ["+experiment=car_cvxpy", "hydra.launcher.n_jobs=2"], RunMode.MULTIRUN)
    composer = JobComposer(loader, master)
    for overrides in [*JOBS, *JOBS]:  # the second round from the kept trees
        want = loader.load_sweep_config(master, list(overrides))
        got = composer.job_config(overrides)
        assert OmegaConf.to_yaml(got) == OmegaConf.to_yaml(want), overrides
        task = [k for k in want if k != "hydra"]
        assert (OmegaConf.to_container(OmegaConf.masked_copy(got, task), resolve=True)
                == OmegaConf.to_container(OmegaConf.masked_copy(want, task), resolve=True))
        assert got._get_flag("struct") == want._get_flag("struct")
    # each job gets its own copy
    a = composer.job_config(JOBS[0])
    a.seed = 99
    assert composer.job_config(JOBS[0]).seed == 3


@pytest.mark.parametrize("bad", ["controller.horizon=ten", "controller.nope=1",
                                 "scenario=nowhere", "+seed=1", "~nope", "~seed=5",
                                 "nope@pkg=a"])
def test_a_shared_tree_fails_as_hydra_does(loader, bad: str) -> None:
    master = loader.load_configuration("config", ["+experiment=car_cvxpy"], RunMode.MULTIRUN)
    composer = JobComposer(loader, master)
    composer.job_config(["+experiment=car_cvxpy", "seed=0"])  # a kept tree
    overrides = ["+experiment=car_cvxpy", bad]
    with pytest.raises(ConfigCompositionException) as want:
        loader.load_sweep_config(master, overrides)
    with pytest.raises(ConfigCompositionException) as got:
        composer.job_config(overrides)
    assert str(got.value) == str(want.value)


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
