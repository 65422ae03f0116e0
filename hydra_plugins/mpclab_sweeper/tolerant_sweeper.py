"""Hydra's basic sweeper, except that a job whose config fails to compose becomes an error row.

Hydra composes every job's config before launching any (``validate_batch_is_legal``) and
aborts the whole sweep on the first failure, e.g. ``controller.horizon=10,ten``. This sweeper
instead writes that job's ``summary.json`` with ``status: error`` and Hydra's message into its
job folder, reports it to the callbacks like a finished job, and launches the others with
their usual job numbers. It composes through :mod:`mpclab.sweeps.compose` (each defaults tree
once), and not at all up front when the launcher composes in its workers and records compose
errors there (mpclab's pool launcher): then the launching process composes nothing. It lives
in the ``hydra_plugins`` namespace because Hydra instantiates sweepers only from there;
``conf/hydra/sweeper/tolerant.yaml`` selects it.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.utils import JobReturn, JobStatus
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext
from omegaconf import DictConfig, OmegaConf, open_dict

from mpclab import record
from mpclab.sweeps.compose import cached
from mpclab.sweeps.jobs import error_summary

log = logging.getLogger(__name__)


class TolerantSweeper(BasicSweeper):
    """:class:`BasicSweeper` that records compose errors as rows and runs the other jobs."""

    def __init__(self, max_batch_size: int | None, params: dict[str, str] | None = None) -> None:
        super().__init__(max_batch_size=max_batch_size, params=params)
        self.compose_errors: dict[tuple[str, ...], Exception] = {}

    def setup(self, *, hydra_context: Any, task_function: Any, config: DictConfig) -> None:
        hydra_context = HydraContext(config_loader=cached(hydra_context.config_loader),
                                     callbacks=hydra_context.callbacks)
        super().setup(hydra_context=hydra_context, task_function=task_function, config=config)
        self.launcher = _SkipUncomposable(self.launcher, self)

    def validate_batch_is_legal(self, batch: Sequence[Sequence[str]]) -> None:
        """Compose every job's config; remember (do not raise) the ones that fail."""
        if getattr(self.launcher, "composes_in_workers", False):
            return
        loader = self.hydra_context.config_loader
        for overrides in batch:
            try:
                loader.load_sweep_config(master_config=self.config, sweep_overrides=list(overrides))
            except Exception as exc:  # noqa: BLE001  (Hydra's ConfigCompositionException etc.)
                log.error("job %s cannot be composed: %s", " ".join(overrides), exc)
                self.compose_errors[tuple(overrides)] = exc

    def record_error(self, idx: int, overrides: Sequence[str], exc: Exception) -> JobReturn:
        return record_job_error(self.hydra_context, self.config, idx, overrides, exc)


def record_job_error(
    hydra_context: HydraContext, master: DictConfig, idx: int, overrides: Sequence[str],
    exc: Exception, job_cfg: DictConfig | None = None,
) -> JobReturn:
    """Write the error row of job ``idx``, which could not record itself (its config failed
    to compose, or the worker process running it died); tell the callbacks.

    ``master`` is the sweep's config (its ``hydra.sweep.dir``, with its clock cached);
    ``job_cfg`` the job's own, where it composed (it names the job's components).
    """
    cfg = copy.deepcopy(master)
    with open_dict(cfg):
        cfg.hydra.job.num = idx
        cfg.hydra.job.override_dirname = ""
    sweep_dir = Path(str(master.hydra.sweep.dir))
    out_dir = sweep_dir / str(OmegaConf.select(cfg, "hydra.sweep.subdir"))
    choices = OmegaConf.to_container(master.hydra.runtime.choices)
    summary = error_summary(exc, overrides, cfg=job_cfg, choices=choices, base=master)
    summary["experiment"] = cfg.get("name")
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / ".hydra").mkdir(exist_ok=True)
    OmegaConf.save(OmegaConf.create(list(overrides)), out_dir / ".hydra" / "overrides.yaml")
    record.write_summary(out_dir, summary)
    ret = JobReturn(overrides=list(overrides), status=JobStatus.COMPLETED,
                    _return_value=summary, working_dir=str(out_dir))
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(out_dir)
    hydra_context.callbacks.on_job_end(config=cfg, job_return=ret)
    return ret


class _SkipUncomposable:
    """Wraps the launcher: runs the composable jobs, records the others, keeps job numbers."""

    def __init__(self, launcher: Launcher, sweeper: TolerantSweeper) -> None:
        self.launcher = launcher
        self.sweeper = sweeper

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        errors = self.sweeper.compose_errors
        results: list[JobReturn] = []
        segment: list[Sequence[str]] = []
        start = initial_job_idx
        for idx, overrides in enumerate(job_overrides, start=initial_job_idx):
            if tuple(overrides) not in errors:
                segment.append(overrides)
                continue
            if segment:  # launch the run of good jobs before this one, numbered as usual
                results += self.launcher.launch(segment, initial_job_idx=start)
            results.append(self.sweeper.record_error(idx, overrides, errors[tuple(overrides)]))
            segment, start = [], idx + 1
        if segment:
            results += self.launcher.launch(segment, initial_job_idx=start)
        return results

    def __getattr__(self, name: str) -> Any:
        return getattr(self.launcher, name)
