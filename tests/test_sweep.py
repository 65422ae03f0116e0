"""Multirun sweeps end to end through ``python -m mpclab -m``: tables, figure, faults, resume.

Each sweep is a real Hydra multirun in a subprocess (mpclab's pool launcher with its
workers), shortened by ``+ci=smoke``. ``test_sweep_jobs.py`` checks resume rules in-process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml
from hydra.errors import HydraException

from conftest import ROOT, compose_cfg
from mpclab.figure_file import read_figure

pytestmark = pytest.mark.slow


def sweep(*overrides: str, timeout: float = 300) -> str:
    """Run ``python -m mpclab -m OVERRIDES``; return its console output (fails on exit != 0)."""
    cmd = [sys.executable, "-m", "mpclab", "-m", *overrides]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    return out


def backend_axis() -> str:
    """Two backends on the car: CVXPY and CasADi if CasADi can run car_cvxpy, else two QP
    solvers of the CVXPY backend."""
    try:
        compose_cfg(["+experiment=car_cvxpy", "controller=casadi"])
    except HydraException:
        return "controller.solver=CLARABEL,OSQP"
    return "controller=cvxpy,casadi"


def test_a_horizon_sweeps_figure_tells_the_horizons_apart(tmp_path: Path) -> None:
    sweep("+experiment=car_cvxpy", "+ci=smoke", "controller.horizon=8,10",
          "figures.enabled=true", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path}")
    fig = read_figure(tmp_path / "arrival_vs_compute.png")
    assert fig.ink > 0.02 and all(p.artists > 0 for p in fig.panels)
    assert fig.panels[0].legend == ("controller.horizon=8", "controller.horizon=10")


def test_two_backends_three_seeds(tmp_path: Path) -> None:
    axis = backend_axis()
    out = sweep("+experiment=car_cvxpy", "+ci=smoke", "scenario.t_max=4.0", axis, "seed=0,1,2",
                "figures.enabled=true", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path}")
    df = pd.read_parquet(tmp_path / "summary.parquet")
    assert len(df) == 6
    assert df["backend"].nunique() == 2 and df.groupby("backend")["seed"].nunique().eq(3).all()
    assert (df["status"] != "error").all(), df[["backend", "error"]]
    fig = read_figure(tmp_path / "arrival_vs_compute.png")
    assert set(fig.panels[0].legend) == set(df["backend"])  # one entry per backend
    assert len(pd.read_csv(tmp_path / "summary.csv")) == 6
    assert "6/6 jobs done, 0 failed" in out
    # every row was streamed as its job ended; each job names the workers that ran at once
    rows = (tmp_path / ".mpclab" / "rows.jsonl").read_text().splitlines()
    assert len(rows) == 6
    assert (df["load.workers"] == 2).all() and (df["compute_cpu_total_s"] > 0).all()
    # the launcher's record of each job in its worker: times within the job's, page faults
    tasks = pd.read_json(tmp_path / ".mpclab" / "tasks.jsonl", lines=True)
    assert sorted(tasks["job"]) == list(range(6)) and tasks["pid"].nunique() <= 2
    assert (tasks["simulate_s"] > 0).all() and (tasks["task_s"] > tasks["simulate_s"]).all()
    assert (tasks["cpu_s"] > 0).all() and (tasks["minor_faults"] >= 0).all()
    # each row is its job's summary.json, and its parameters are the job's overrides
    for row in df.itertuples():
        job = tmp_path / row.job
        summary = json.loads((job / "summary.json").read_text())
        assert (row.status, row.seed, row.n_steps) == (
            summary["status"], summary["seed"], summary["n_steps"])
        assert f"seed={row.seed}" in yaml.safe_load((job / ".hydra/overrides.yaml").read_text())
    # from rest at (-10, 10), with |a| <= 10 m/s^2, 1 m from the origin is >= 13.14 m away:
    # no arrival before sqrt(2 * 13.14 / 10) = 1.62 s
    arrived = df[df["status"] == "arrived"]
    assert len(arrived) >= 3 and (arrived["arrival_time_s"] >= 1.62).all()


def test_failed_jobs_are_rows_and_the_same_sweep_resumes(tmp_path: Path) -> None:
    # job 1: the controller refuses horizon -1 when built; job 2: the schema rejects "ten"
    args = ("+experiment=car_cvxpy", "+ci=smoke", "controller.horizon=10,-1,ten",
            f"hydra.sweep.dir={tmp_path}")
    out = sweep(*args)
    df = pd.read_parquet(tmp_path / "summary.parquet").set_index("job")
    assert len(df) == 3 and "3/3 jobs done, 2 failed" in out
    assert df.loc["0", "status"] == "timeout" and df.loc["0", "n_steps"] == 10
    assert df.loc["1", "status"] == "error"
    assert df.loc["1", "error"] == ("controller.horizon must be >= 1, got -1 (set in "
                                    "conf/experiment/car_cvxpy.yaml, then the command line "
                                    "(controller.horizon=-1))")  # where the value came from
    assert df.loc["2", "status"] == "error" and "'ten'" in df.loc["2", "error"]
    assert df.loc["2", "controller"] == "cvxpy"  # named even though it never composed
    assert not (tmp_path / "arrival_vs_compute.png").exists()  # +ci=smoke: no figures at all
    steps = tmp_path / "0" / "steps.parquet"
    before = steps.stat().st_mtime_ns
    # the same sweep again (here launched without workers): the complete job is skipped,
    # the failed ones run again
    out = sweep(*args, "hydra/launcher=basic")
    assert "3/3 jobs done, 2 failed, 1 resumed" in out
    assert steps.stat().st_mtime_ns == before
    assert len(pd.read_parquet(tmp_path / "summary.parquet")) == 3


def test_started_workers_run_the_sweep(tmp_path: Path) -> None:
    # spawned workers inherit nothing: they are sent the task, the config and Hydra's
    # singletons (forked ones and the launching process use their own)
    out = sweep("+experiment=car_cvxpy", "+ci=smoke", "seed=0,1", "hydra.launcher.n_jobs=2",
                "hydra.launcher.start_method=spawn", f"hydra.sweep.dir={tmp_path}")
    df = pd.read_parquet(tmp_path / "summary.parquet")
    assert len(df) == 2 and (df["status"] != "error").all(), df.get("error")
    assert "2/2 jobs done, 0 failed" in out and "(spawn)" in out


FAULTY = '''"""A scenario that, in the job with seed=1, kills its own process (a stand-in for a
crash in native code, or the kernel's OOM killer) or hangs."""
import inspect
import os
import pydoc
import signal
import time

from hydra.core.hydra_config import HydraConfig

from mpclab.registry import register_target


@register_target  # a config may build it (the config lists this module under plugins)
def scenario(plant, rng, **options):
    if "seed=1" in HydraConfig.get().overrides.task:
        {fault}
    real = pydoc.locate({real!r})
    deps = {{"plant": plant, "rng": rng}}
    takes = inspect.signature(real).parameters
    return real(**options, **{{k: v for k, v in deps.items() if k in takes}})
'''


def faulty_sweep(tmp_path: Path, fault: str, *overrides: str) -> tuple[pd.DataFrame, str]:
    """A 4-job car sweep on the pool whose job with seed=1 does ``fault``; its table (by
    seed) and console output."""
    base = ["+experiment=car_cvxpy", "+ci=smoke"]
    real = compose_cfg(base).scenario._target_
    (tmp_path / "faulty.py").write_text(FAULTY.format(real=real, fault=fault))
    out_dir = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "mpclab", "-m", *base, "scenario._target_=faulty.scenario",
           "plugins=[faulty]", "seed=0,1,2,3", *overrides, f"hydra.sweep.dir={out_dir}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(tmp_path)})
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    df = pd.read_parquet(out_dir / "summary.parquet").set_index("seed")
    assert len(df) == 4 and "4/4 jobs done, 1 failed" in out, out[-4000:]
    return df, out


def test_a_worker_that_dies_costs_only_its_own_job(tmp_path: Path) -> None:
    df, out = faulty_sweep(tmp_path, "os.kill(os.getpid(), signal.SIGKILL)",
                           "hydra.launcher.n_jobs=2")
    # the job that killed its worker (twice: once among the others, once alone) is a row
    assert df.loc[1, "status"] == "error"
    assert "worker process" in df.loc[1, "error"] and "SIGKILL" in df.loc[1, "error"]
    # the jobs that ran beside it, or after it, ran to the end, in the same backend's group
    assert (df.drop(index=1)["status"] != "error").all(), df["error"]
    assert df["backend"].nunique() == 1
    assert "Traceback" not in out


@pytest.mark.parametrize("workers", [1, 2])
def test_a_job_that_hangs_is_stopped_at_its_time_limit(tmp_path: Path, workers: int) -> None:
    # the limit leaves the other jobs 5 times what a worker's first car job takes here (2 s)
    df, out = faulty_sweep(tmp_path, "time.sleep(600)", "hydra.launcher.job_timeout_s=10",
                           f"hydra.launcher.n_jobs={workers}")
    assert df.loc[1, "status"] == "error"
    assert "did not end within hydra.launcher.job_timeout_s=10 s" in df.loc[1, "error"]
    assert (df.drop(index=1)["status"] != "error").all(), df["error"]
    assert "Traceback" not in out
