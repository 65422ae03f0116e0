"""One multirun job: resume a complete run record, or run it and record any error as a row.

A job's record is *complete* when its ``summary.json`` exists, its status is not ``error``
or ``interrupted`` and it was written for the same overrides (``summary["overrides"]``,
ignoring ``resume``).
Hydra numbers jobs by their position in the sweep, so the same sweep command with the same
sweep folder maps every job to the same folder again.
"""

from __future__ import annotations

import inspect
import logging
import os
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from mpclab.config.key_origin import RunOrigin
from mpclab.config.registry import TARGETS
from mpclab.core.errors import bad_input_message
from mpclab.core.signals import interrupted, stopped_by
from mpclab.record import files as record
from mpclab.runner.component_cache import WORKER_CACHE
from mpclab.tables import override_key

log = logging.getLogger("mpclab.sweep")

#: overrides that change how a sweep runs but not what a job computes
IGNORED_KEYS = ("resume", "progress")
#: set by the launcher in its workers (hydra_plugins/mpclab_launcher): jobs run at once
WORKERS_VAR = "MPCLAB_SWEEP_WORKERS"


def job_overrides(overrides: Sequence[str]) -> list[str]:
    """The overrides that define what a job computes, in their given order."""
    return [o for o in overrides if override_key(o) not in IGNORED_KEYS]


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, where the OS says): what a
    sweep's workers share, recorded with each job and checked by the launcher."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return cores or os.cpu_count() or 1


def complete_summary(out_dir: Path, overrides: Sequence[str]) -> dict[str, Any] | None:
    """The summary of a complete run record for ``overrides`` in ``out_dir``, else None."""
    path = Path(out_dir) / record.SUMMARY
    if not path.is_file():
        return None
    try:
        summary = record.read_summary(out_dir)
    except ValueError:  # a torn or hand-edited file: run again
        return None
    if summary.get("status") in ("error", "interrupted"):
        return None
    if job_overrides(summary.get("overrides") or []) != job_overrides(overrides):
        return None
    return summary


def error_message(exc: BaseException) -> str:
    """Bad input as the one message the command line prints; otherwise the root cause
    first, then the wrapper that says where (Hydra wraps both)."""
    message = bad_input_message(exc)
    if message is not None:
        return message
    root = exc
    while root.__cause__ is not None:
        root = root.__cause__

    def line(e: BaseException) -> str:
        return f"{type(e).__name__}: {str(e).strip().splitlines()[0] if str(e).strip() else ''}"

    return line(root) if root is exc else f"{line(root)} (in {line(exc)})"


def component_name(node: Any) -> str | None:
    """What a run's row calls the plant or controller that config ``node`` builds: its
    class's registered name (as a finished run writes it), None where ``node`` names no
    registered class."""
    if not isinstance(node, DictConfig) or "_target_" not in node.keys():
        return None
    try:
        obj = TARGETS.get(str(node["_target_"]))  # looked up, never imported by name
    except Exception:  # noqa: BLE001  (a bad interpolation)
        return None
    return getattr(obj, "registered_name", obj.__name__) if inspect.isclass(obj) else None


def error_summary(
    exc: BaseException, overrides: Sequence[str], cfg: DictConfig | None = None,
    choices: dict[str, Any] | None = None, base: DictConfig | None = None,
) -> dict[str, Any]:
    """The run-record summary of a job that raised ``exc`` before or while running.

    Plant and controller are named as a finished run names them (:func:`component_name`)
    from the job's config ``cfg``, else from ``base`` (the sweep's config, for a group the
    job's overrides do not choose), else by their Hydra group choice; so a failed job falls
    in its backend's group of the tables, not in one of its own.
    """
    given = dict(o.lstrip("+").split("=", 1) for o in overrides if "=" in o)
    named = {**(choices or {}), **given}
    name = cfg.get("name") if cfg is not None else None
    seed = cfg.get("seed") if cfg is not None else named.get("seed")

    def source(group: str) -> DictConfig | None:
        return cfg if cfg is not None else (base if group not in given else None)

    def component(group: str) -> Any:
        node = source(group)
        found = component_name(node.get(group)) if node is not None else None
        return found or named.get(group)

    controller = source("controller")
    solver = named.get("controller.solver") or (
        OmegaConf.select(controller, "controller.solver", default=None)
        if controller is not None else None)
    return {
        "experiment": name,
        "plant": component("plant"),
        "controller": component("controller"),
        **({"solver": str(solver)} if solver is not None else {}),  # its backend's label
        "scenario": named.get("scenario"),
        "seed": int(seed) if str(seed).lstrip("-").isdigit() else None,
        "status": "error",
        "arrived": False,
        "arrival_time_s": None,
        "n_steps": 0,
        "error": error_message(exc),
        "overrides": list(overrides),
        "versions": record.versions(),
    }


