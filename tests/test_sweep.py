"""Multirun sweeps end to end through ``python -m mpclab -m``: tables, figure, faults, resume.

Each sweep is a real Hydra multirun in a subprocess (mpclab's pool launcher with its
workers), shortened by ``+ci=smoke``. ``test_sweep_jobs.py`` checks resume rules in-process.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
import yaml
from hydra.errors import HydraException

from conftest import ROOT, compose_cfg, wait_for
from mpclab.core.signals import SAME_STOP_S
from mpclab.record.figure_file import read_figure

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


FAULTY = '''"""A scenario whose building does a fault in some jobs: kills its own process (a
stand-in for a crash in native code, or the kernel's OOM killer), hangs, or waits for another
job (files in MARKS tell where the jobs are)."""
import inspect
import os
import pydoc
import signal
import time
from pathlib import Path

from hydra.core.hydra_config import HydraConfig

from mpclab.config.registry import register_target

MARKS = Path({marks!r})


@register_target  # a config may build it (the config lists this module under plugins)
def scenario(plant, rng, **options):
    task = HydraConfig.get().overrides.task
{fault}
    real = pydoc.locate({real!r})
    deps = {{"plant": plant, "rng": rng}}
    takes = inspect.signature(real).parameters
    return real(**options, **{{k: v for k, v in deps.items() if k in takes}})
'''


def faulty_command(tmp_path: Path, fault: str, *overrides: str) -> tuple[list[str], dict]:
    """The command and environment of a 4-job car sweep on the pool whose scenario runs
    ``fault`` (code that reads ``task``, the job's overrides) as it is built."""
    base = ["+experiment=car_cvxpy", "+ci=smoke"]
    real = compose_cfg(base).scenario._target_
    (tmp_path / "faulty.py").write_text(FAULTY.format(
        real=real, marks=str(tmp_path), fault=textwrap.indent(textwrap.dedent(fault), "    ")))
    cmd = [sys.executable, "-m", "mpclab", "-m", *base, "scenario._target_=faulty.scenario",
           "plugins=[faulty]", "seed=0,1,2,3", *overrides,
           f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    return cmd, {**os.environ, "PYTHONPATH": str(tmp_path)}


def faulty_sweep(tmp_path: Path, fault: str, *overrides: str) -> tuple[pd.DataFrame, str]:
    """The sweep of :func:`faulty_command`, run to its end; its table (by seed) and console
    output."""
    cmd, env = faulty_command(tmp_path, fault, *overrides)
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    df = pd.read_parquet(tmp_path / "sweep" / "summary.parquet").set_index("seed")
    assert len(df) == 4 and "4/4 jobs done, 1 failed" in out, out[-4000:]
    return df, out


def test_a_worker_that_dies_costs_only_its_own_job(tmp_path: Path) -> None:
    df, out = faulty_sweep(tmp_path, """
        if "seed=1" in task:
            os.kill(os.getpid(), signal.SIGKILL)
        """, "hydra.launcher.n_jobs=2")
    # the job that killed its worker (twice: once among the others, once alone) is a row
    assert df.loc[1, "status"] == "error"
    assert "worker process" in df.loc[1, "error"] and "SIGKILL" in df.loc[1, "error"]
    # the jobs that ran beside it, or after it, ran to the end, in the same backend's group
    assert (df.drop(index=1)["status"] != "error").all(), df["error"]
    assert df["backend"].nunique() == 1
    assert "Traceback" not in out


def test_a_worker_stopped_by_the_pool_records_its_job_and_ends(tmp_path: Path) -> None:
    """When a worker dies, the pool stops the others with SIGTERM and waits for them: one
    running a job takes it as a stop (its job records what it has), then ends, and the sweep
    goes on (no worker left waiting for a job that never comes)."""
    df, out = faulty_sweep(tmp_path, """
        if "seed=0" in task and not (MARKS / "started").exists():  # beside seed 1, not again
            try:
                (MARKS / "started").touch()  # now seed 1's worker dies
                while True:  # at work: a signal that another thread took is seen here too
                    time.sleep(0.05)
            except KeyboardInterrupt as stop:
                (MARKS / "stopped").write_text(repr(stop))
                raise
        if "seed=1" in task:
            while not (MARKS / "started").exists():
                time.sleep(0.05)
            os.kill(os.getpid(), signal.SIGKILL)
        """, "hydra.launcher.n_jobs=2")
    assert (tmp_path / "stopped").read_text() == "Terminated('SIGTERM')"
    assert "the 2 job(s) running then run again" in out
    assert df.loc[1, "status"] == "error" and "SIGKILL" in df.loc[1, "error"]
    assert (df.drop(index=1)["status"] != "error").all(), df["error"]
    assert not (df["status"] == "interrupted").any()  # seed 0 ran again, to its end


@pytest.mark.parametrize("to_group", [False, True], ids=["to_the_launcher", "to_its_group"])
def test_a_second_sigterm_ends_the_sweep_with_its_workers(tmp_path: Path, to_group: bool) -> None:
    """Jobs that run on past a stop (here each ignores its interrupt): a second SIGTERM ends
    the launcher at once, and its workers with it (none is left running on its own)."""
    cmd, env = faulty_command(tmp_path, """
        (MARKS / f"worker-{os.getpid()}").touch()
        while True:  # at work (not one long sleep): it sees a signal another thread took
            try:
                time.sleep(0.05)
            except KeyboardInterrupt:
                (MARKS / f"stopped-{os.getpid()}").touch()
        """, "hydra.launcher.n_jobs=2")
    with (tmp_path / "console.txt").open("w") as console:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=console,
                                stderr=subprocess.STDOUT, start_new_session=True)

    def stop() -> None:
        if to_group:
            os.killpg(proc.pid, signal.SIGTERM)
        else:
            proc.send_signal(signal.SIGTERM)

    try:
        wait_for(lambda: len(list(tmp_path.glob("worker-*"))) == 2, proc)
        workers = [int(p.name.split("-")[1]) for p in tmp_path.glob("worker-*")]
        stop()
        wait_for(lambda: len(list(tmp_path.glob("stopped-*"))) == 2, proc)  # each goes on
        for _ in range(60):  # within SAME_STOP_S of the first, a signal is that one again
            stop()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=SAME_STOP_S)
                break
        assert proc.wait(timeout=0) == -signal.SIGTERM
        for pid in workers:
            with pytest.raises(ProcessLookupError):
                os.kill(pid, 0)
    finally:  # whatever failed, nothing of it is left running
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_job_that_hangs_is_stopped_at_its_time_limit(tmp_path: Path, workers: int) -> None:
    # the limit leaves the other jobs 5 times what a worker's first car job takes here (2 s)
    df, out = faulty_sweep(tmp_path, """
        if "seed=1" in task:
            time.sleep(600)
        """, "hydra.launcher.job_timeout_s=10", f"hydra.launcher.n_jobs={workers}")
    assert df.loc[1, "status"] == "error"
    assert "did not end within hydra.launcher.job_timeout_s=10 s" in df.loc[1, "error"]
    assert (df.drop(index=1)["status"] != "error").all(), df["error"]
    assert "Traceback" not in out
