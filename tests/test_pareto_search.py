"""The multi-objective search sweeper (hydra_plugins/mpclab_sweeper/pareto_search.py): optuna
trials, each a point on several seeds; its front written as a grid's; resumed from its study
without running a finished trial again, and a trial cut short run again in its own folders.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT

pytestmark = pytest.mark.slow


def search(sweep_dir: Path, n_trials: int) -> str:
    cmd = [sys.executable, "-m", "mpclab", "-m", "+experiment=car_cvxpy", "+ci=smoke",
           "scenario.t_max=4.0", "hydra/sweeper=pareto_search",
           "+hydra.sweeper.search_space={controller.horizon: 'range(6,12,2)', "
           "controller.control_horizon: \"choice('null',3)\"}",
           f"hydra.sweeper.n_trials={n_trials}", "hydra.sweeper.seeds=[0,1]",
           "hydra.sweeper.population_size=2",
           "+hydra.callbacks.sweep.pareto.objectives=[arrival_s,step_cpu_p95_ms]",
           "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={sweep_dir}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    return out


@pytest.mark.needs("search")
def test_search_writes_its_front_and_resumes_without_repeating_trials(tmp_path: Path) -> None:
    import optuna  # the `search` extra (the marker skips this test without it)

    search(tmp_path, 3)
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    study = optuna.load_study(study_name="pareto", storage=storage)
    first = study.get_trials(deepcopy=False)
    assert [t.state for t in first] == [optuna.trial.TrialState.COMPLETE] * 3
    points = pd.read_csv(tmp_path / "pareto_points.csv")
    assert points["runs"].isin([2, 4, 6]).all()  # a point asked again reuses its 2 runs
    assert (tmp_path / "pareto.csv").is_file() and (tmp_path / "pareto.png").is_file()
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/summary.json")}
    # an interrupt cut a trial short: asked, its jobs numbered from 100, never told
    cut = study.ask({"controller.horizon": optuna.distributions.IntDistribution(6, 10, step=2),
                     "controller.control_horizon": optuna.distributions.CategoricalDistribution(
                         ["null", 3])})
    cut.set_user_attr("first_job", 100)
    out = search(tmp_path, 4)
    trials = optuna.load_study(study_name="pareto", storage=storage).get_trials(deepcopy=False)
    rerun = [t for t in trials if t.user_attrs.get("rerun_of") == cut.number]
    assert len(rerun) == 1 and rerun[0].params == cut.params
    assert rerun[0].state == optuna.trial.TrialState.COMPLETE
    assert rerun[0].user_attrs["first_job"] == 100 and (tmp_path / "101" / "summary.json").is_file()
    assert len(trials) == 5  # 3 finished before, the cut one, its rerun: nothing else ran
    assert "3 of 4 trials finished" in out
    for path, mtime in stamps.items():  # the finished trials' runs were not run again
        assert path.stat().st_mtime_ns == mtime, path
