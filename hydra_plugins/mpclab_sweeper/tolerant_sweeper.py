"""mpclab's sweeper: Hydra's basic sweep syntax, and a job that fails to compose is a row.

It makes the same jobs, in the same order and with the same numbers, as Hydra's basic sweeper
(:func:`mpclab.sweeps.expand.job_overrides`: every comma list, ``range`` and ``glob`` expanded,
the cartesian product in the order the keys first appear, ``hydra.sweeper.params`` first,
batches of ``max_batch_size``). Hydra's basic sweeper composes every job's config before
launching any and aborts the sweep at the first that fails (``controller.horizon=10,ten``);
this one launches them all, and a job whose config fails to compose becomes a
``status: error`` row with Hydra's message in its job folder, reported to the callbacks like a
finished job; so does a job whose config may not be run
(:func:`mpclab.config.allowed_targets.check_config`). mpclab's pool launcher composes and checks in
its workers and writes those rows itself; for any other launcher (joblib, Ray) the jobs are composed
and checked here first and the failing ones recorded here. Written on Hydra's public ``Sweeper``
plugin interface; lives in the ``hydra_plugins`` namespace because Hydra instantiates sweepers only
from there; ``conf/hydra/sweeper/tolerant.yaml`` selects it.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Sequence
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.plugins import Plugins
from hydra.core.utils import JobReturn, JobStatus
from hydra.plugins.launcher import Launcher
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

from mpclab.config.allowed_targets import check_config
from mpclab.record import files as record
from mpclab.sweeps.expand import job_overrides, sweep_dir_override
from mpclab.sweeps.jobs import error_summary

log = logging.getLogger(__name__)


class TolerantSweeper(Sweeper):
    """Hydra's basic sweep; compose errors become rows and the other jobs run.

    Parameters
    ----------
    max_batch_size
        Jobs launched at once (None: all of them).
    params
        Sweep overrides from the config (``hydra.sweeper.params``), before the command's.
    """

    def __init__(self, max_batch_size: int | None = None,
                 params: dict[str, str] | None = None) -> None:
        super().__init__()
        self.max_batch_size = max_batch_size
        self.params = dict(params or {})
        self.hydra_context: HydraContext | None = None
        self.config: DictConfig | None = None
        self.launcher: Launcher | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.hydra_context = hydra_context
        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config)

    def sweep(self, arguments: list[str]) -> list[Sequence[JobReturn]]:
        assert self.config is not None and self.launcher is not None
        assert self.hydra_context is not None
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        lines = [f"{k}={v}" for k, v in self.params.items()] + list(arguments)
        lines.append(sweep_dir_override(sweep_dir))  # every job under the announced folder
        parser = OverridesParser.create(config_loader=self.hydra_context.config_loader)
        batches = job_overrides(parser.parse_overrides(lines), self.max_batch_size)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        returns: list[Sequence[JobReturn]] = []
        start = 0
        for batch in batches:
            returns.append(self._launch(batch, start))
            start += len(batch)
        return returns

    def _launch(self, batch: list[list[str]], start: int) -> list[JobReturn]:
        """Launch ``batch`` numbered from ``start``; without a launcher that composes in its
        workers, first compose each job here and record the ones that fail."""
        assert self.launcher is not None and self.hydra_context is not None
        if getattr(self.launcher, "composes_in_workers", False):
            return list(self.launcher.launch(batch, initial_job_idx=start))
        results: list[JobReturn] = []
        segment: list[list[str]] = []
        seg_start = start
        for idx, overrides in enumerate(batch, start=start):
            try:  # composed and checked before the launcher (Hydra) acts on any of it
                check_config(self.hydra_context.config_loader.load_sweep_config(
                    self.config, list(overrides)), app=False)
            except Exception as exc:  # noqa: BLE001  (Hydra's ConfigCompositionException etc.)
                log.error("job %s cannot be composed: %s", " ".join(overrides), exc)
                if segment:  # the good jobs before it, numbered as usual
                    results += self.launcher.launch(segment, initial_job_idx=seg_start)
                results.append(record_job_error(self.hydra_context, self.config, idx,
                                                overrides, exc))
                segment, seg_start = [], idx + 1
                continue
            segment.append(overrides)
        if segment:
            results += self.launcher.launch(segment, initial_job_idx=seg_start)
        return results


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
                    working_dir=str(out_dir))
    ret.return_value = summary
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(out_dir)
    hydra_context.callbacks.on_job_end(config=cfg, job_return=ret)
    return ret
