"""The Hydra callback of every multirun: progress while it runs, tables when it ends.

Registered in ``conf/config.yaml`` under ``hydra.callbacks.sweep``. Hydra calls
``on_multirun_start`` and ``on_multirun_end`` in the process that launches the sweep and
``on_job_end`` where each job runs (a pool, joblib or Ray worker), so progress goes through
small files in ``<sweep dir>/.mpclab/``: ``sweep.json`` (job count, start time),
``progress.jsonl`` (one line per finished job, appended atomically) and ``rows.jsonl`` (each
finished job's table row, :func:`mpclab.tables.stream_row`): the sweep's table grows as jobs
end, and the tables at the end are made from it.
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.utils import JobReturn, JobStatus
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from mpclab import tables
from mpclab.config.registry import register_target
from mpclab.core import jsonl as stream
from mpclab.sweeps.expand import job_overrides

log = logging.getLogger("mpclab.sweep")

STATE_DIR = ".mpclab"
SWEEP_FILE = "sweep.json"
PROGRESS_FILE = "progress.jsonl"
#: files of one sweep's run, emptied when it starts (rows.jsonl: mpclab.tables.ROWS_FILE)
STREAMS = (PROGRESS_FILE, "rows.jsonl", "tasks.jsonl")
BAR_WIDTH = 20
#: the folder of the sweep this process is launching, from its start to its end
_LAUNCHING: list[Path] = []
#: why the sweep this process launched last has no result (every job failed, or no job
#: wrote a run record), said by the command as it exits non-zero
_NO_RESULT: list[str] = []


def count_jobs(config: DictConfig) -> int | None:
    """How many jobs mpclab's (or Hydra's basic) sweeper makes of this multirun's overrides
    (None for another sweeper, or a sweep Hydra will report on)."""
    sweeper = config.hydra.sweeper
    if not str(sweeper.get("_target_", "")).endswith(("TolerantSweeper", ".BasicSweeper")):
        return None
    params = [f"{k}={v}" for k, v in (sweeper.get("params") or {}).items()]
    params += list(OmegaConf.to_container(config.hydra.overrides.task))
    try:
        batches = job_overrides(OverridesParser.create().parse_overrides(params))
    except Exception:  # noqa: BLE001  (progress just has no total)
        return None
    return sum(len(b) for b in batches)


def interrupted_sweep() -> str | None:
    """Write the tables of the jobs done so far of the sweep this process was launching, and
    say what to tell a user who interrupted it (how many jobs are recorded, where the tables
    are, how to resume); None outside a sweep."""
    from mpclab.sweeps.report import write_report  # matplotlib: only when a sweep ends

    if not _LAUNCHING:
        return None
    sweep_dir = _LAUNCHING[-1]
    state = sweep_dir / STATE_DIR
    try:
        total = json.loads((state / SWEEP_FILE).read_text()).get("total")
    except (OSError, ValueError):
        total = None
    done = len(stream.read(state / PROGRESS_FILE))
    of = f" of {total}" if total else ""
    try:
        write_report([sweep_dir], sweep_dir, figure=False)
        tables = f"their tables (and the interrupted jobs' rows) are in {sweep_dir}"
    except Exception as exc:  # noqa: BLE001  (the rows stay; the tool makes them later)
        log.warning("sweep: no tables written (%s)", exc)
        tables = f"`python -m mpclab.cli.tables {sweep_dir}` makes the tables so far"
    return (f"{done}{of} jobs of the sweep in {sweep_dir} are done and recorded; {tables}; "
            "the same command resumes it (skipping them)")


def forget_sweep() -> None:
    """This process launches no sweep now (its end, or its command's)."""
    _LAUNCHING.clear()


def failed_sweep() -> str | None:
    """Why the sweep this process launched last has no result (every job failed: the first
    error; or no run record was found), and forget it; None if it has results."""
    message = _NO_RESULT[0] if _NO_RESULT else None
    _NO_RESULT.clear()
    return message


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def progress_line(
    done: int, total: int | None, failed: int, resumed: int, elapsed: float,
) -> str:
    """``'[######..............] 5/16 jobs done, 1 failed, 2 resumed | elapsed 0:00:12 |
    about 0:00:25 left'`` (the bar only when the total is known)."""
    head = f"{done}/{total}" if total else f"{done}"
    if total:
        filled = min(BAR_WIDTH, BAR_WIDTH * done // total)
        head = f"[{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {head}"
    parts = [f"{head} jobs done", f"{failed} failed"]
    if resumed:
        parts.append(f"{resumed} resumed")
    line = ", ".join(parts) + f" | elapsed {_clock(elapsed)}"
    ran = done - resumed
    if total and ran > 0 and done < total:
        line += f" | about {_clock(elapsed / ran * (total - done))} left"
    return line


def job_outcome(job_return: JobReturn) -> tuple[str, bool]:
    """``(status, resumed)`` of a finished job, from what its task function returned."""
    if job_return.status != JobStatus.COMPLETED:
        return "error", False
    value = job_return.return_value
    if not isinstance(value, dict):
        return "unknown", False
    return str(value.get("status")), bool(value.get("skipped"))


@register_target  # hydra.callbacks.sweep in conf/config.yaml
class SweepCallback(Callback):
    """Progress lines during a multirun; ``mpclab.tables`` over the sweep folder at its end.

    Hydra passes its own keyword arguments (``config_name``, ...) to every hook; they are
    accepted and not used.

    Parameters
    ----------
    figure
        Draw ``arrival_vs_compute.png`` in the sweep folder (unless the sweep's config says
        ``figures.enabled=false``).
    x
        Its x axis: ``step_ms`` or ``rtf`` (see :class:`mpclab.tables.XAxis`).
    pareto
        ``{objectives: [...]}``: also write the sweep's Pareto front (``pareto.csv``,
        ``pareto.png`` even under ``figures.enabled=false``: :mod:`mpclab.sweeps.pareto`);
        with ``rerun: true``, also ``pareto_front.rrd``, its runs side by side (runs the sweep
        did not record are run again: :mod:`mpclab.sweeps.front_replay`); None: no front.
    """

    def __init__(self, figure: bool = True, x: str = "step_ms",
                 pareto: dict[str, Any] | None = None) -> None:
        self.figure = figure
        self.x = tables.XAxis(x)
        self.pareto = pareto
        #: per sweep folder, in this process: the progress file followed, and its tally
        self._progress: dict[Path, tuple[stream.Tail, Counter[str]]] = {}

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        state = Path(config.hydra.sweep.dir) / STATE_DIR
        state.mkdir(parents=True, exist_ok=True)
        total = count_jobs(config)
        (state / SWEEP_FILE).write_text(json.dumps({"total": total, "start": time.time()}))
        for name in STREAMS:
            (state / name).write_text("")
        self._progress.pop(state, None)
        _LAUNCHING[:] = [Path(config.hydra.sweep.dir)]
        _NO_RESULT.clear()
        log.info("sweep of %s jobs into %s", "?" if total is None else total,
                 config.hydra.sweep.dir)

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        if config.hydra.mode != RunMode.MULTIRUN:
            return
        state = Path(config.hydra.sweep.dir) / STATE_DIR
        try:
            meta = json.loads((state / SWEEP_FILE).read_text())
        except (OSError, ValueError):
            return  # not started by this callback (e.g. a job run by hand)
        status, resumed = job_outcome(job_return)
        run_dir = OmegaConf.select(config, "hydra.runtime.output_dir")
        if run_dir:
            tables.stream_row(config.hydra.sweep.dir, Path(run_dir))
        stream.append(state / PROGRESS_FILE,
                      {"job": config.hydra.job.num, "status": status, "resumed": resumed})
        tail, tally = self._progress.setdefault(
            state, (stream.Tail(state / PROGRESS_FILE), Counter()))
        records, from_start = tail.new()
        if from_start:
            tally.clear()
        for rec in records:
            tally["done"] += 1
            tally["failed"] += int(rec["status"] == "error")
            tally["resumed"] += int(bool(rec["resumed"]))
        log.info("sweep: %s", progress_line(
            tally["done"], meta["total"], tally["failed"], tally["resumed"],
            time.time() - meta["start"],
        ))

    @staticmethod
    def _replay_front(sweep_dir: Path, points: Any) -> None:
        """``pareto_front.rrd``; a run that cannot be recorded again is said, not raised."""
        from mpclab.sweeps.front_replay import replay_front, replay_lines  # rerun, as above

        try:
            log.info("sweep: %s", replay_lines(*replay_front([sweep_dir], sweep_dir, points)))
        except (OSError, ValueError) as exc:
            log.warning("sweep: the front's runs were not merged (%s)", exc)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from mpclab.sweeps.report import write_report  # matplotlib: only when a sweep ends

        sweep_dir = Path(config.hydra.sweep.dir)
        forget_sweep()
        state = sweep_dir / STATE_DIR
        jobs_end = time.time()
        try:
            meta = json.loads((state / SWEEP_FILE).read_text())
            elapsed = jobs_end - meta["start"]
        except (OSError, ValueError):
            meta, elapsed = None, float("nan")
        t0 = time.perf_counter()
        # figures.enabled=false turns off the sweep's figure too, not only the runs'
        figure = self.figure and OmegaConf.select(config, "figures.enabled", default=True)
        report = write_report([sweep_dir], sweep_dir, figure=bool(figure), x=self.x)
        if self.pareto is not None and not report.runs.empty:
            from mpclab.sweeps.pareto import write_pareto  # matplotlib, as the report

            # the front's figure is what a sweep asking for a front is for: always drawn
            points, files = write_pareto([sweep_dir], sweep_dir, self.pareto.get("objectives"))
            report.files.update({f"pareto:{k}": v for k, v in files.items()})
            if self.pareto.get("rerun") and not points.empty:
                self._replay_front(sweep_dir, points)
        if meta is not None:  # when the jobs ended and how long the tables took (benchmarks)
            meta.update(jobs_end=jobs_end, report_s=time.perf_counter() - t0)
            (state / SWEEP_FILE).write_text(json.dumps(meta))
        df = report.runs
        if df.empty:  # the command fails with this line (mpclab.cli.app)
            _NO_RESULT[:] = [f"the sweep wrote no run record: none found below {sweep_dir}"]
            return
        counts = df["status"].value_counts().to_dict()
        if set(counts) == {"error"}:
            first = df.sort_values("job")["error"].iloc[0] if "job" in df else df["error"].iloc[0]
            _NO_RESULT[:] = [f"every job of the sweep in {sweep_dir} failed; the first: {first}"]
        log.info("sweep finished: %d runs in %s, %s", len(df), _clock(elapsed),
                 ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))
        log.info("sweep by %s:\n%s", ", ".join(tables.group_keys(df)),
                 tables.markdown_table(report.groups))
        log.info("sweep files (written in %.2f s): %s", time.perf_counter() - t0,
                 ", ".join(str(p) for p in report.files.values()))
