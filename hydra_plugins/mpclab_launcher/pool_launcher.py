"""A Hydra launcher whose worker processes stay warm from one job to the next.

Hydra's joblib launcher composes every job's config from scratch and its tolerant sweeper
composes each one again in the launching process before any job starts: that serial part
dominated a sweep of short jobs. This launcher:

* starts ``n_jobs`` worker processes once per sweep (``fork`` by default: they inherit the
  imports of the launching process, so none imports anything again); with ``n_jobs=1`` the
  jobs run in the launching process itself;
* pins each worker's BLAS/OpenMP thread pools to ``threads_per_worker`` threads (one job per
  core, no oversubscription);
* sends a worker only a job's number and overrides; the worker (:mod:`._worker`) composes
  the job's config through Hydra's config loader (``load_sweep_config``, as Hydra's own
  launchers do) and runs it with Hydra's ``run_job`` (job folders,
  ``.hydra/`` files, logging and callbacks as with Hydra's launchers); a config that fails
  to compose becomes the job's error row there (the sweeper does not compose jobs up front);
* keeps what a worker built between jobs (``mpclab.runner.component_cache``: the plant,
  objective and compiled controller of the same structure);
* returns each job as soon as it ends and writes ``<sweep>/.mpclab/tasks.jsonl`` (per job:
  worker, time in the worker and the CPU time and minor page faults of that time, time in
  the closed loop);
* goes on when a worker process dies (killed for memory, a crash in a solver's native code):
  the jobs that were running then are run again, each in a process of its own; a job whose
  process dies again becomes an error row that says so, and the other jobs run on a new
  pool. (With ``n_jobs=1`` the jobs run in the launching process, and such a
  crash ends the sweep: the rows written so far stay, and the same command resumes it.)
  A job that runs longer than ``job_timeout_s`` has its worker stopped and becomes an error
  row (:mod:`.recovery`).

Selected by ``conf/hydra/launcher/local.yaml`` (the default); Hydra's joblib launcher stays
available as ``hydra/launcher=joblib`` and the Ray launcher as ``hydra/launcher=ray_cluster``.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import multiprocessing
import os
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from enum import StrEnum
from pathlib import Path
from typing import Any

try:
    import resource  # page faults per job (POSIX)
except ImportError:  # pragma: no cover  (Windows)
    resource = None  # type: ignore[assignment]

import cloudpickle
from hydra.core.singleton import Singleton
from hydra.core.utils import (
    JobReturn,
    configure_log,
    filter_overrides,
    setup_globals,
)
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, open_dict
from threadpoolctl import threadpool_limits

from hydra_plugins.mpclab_launcher import recovery
from hydra_plugins.mpclab_launcher._worker import (
    THREAD_VARS,
    init_forked,
    init_pickled,
    init_worker,
    run_one,
)
from hydra_plugins.mpclab_launcher.recovery import JobBoard, JobTimedOut, Watchdog, each_alone
from hydra_plugins.mpclab_sweeper.tolerant_sweeper import record_job_error
from mpclab.config.registry import register_schema, schema_from_init
from mpclab.core.errors import ConfigError, number, parse_choice, whole_number
from mpclab.core.signals import Terminated, call_first_on_stop, signal_of
from mpclab.sweeps.callbacks import STATE_DIR
from mpclab.sweeps.jobs import WORKERS_VAR, usable_cores

log = logging.getLogger(__name__)

TASKS_FILE = "tasks.jsonl"
#: where the options are, for messages
KEY = "hydra.launcher"


class StartMethod(StrEnum):
    """How worker processes start (:mod:`multiprocessing`'s start methods)."""

    fork = "fork"  # a copy of the launching process: its imports, nothing to pickle
    forkserver = "forkserver"
    spawn = "spawn"


class PoolLauncher(Launcher):
    """Runs a sweep's jobs on ``n_jobs`` warm worker processes (module docstring).

    Parameters
    ----------
    n_jobs
        Worker processes; -1: one per core this process may use.
    threads_per_worker
        BLAS/OpenMP threads of each worker.
    start_method
        ``fork`` (workers inherit the imports), ``forkserver`` or ``spawn``.
    job_timeout_s
        Seconds a job may run before its worker is stopped and the job becomes an error row
        (None: no limit). A limit needs worker processes: with it, ``n_jobs=1`` runs one
        worker process instead of running the jobs in the launching process.
    """

    #: the sweeper leaves composing (and compose errors) to the workers
    composes_in_workers = True

    def __init__(self, n_jobs: int = -1, threads_per_worker: int = 1,
                 start_method: StartMethod | str = StartMethod.fork,
                 job_timeout_s: float | None = None) -> None:
        self.n_jobs = whole_number(n_jobs, f"{KEY}.n_jobs", at_least=1,
                                   also={-1: "one worker per core"})
        self.threads = whole_number(threads_per_worker, f"{KEY}.threads_per_worker", at_least=1)
        self.start_method = str(parse_choice(StartMethod, start_method, f"{KEY}.start_method"))
        try:
            self.timeout_s = None if job_timeout_s is None else number(
                job_timeout_s, f"{KEY}.job_timeout_s", above=0)
        except ConfigError:
            raise ConfigError(f"{KEY}.job_timeout_s: expected seconds > 0, or null for "
                              f"no limit, got {job_timeout_s!r}") from None
        self.config: DictConfig | None = None
        self.hydra_context: HydraContext | None = None
        self.task_function: TaskFunction | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.config = config
        self.hydra_context = hydra_context
        self.task_function = task_function

    def workers(self, n_tasks: int) -> int:
        """How many workers run ``n_tasks`` jobs; a warning where they outnumber the cores."""
        cores = usable_cores()
        n = max(1, min(cores if self.n_jobs == -1 else self.n_jobs, n_tasks))
        if n > cores:
            log.warning("%d workers on %d core(s): jobs share cores, so their compute times "
                        "are inflated (the tables mark such runs 'contended'); "
                        "hydra.launcher.n_jobs=-1 runs one worker per core", n, cores)
        return n

    def launch(self, job_overrides: Sequence[Sequence[str]],
               initial_job_idx: int) -> Sequence[JobReturn]:
        assert self.config is not None and self.hydra_context is not None
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        n = self.workers(len(job_overrides))
        in_process = n == 1 and self.timeout_s is None  # a time limit needs a worker to stop
        log.info("mpclab pool launcher: %d jobs on %d warm worker%s (%s), sweep folder %s",
                 len(job_overrides), n, "" if n == 1 else "s",
                 "in this process" if in_process else self.start_method, sweep_dir)
        for idx, overrides in enumerate(job_overrides, start=initial_job_idx):
            log.debug("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
        # a forked worker inherits Hydra's singletons, the launching process has them; only a
        # started worker needs a copy (Hydra's get_state deep-copies the config store)
        started = not in_process and self.start_method != "fork"
        init = (self.hydra_context, self.config, self.task_function,
                Singleton.get_state() if started else None, self.threads, n)
        jobs = list(enumerate(job_overrides, start=initial_job_idx))
        if in_process:
            results = self._in_process(jobs, init)
        else:
            results = self._on_pool(jobs, init, n)
        _write_tasks(sweep_dir, [info for _, info in results.values()])
        return [results[idx][0] for idx, _ in jobs]

    def _in_process(self, jobs: list[tuple[int, Sequence[str]]],
                    init: tuple[Any, ...]) -> dict[int, tuple[JobReturn, dict[str, Any]]]:
        saved = {v: os.environ.get(v) for v in (*THREAD_VARS, WORKERS_VAR)}
        limits = threadpool_limits(self.threads)
        try:
            init_worker(*init)
            return {idx: run_one(idx, ov) for idx, ov in jobs}
        finally:
            gc.unfreeze()  # frozen by run_one after the first job; this process goes on
            limits.restore_original_limits()
            for var, value in saved.items():
                if value is None:
                    os.environ.pop(var, None)
                else:
                    os.environ[var] = value

    def _on_pool(self, jobs: list[tuple[int, Sequence[str]]], init: tuple[Any, ...],
                 n: int) -> dict[int, tuple[JobReturn, dict[str, Any]]]:
        ctx = multiprocessing.get_context(self.start_method)
        board = JobBoard.new(ctx, len(jobs))
        if self.start_method == "fork":  # inherited, not pickled
            initializer, initargs = init_forked, (*init, board.cells)
        else:
            initializer, initargs = init_pickled, (cloudpickle.dumps(init), board.cells)
        results: dict[int, tuple[JobReturn, dict[str, Any]]] = {}
        todo = list(range(len(jobs)))
        while todo:
            lost, stopped = self._pool_round(ctx, jobs, todo, initializer, initargs, n,
                                             board, results)
            if not lost:
                break
            running = [slot for slot in lost if board.started(slot) and slot not in stopped]
            for slot in stopped:  # ran out of time: not again
                idx, overrides = jobs[slot]
                results[idx] = self._error_row(idx, overrides, JobTimedOut(self.timeout_s or 0),
                                               {"job": idx, "died": "timeout"})
            if not running and not stopped:  # no job started: the workers cannot start
                raise RuntimeError("mpclab pool launcher: the worker processes died before "
                                   "running any job (see the log above)")
            if running:
                log.error("a worker process died; the %d job(s) running then run again, each "
                          "in a process of its own, then the %d not started on new workers",
                          len(running), sum(not board.started(slot) for slot in lost))
            alone = each_alone(ctx, run_one, initializer, initargs, jobs, running, n,
                               self.timeout_s)
            for slot, out in alone.items():
                idx, overrides = jobs[slot]
                # by the module's name: Hydra's plugin scan runs this package's modules again
                if isinstance(out, recovery.Lost):
                    log.error("job %d (%s): %s", idx, " ".join(overrides), out.error)
                    out = self._error_row(idx, overrides, out.error,
                                          {"job": idx, "pid": out.pid, "died": out.how})
                results[idx] = out
            todo = [slot for slot in lost if not board.started(slot)]
        return results

    def _pool_round(
        self, ctx: Any, jobs: list[tuple[int, Sequence[str]]], todo: list[int],
        initializer: Any, initargs: tuple[Any, ...], n: int, board: JobBoard,
        results: dict[int, tuple[JobReturn, dict[str, Any]]],
    ) -> tuple[list[int], set[int]]:
        """Run the jobs at ``todo`` (places in ``jobs``) on a new pool of ``n`` workers into
        ``results``; return the places of those lost because a worker died, and of those
        whose worker was stopped for running out of time."""
        children = set(multiprocessing.active_children())  # before this round's workers
        pool = ProcessPoolExecutor(max_workers=min(n, len(todo)), mp_context=ctx,
                                   initializer=initializer, initargs=initargs)
        lost: list[int] = []
        watchdog = Watchdog(board, self.timeout_s) if self.timeout_s else None
        # what the workers inherit stays out of their garbage collector's way: a collection
        # in a forked worker would otherwise write to (and so copy) every inherited page
        gc.freeze()
        try:
            with watchdog if watchdog is not None else contextlib.nullcontext():
                futures: dict[Future, int] = {pool.submit(run_one, *jobs[slot], slot): slot
                                              for slot in todo}
                # as_completed waits on every future once; wait() in a loop would register
                # with every pending future again after each job (quadratic in the jobs)
                for fut in as_completed(futures):
                    slot = futures[fut]
                    idx, overrides = jobs[slot]
                    try:
                        results[idx] = fut.result()
                    except BrokenProcessPool:  # every job not yet done, once a worker died
                        lost.append(slot)
                    except Exception as exc:  # noqa: BLE001  (e.g. a result that won't pickle)
                        log.error("job %d: its worker could not return it: %r", idx, exc)
                        results[idx] = self._error_row(idx, overrides, exc, {"job": idx})
        except BaseException as exc:
            # the workers record their stopped jobs; a second signal ends them, and this process
            with call_first_on_stop(lambda: recovery.kill_started_since(children)):
                board.stop(signal_of(exc))  # the jobs queued for the workers do not start
                if isinstance(exc, Terminated):  # Ctrl-C reaches the workers too; a signal
                    board.interrupt_running()    # sent to this process alone is passed on
                pool.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            gc.unfreeze()
        # every job is done: the workers exit while this process writes the sweep's tables
        pool.shutdown(wait=False)
        return sorted(lost), (watchdog.stopped & set(lost)) if watchdog else set()

    def _error_row(self, idx: int, overrides: Sequence[str], exc: Exception,
                   info: dict[str, Any]) -> tuple[JobReturn, dict[str, Any]]:
        """Job ``idx``'s error row, written here (its worker could not write it)."""
        try:  # its config composed in the worker; here it names the job's components
            job_cfg = self.hydra_context.config_loader.load_sweep_config(
                self.config, list(overrides))
            with open_dict(job_cfg):
                del job_cfg["hydra"]
        except Exception:  # noqa: BLE001  (the row is written all the same)
            job_cfg = None
        ret = record_job_error(self.hydra_context, self.config, idx, overrides, exc, job_cfg)
        return ret, info


#: the options' one schema, from the constructor: composing checks their types and choices
#: (conf/hydra/launcher/local.yaml lists it first); bound here by name, as Hydra's plugin
#: scan runs this module before it is in ``sys.modules``
PoolLauncherConf = schema_from_init(PoolLauncher)
register_schema("hydra/launcher", "pool", PoolLauncherConf)


def _write_tasks(sweep_dir: Path, infos: list[dict[str, Any]]) -> None:
    """Append each job's time in its worker to ``<sweep>/.mpclab/tasks.jsonl``."""
    state = sweep_dir / STATE_DIR
    state.mkdir(parents=True, exist_ok=True)
    with open(state / TASKS_FILE, "a") as f:
        for info in sorted(infos, key=lambda i: i["job"]):
            f.write(json.dumps(info) + "\n")
