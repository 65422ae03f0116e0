"""SIGTERM stops a run or a sweep as Ctrl-C does: nothing done so far is lost.

Each case starts ``python -m mpclab`` in a subprocess, waits until it is under way, sends it
SIGTERM (what ``timeout``, SLURM, a container stop send) and reads what it left.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT, wait_for

pytestmark = pytest.mark.slow
LONG_RUN = ["+experiment=zumo_right_hand", "scenario=zumo_dead_end", "recorder=none",
            "figures.enabled=false"]


#: how a shell script starts a background job (``cmd &``): with SIGINT ignored, which the
#: command inherits
AS_BACKGROUND_JOB = ["sh", "-c", 'trap "" INT; exec "$@"', "sh"]


def _start(args: list[str], out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "mpclab", *args], cwd=ROOT, text=True,
                            stdout=out.open("w"), stderr=subprocess.STDOUT)


def test_sigterm_ends_a_single_run_with_its_record(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = _start([*LONG_RUN, "scenario.t_max=50000", "progress=true",
                   f"hydra.run.dir={run_dir}"], tmp_path / "console.txt")
    log = run_dir / "mpclab.log"  # hydra.job.name (conf/config.yaml)
    # said once the loop has run 2 s and its estimate is above a minute: the loop is going
    wait_for(lambda: log.exists() and "a long run" in log.read_text(), proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 130, (tmp_path / "console.txt").read_text()[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["n_steps"] > 0
    assert "SIGTERM" in summary["error"]
    steps = pd.read_parquet(run_dir / "steps.parquet")
    assert len(steps) >= summary["n_steps"]
    assert "interrupted by SIGTERM" in (tmp_path / "console.txt").read_text()


#: a recorder whose step sends this process SIGTERM where the interrupt it raises is lost, as
#: in a ``__del__`` that the garbage collector runs or a native callback that drops errors
SWALLOWER = """
import os
import signal
import time

from mpclab.recorders.base import Recorder
from mpclab.config.registry import register_target


@register_target
class Swallower(Recorder):
    def __init__(self, out_dir):
        pass

    def log_step(self, k, t, x, step, ctx):
        if k == 5:
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(1.0)
            except BaseException:
                pass
"""


def test_a_stop_lost_where_it_was_raised_still_ends_the_run(tmp_path: Path) -> None:
    """The stop signal was received: the loop ends the run ``interrupted`` at its next step,
    whatever became of the interrupt the signal raised."""
    (tmp_path / "swallower.py").write_text(SWALLOWER)
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mpclab", *LONG_RUN, "scenario.t_max=20", "plugins=[swallower]",
         "recorder._target_=swallower.Swallower", f"hydra.run.dir={run_dir}"],
        cwd=ROOT, text=True, env={**os.environ, "PYTHONPATH": str(tmp_path)},
        stdout=(tmp_path / "console.txt").open("w"), stderr=subprocess.STDOUT)
    assert proc.wait(timeout=120) == 130, (tmp_path / "console.txt").read_text()[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and "SIGTERM" in summary["error"]
    assert summary["n_steps"] == 6  # steps 0-5 recorded, the stop taken before step 6


#: a recorder (a plugin, as a user's own would be) by which job 6 of a sweep sends SIGTERM at
#: its fifth step, once (not again when the sweep resumes): the stop lands while that job is
#: in its loop, the other worker's job wherever it is
STOPPER = """
import os
import signal
from pathlib import Path

from mpclab.recorders.base import Recorder
from mpclab.config.registry import register_target


@register_target
class Stopper(Recorder):
    def __init__(self, out_dir):
        self.mark = Path(out_dir).parent / "stopped"
        self.here = Path(out_dir).name == "6" and not self.mark.exists()

    def log_step(self, k, t, x, step, ctx):
        if self.here and k == 5:
            self.mark.touch()
            {send}
"""
SENDS = {"to_the_launcher": "os.kill(os.getppid(), signal.SIGTERM)",
         "to_its_group": "os.killpg(os.getpgrp(), signal.SIGTERM)"}


@pytest.mark.parametrize("to", list(SENDS))
def test_sigterm_ends_a_sweep_that_resumes(tmp_path: Path, to: str) -> None:
    """Sent to the launcher alone, the stop is passed on to its workers as SIGINT; started as
    a background job of a script (SIGINT ignored, and inherited so by the workers), each
    worker still takes it as an interrupt of its job. Sent to the process group (SLURM's time
    limit, ``timeout``, a container stop), each worker gets it too and takes it the same way:
    its job ends ``interrupted`` with its record, then the worker ends."""
    (tmp_path / "stopper.py").write_text(STOPPER.format(send=SENDS[to]))
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    sweep_dir = tmp_path / "sweep"
    args = ["-m", *LONG_RUN, "scenario.t_max=40", "seed=range(0,12)", "plugins=[stopper]",
            "recorder._target_=stopper.Stopper", "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={sweep_dir}"]
    console = tmp_path / "console.txt"
    # in a process group of its own, with its workers, as a batch system starts a command
    proc = subprocess.Popen([*AS_BACKGROUND_JOB, sys.executable, "-m", "mpclab", *args],
                            cwd=ROOT, env=env, stdout=console.open("w"),
                            stderr=subprocess.STDOUT, start_new_session=True)
    try:
        assert proc.wait(timeout=300) == 130, console.read_text()[-3000:]
        with pytest.raises(ProcessLookupError):  # no worker outlives the launcher
            os.killpg(proc.pid, 0)
    finally:  # whatever failed, nothing of it is left running
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    rows = pd.read_parquet(sweep_dir / "summary.parquet").set_index("job")
    finished = rows[~rows["status"].isin(["interrupted", "incomplete"])]
    assert len(finished) >= 5 and len(finished) < 12  # job 6 started once 5 had ended
    progress = (sweep_dir / ".mpclab" / "progress.jsonl").read_text().splitlines()
    assert {str(json.loads(line)["job"]) for line in progress} <= set(finished.index)
    # the jobs running then, each recorded, saying what stopped it; job 6 in its loop, with
    # its steps so far
    stopped = rows[rows["status"] == "interrupted"]
    assert stopped["error"].str.contains("SIGTERM").all(), stopped["error"]
    assert rows.loc["6", "status"] == "interrupted" and rows.loc["6", "n_steps"] >= 5
    summary = json.loads((sweep_dir / "6" / "summary.json").read_text())
    assert summary["error"] == "KeyboardInterrupt (SIGTERM)"
    assert len(pd.read_parquet(sweep_dir / "6" / "steps.parquet")) >= summary["n_steps"]
    out = console.read_text()
    assert "interrupted by SIGTERM" in out and "resumes it" in out
    # the same command goes on: the finished jobs are skipped, the others run
    again = subprocess.run([sys.executable, "-m", "mpclab", *args], cwd=ROOT, env=env,
                           text=True, capture_output=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    rows = pd.read_parquet(sweep_dir / "summary.parquet")
    assert len(rows) == 12 and not rows["status"].isin(["interrupted", "error"]).any()
    assert f"{len(finished)} resumed" in again.stdout + again.stderr
