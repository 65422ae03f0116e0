"""SIGTERM stops a run or a sweep as Ctrl-C does: nothing done so far is lost.

Each case starts ``python -m mpclab`` in a subprocess, waits until it is under way, sends it
SIGTERM (what ``timeout``, SLURM, a container stop send) and reads what it left.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT

pytestmark = pytest.mark.slow
LONG_RUN = ["+experiment=zumo_right_hand", "scenario=zumo_dead_end", "recorder=none",
            "figures.enabled=false"]


#: how a shell script starts a background job (``cmd &``): with SIGINT ignored, which the
#: command inherits
AS_BACKGROUND_JOB = ["sh", "-c", 'trap "" INT; exec "$@"', "sh"]


def _start(args: list[str], out: Path, prefix: list[str] | None = None) -> subprocess.Popen:
    return subprocess.Popen([*(prefix or []), sys.executable, "-m", "mpclab", *args], cwd=ROOT,
                            text=True, stdout=out.open("w"), stderr=subprocess.STDOUT)


def _wait_for(check, proc: subprocess.Popen, limit_s: float = 240.0) -> None:
    t0 = time.time()
    while not check():
        assert proc.poll() is None, "ended before it could be stopped"
        assert time.time() - t0 < limit_s, "never got under way"
        time.sleep(0.2)


def test_sigterm_ends_a_single_run_with_its_record(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = _start([*LONG_RUN, "scenario.t_max=50000", "progress=true",
                   f"hydra.run.dir={run_dir}"], tmp_path / "console.txt")
    log = run_dir / "__main__.log"
    # said once the loop has run 2 s and its estimate is above a minute: the loop is going
    _wait_for(lambda: log.exists() and "a long run" in log.read_text(), proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 130, (tmp_path / "console.txt").read_text()[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["n_steps"] > 0
    assert "SIGTERM" in summary["error"]
    steps = pd.read_parquet(run_dir / "steps.parquet")
    assert len(steps) >= summary["n_steps"]
    assert "interrupted by SIGTERM" in (tmp_path / "console.txt").read_text()


def test_sigterm_ends_a_sweep_that_resumes(tmp_path: Path) -> None:
    """The launcher passes the stop on to its workers as SIGINT; started as a background job
    of a script (SIGINT ignored, and inherited so by the workers), each worker still takes it
    as an interrupt of its job."""
    sweep_dir = tmp_path / "sweep"
    args = ["-m", *LONG_RUN, "scenario.t_max=40", "seed=range(0,24)",
            "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={sweep_dir}"]
    proc = _start(args, tmp_path / "console.txt", prefix=AS_BACKGROUND_JOB)
    progress = sweep_dir / ".mpclab" / "progress.jsonl"
    _wait_for(lambda: progress.exists() and len(progress.read_text().splitlines()) >= 6, proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 130
    rows = pd.read_parquet(sweep_dir / "summary.parquet")
    finished = rows[~rows["status"].isin(["interrupted", "incomplete"])]
    assert len(finished) >= 6 and len(finished) < 24
    assert (rows["status"] == "interrupted").any()  # the jobs running then, each recorded
    console = (tmp_path / "console.txt").read_text()
    assert "interrupted by SIGTERM" in console and "resumes it" in console
    # the same command goes on: the finished jobs are skipped, the others run
    again = subprocess.run([sys.executable, "-m", "mpclab", *args], cwd=ROOT, text=True,
                           capture_output=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    rows = pd.read_parquet(sweep_dir / "summary.parquet")
    assert len(rows) == 24 and not rows["status"].isin(["interrupted", "error"]).any()
    assert f"{len(finished)} resumed" in again.stdout + again.stderr
