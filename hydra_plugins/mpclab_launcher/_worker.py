"""The worker side of :mod:`.pool_launcher`: set a process up to run jobs, then compose and
run each job it is sent with Hydra's ``run_job``, timing it (time, CPU time and minor page
faults of the job, for ``tasks.jsonl``).

Named with a leading underscore so that Hydra's plugin scan, which executes every other module
under ``hydra_plugins`` again, leaves it alone: the functions the launcher sends to its pool
must stay the objects this module's name resolves to (pickling finds them by name)."""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import time
from collections.abc import Sequence
from typing import Any

try:
    import resource  # page faults per job (POSIX)
except ImportError:  # pragma: no cover  (Windows)
    resource = None  # type: ignore[assignment]

import cloudpickle
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, run_job, setup_globals
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, open_dict
from threadpoolctl import threadpool_limits

from hydra_plugins.mpclab_launcher.recovery import JobBoard
from hydra_plugins.mpclab_sweeper.tolerant_sweeper import record_job_error
from mpclab.config.allowed_targets import check_config
from mpclab.core.signals import interrupted, worker_signals
from mpclab.sweeps.jobs import WORKERS_VAR

log = logging.getLogger(__name__)

#: environment variables that size thread pools of BLAS, OpenMP and friends
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
               "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")

#: what a worker needs to run a job, set once per worker by :func:`init_worker`
_WORKER: dict[str, Any] = {}


def init_worker(
    hydra_context: HydraContext, config: DictConfig, task_function: TaskFunction,
    singleton_state: dict[Any, Any] | None, threads: int, workers: int,
    board_cells: Any = None,
) -> None:
    """Set up this process to run jobs of the sweep whose config is ``config``;
    ``singleton_state``: Hydra's singletons (config
    store, runtime, resolvers) for a started worker, None where they are this process's own
    (in the launching process, or forked from it); ``board_cells``: the shared array of the
    pool's :class:`~.recovery.JobBoard`, where a worker notes each job it starts and ends."""
    for var in THREAD_VARS:
        os.environ[var] = str(threads)
    os.environ[WORKERS_VAR] = str(workers)
    threadpool_limits(threads)  # pools already loaded (numpy's BLAS) follow the variables
    setup_globals()
    if singleton_state is not None:
        Singleton.set_state(singleton_state)  # and scans Hydra's plugins again
    board = None if board_cells is None else JobBoard(board_cells)
    _WORKER.update(hydra_context=hydra_context, config=config, task_function=task_function,
                   board=board)


def init_forked(*args: Any) -> None:
    """:func:`init_worker` for a worker process forked from the launching one, with a
    worker's signal handling (:func:`~mpclab.core.signals.worker_signals`), not the launching
    process's: SIGTERM and SIGHUP end it (the pool stops a worker with SIGTERM), after the
    job it runs, if any, recorded what it had; SIGINT interrupts its job only."""
    worker_signals()
    init_worker(*args)


def init_pickled(blob: bytes, board_cells: Any = None) -> None:
    """:func:`init_worker` for a started (not forked) worker: its arguments cloudpickled
    (Hydra's configs hold classes that the standard pickle cannot find by name); the shared
    ``board_cells`` apart (shared memory passes only as the process starts)."""
    worker_signals()
    init_worker(*cloudpickle.loads(blob), board_cells=board_cells)


def run_one(
    idx: int, overrides: Sequence[str], slot: int | None = None,
) -> tuple[JobReturn, dict[str, Any]]:
    """Compose and run job ``idx`` in this worker; the result without its configs. ``slot``:
    the job's place on the pool's board (None: no board, as in the launching process)."""
    board = _WORKER.get("board") if slot is not None else None
    with board.running(slot) if board is not None else contextlib.nullcontext():
        try:
            return _compose_and_run(idx, overrides)
        except Exception as exc:
            # a stop that hit Hydra's or OmegaConf's code around the job, handed back as
            # another error, is a stop: the same command runs the job again
            stop = interrupted(exc)
            if stop is not None:
                raise stop from exc
            raise


def _compose_and_run(idx: int, overrides: Sequence[str]) -> tuple[JobReturn, dict[str, Any]]:
    if _WORKER.setdefault("jobs", 0) == 1:
        # what the first job built stays: out of the garbage collector's way, so that
        # its full collections (tens of ms over the configs and solvers) do not recur
        gc.collect()
        gc.freeze()
    _WORKER["jobs"] += 1
    t0, start, cpu0, faults0 = time.perf_counter(), time.time(), time.process_time(), _faults()
    ctx, config = _WORKER["hydra_context"], _WORKER["config"]
    try:
        # composed as Hydra composes every job of a sweep (its public config loader)
        sweep_config = ctx.config_loader.load_sweep_config(config, list(overrides))
        check_config(sweep_config, app=False)  # its hydra node, before run_job acts on it
    except Exception as exc:  # noqa: BLE001  (Hydra's ConfigCompositionException etc.)
        if interrupted(exc) is not None:  # a stop, handed back as another error (above)
            raise
        log.error("job %s cannot be composed: %s", " ".join(overrides), exc)
        ret = record_job_error(ctx, config, idx, overrides, exc)
    else:
        with open_dict(sweep_config):
            sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
            sweep_config.hydra.job.num = idx
        ret = run_job(hydra_context=ctx, task_function=_WORKER["task_function"],
                      config=sweep_config, job_dir_key="hydra.sweep.dir",
                      job_subdir_key="hydra.sweep.subdir")
        # the configs stay here: the launching process needs the return value only (and a
        # config holds schema classes that a started worker's copy of a module redefines)
        ret.cfg = ret.hydra_cfg = None
    task_s, cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
    value = ret.return_value if ret.status == JobStatus.COMPLETED else None
    timing = value.get("timing", {}) if isinstance(value, dict) else {}
    # minor faults: a forked worker copies each inherited page it writes (copy on write)
    faults = None if faults0 is None else _faults() - faults0
    info = {"job": idx, "pid": os.getpid(), "start": start, "task_s": task_s, "cpu_s": cpu_s,
            "minor_faults": faults, **timing}
    return ret, info


def _faults() -> int | None:
    """Minor page faults of this process so far (None where the OS does not say)."""
    return None if resource is None else resource.getrusage(resource.RUSAGE_SELF).ru_minflt
