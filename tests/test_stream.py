"""Append-only JSON lines: whole records only, a tail that reads each line once, and the
sweep progress that follows it."""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.core.utils import JobReturn, JobStatus
from hydra.types import RunMode
from omegaconf import OmegaConf

from mpclab.core import jsonl as stream
from mpclab.sweeps.callbacks import SweepCallback


def test_a_tail_reads_each_whole_line_once(tmp_path: Path) -> None:
    path = tmp_path / "progress.jsonl"
    tail = stream.Tail(path)
    assert tail.new() == ([], True)  # no file yet
    stream.append(path, {"job": 0})
    stream.append(path, {"job": 1})
    assert tail.new() == ([{"job": 0}, {"job": 1}], True)
    assert tail.new() == ([], False)
    with open(path, "a") as f:  # a line still being written waits for the next call
        f.write('{"job": 2')
    assert tail.new() == ([], False)
    with open(path, "a") as f:
        f.write("}\n")
    stream.append(path, {"job": 3})
    assert tail.new() == ([{"job": 2}, {"job": 3}], False)
    assert [r["job"] for r in stream.read(path)] == [0, 1, 2, 3]


def test_a_tail_follows_a_file_started_anew(tmp_path: Path) -> None:
    path = tmp_path / "progress.jsonl"
    stream.append(path, {"job": 0})
    stream.append(path, {"job": 1})
    tail = stream.Tail(path)
    tail.new()
    path.write_text("")  # a new sweep into the same folder
    stream.append(path, {"job": 7})
    assert tail.new() == ([{"job": 7}], True)


def test_the_progress_line_counts_jobs_of_every_worker(tmp_path: Path, caplog) -> None:
    """Each process follows the shared progress file: its line counts every worker's jobs."""
    cfg = OmegaConf.create({"hydra": {"mode": RunMode.MULTIRUN, "sweep": {"dir": str(tmp_path)},
                                      "runtime": {"output_dir": None}, "job": {"num": 0},
                                      "overrides": {"task": []},
                                      "sweeper": {"_target_": "nowhere.Sweeper"}}})
    here, other = SweepCallback(), SweepCallback()  # two workers
    here.on_multirun_start(cfg)
    outcomes = [JobStatus.FAILED, JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.COMPLETED]
    caplog.set_level(logging.INFO, logger="mpclab.sweep")
    for i, status in enumerate(outcomes):
        ret = JobReturn(status=status, _return_value={"status": "arrived"})
        (here if i % 2 == 0 else other).on_job_end(cfg, ret)
    lines = [r.getMessage() for r in caplog.records if "jobs done" in r.getMessage()]
    assert [line.split(" | ")[0].removeprefix("sweep: ") for line in lines] == [
        "1 jobs done, 1 failed", "2 jobs done, 1 failed", "3 jobs done, 2 failed",
        "4 jobs done, 2 failed"]
