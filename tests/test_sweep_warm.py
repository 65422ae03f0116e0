"""Warm sweep workers: cached compose equals Hydra's, reused components repeat a fresh run.

A sweep worker composes each job from a cached defaults tree (mpclab.sweeps.compose) and
reuses the plant, objective and controller of an earlier job of the same structure
(mpclab.warm). Both must be invisible in the results: the config is Hydra's own, and a run
on a reused controller is the run a freshly built one makes.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import ConfigCompositionException
from hydra.types import RunMode
from omegaconf import OmegaConf, open_dict, read_write

from conftest import CONF
from mpclab import record
from mpclab.experiment import compose, run_experiment
from mpclab.registry import register_all
from mpclab.sweeps import compose as compose_module
from mpclab.sweeps.compose import CachedComposeLoader, composing_once
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


def test_cached_compose_is_hydras_compose(loader) -> None:
    master = loader.load_configuration(
        "config", ["+experiment=car_cvxpy", "hydra.launcher.n_jobs=2"], RunMode.MULTIRUN)
    cached = CachedComposeLoader(loader)
    for overrides in [*JOBS, *JOBS]:  # the second round comes from the cache
        want = loader.load_sweep_config(master, list(overrides))
        got = cached.load_sweep_config(master, list(overrides))
        assert OmegaConf.to_yaml(got) == OmegaConf.to_yaml(want), overrides
        task = [k for k in want if k != "hydra"]
        assert (OmegaConf.to_container(OmegaConf.masked_copy(got, task), resolve=True)
                == OmegaConf.to_container(OmegaConf.masked_copy(want, task), resolve=True))
        # the task's copy: Hydra's run_job deletes ``hydra`` from a deep copy
        want_task = copy.deepcopy(want)
        with read_write(want_task), open_dict(want_task):
            del want_task["hydra"]
        got_task = cached.load_task_config(master, list(overrides))
        assert OmegaConf.to_yaml(got_task) == OmegaConf.to_yaml(want_task), overrides
        assert got_task._get_flag("struct") == want_task._get_flag("struct")
    # each job gets its own copy
    a = cached.load_sweep_config(master, JOBS[0])
    a.seed = 99
    assert cached.load_sweep_config(master, JOBS[0]).seed == 3


@pytest.mark.parametrize("bad", ["controller.horizon=ten", "controller.nope=1",
                                 "scenario=nowhere", "+seed=1"])
def test_cached_compose_fails_as_hydra_does(loader, bad: str) -> None:
    master = loader.load_configuration("config", ["+experiment=car_cvxpy"], RunMode.MULTIRUN)
    cached = CachedComposeLoader(loader)
    cached.load_sweep_config(master, ["+experiment=car_cvxpy", "seed=0"])  # warm the cache
    overrides = ["+experiment=car_cvxpy", bad]
    with pytest.raises(ConfigCompositionException) as want:
        loader.load_sweep_config(master, overrides)
    with pytest.raises(ConfigCompositionException) as got:
        cached.load_sweep_config(master, overrides)
    assert str(got.value) == str(want.value)


COMMANDS = [
    (["+experiment=zumo_bug2", "seed=range(0,4)", "controller.horizon=8,10",
      "hydra.launcher.n_jobs=2", "hydra.mode=MULTIRUN"], RunMode.MULTIRUN),
    (["+experiment=car_cvxpy", "controller=casadi,cvxpy", "seed=1"], RunMode.MULTIRUN),
    (["hydra/launcher=joblib", "+experiment=car_cvxpy", "+tag=a", "figures.enabled=false"],
     RunMode.MULTIRUN),
    (["+experiment=car_cvxpy", "seed=2", "~figures"], RunMode.RUN),
    (["+experiment=zumo_bug2", "scenario=zumo_random", "hydra.job.chdir=false"], RunMode.RUN),
]


@pytest.mark.parametrize(("overrides", "mode"), COMMANDS)
def test_a_cached_command_config_is_hydras(loader, monkeypatch, overrides, mode) -> None:
    monkeypatch.setattr(compose_module, "_BASES", OrderedDict())
    want = loader.load_configuration("config", overrides, mode)
    cached = CachedComposeLoader(loader)
    for _ in range(2):  # composed, then from the cache
        got = cached.load_configuration("config", overrides, mode)
        assert OmegaConf.to_yaml(got) == OmegaConf.to_yaml(want)


def test_a_multirun_command_and_its_jobs_share_one_tree(loader, monkeypatch, tmp_path,
                                                        request) -> None:
    monkeypatch.setattr(compose_module, "_BASES", OrderedDict())
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))  # no tree stored by an earlier command
    hydra = GlobalHydra.instance().hydra
    original = hydra.config_loader
    sweep = ["+experiment=zumo_bug2", "seed=range(0,4)", "controller.horizon=8,10",
             "hydra.launcher.n_jobs=2"]
    want = hydra.compose_config("config", [*sweep, "hydra.mode=MULTIRUN"], RunMode.MULTIRUN)
    job = ["+experiment=zumo_bug2", "seed=3", "controller.horizon=10"]
    want_job = original.load_sweep_config(want, job)
    calls = request.getfixturevalue("hydra_calls")  # from here on
    compose_module._BASES[("stale",)] = (b"", b"")  # a tree kept by an earlier command
    with composing_once():
        assert ("stale",) not in compose_module._BASES  # each command composes anew
        assert hydra.get_mode("config", sweep) is None  # as Hydra's: no config sets the mode
        got = hydra.compose_config("config", [*sweep, "hydra.mode=MULTIRUN"], RunMode.MULTIRUN)
        assert calls == [RunMode.RUN]  # the tree of the group overrides, once
        assert OmegaConf.to_yaml(got) == OmegaConf.to_yaml(want)
        assert (OmegaConf.to_yaml(hydra.config_loader.load_sweep_config(got, job))
                == OmegaConf.to_yaml(want_job))
        assert calls == [RunMode.RUN]  # a job of the sweep: the same tree
        # a single run: its tree once, for both of Hydra's compositions
        hydra.get_mode("config", ["+experiment=car_cvxpy"])
        hydra.compose_config("config", ["+experiment=car_cvxpy"], RunMode.RUN)
        assert calls == [RunMode.RUN] * 2
        # the sweep overrides are still checked, as Hydra checks them
        bad = ["+experiment=car_cvxpy", "hydra.run.dir=a,b"]
        hydra.get_mode("config", bad)
        with pytest.raises(ConfigCompositionException, match="hydra.run.dir"):
            hydra.compose_config("config", [*bad, "hydra.mode=MULTIRUN"], RunMode.MULTIRUN)
    assert "get_mode" not in vars(hydra) and hydra.config_loader is original
    assert not compose_module._BASES  # nothing kept for the next command


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