def run_job(
    cfg: DictConfig, out_dir: Path, overrides: Sequence[str], choices: dict[str, Any],
    workers: int | None = None,
) -> dict[str, Any]:
    """Run one multirun job into ``out_dir`` and return its summary; never raises ``Exception``.

    Parameters
    ----------
    cfg
        The job's composed config (``resume`` read from it).
    out_dir
        The job's Hydra output folder.
    overrides
        The job's task overrides (``hydra.overrides.task``), stored in the summary.
    choices
        Hydra's group choices (``hydra.runtime.choices``), naming components in error rows.
    workers
        How many jobs the launcher runs at once (None: unknown); recorded with the load
        average at the job's start and end (``summary["load"]``), so that compute columns
        from a loaded machine can be told apart (:func:`mpclab.tables.contended`).

    Plant, objective and controller are reused from an earlier job of this process with the
    same structure (:mod:`mpclab.runner.component_cache`).
    """
    from mpclab.runner.loop import RunInterrupted
    from mpclab.runner.single_run import run_experiment

    overrides = list(overrides)
    if cfg.get("resume", True):
        done = complete_summary(out_dir, overrides)
        if done is not None:
            log.info("resume: %s is complete (%s), skipped", out_dir, done.get("status"))
            return {**done, "skipped": True}
    env = os.environ.get(WORKERS_VAR)
    workers = int(env) if env else workers
    load_start = os.getloadavg()[0]
    try:
        summary = run_experiment(cfg, out_dir, cache=WORKER_CACHE,
                                 origin=RunOrigin(dict(choices), tuple(overrides))).summary
    except RunInterrupted:
        raise  # stopped in its loop: its partial record is written
    except KeyboardInterrupt as exc:  # stopped while building: the row says so, resume reruns it
        _write_interrupted(exc, out_dir, overrides, cfg, choices)
        raise
    except Exception as exc:  # the sweep goes on; the row says what happened
        stop = interrupted(exc)  # a stop that the code it hit turned into another error
        if stop is not None:
            _write_interrupted(stop, out_dir, overrides, cfg, choices)
            raise stop from exc
        log.error("job failed: %s\n%s", exc, traceback.format_exc())
        summary = error_summary(exc, overrides, cfg, choices)
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        record.write_summary(out_dir, summary)  # an error row has no steps to write
        return summary
    load = {"workers": workers, "cores": usable_cores(), "load_1m_start": load_start,
            "load_1m_end": os.getloadavg()[0]}
    summary = {**summary, "load": load, "overrides": overrides}
    record.write_summary(out_dir, summary)  # again, now naming its overrides (for resume)
    return summary


def _write_interrupted(
    stop: KeyboardInterrupt, out_dir: Path, overrides: Sequence[str], cfg: DictConfig,
    choices: dict[str, Any],
) -> None:
    """The row of a job stopped before its loop (the same command runs it again), naming
    what stopped it as a run's record does."""
    summary = {**error_summary(stop, overrides, cfg, choices), "status": "interrupted",
               "error": f"KeyboardInterrupt ({stopped_by(stop)})"}
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    record.write_summary(out_dir, summary)
