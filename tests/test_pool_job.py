"""A pool worker's job is Hydra's ``run_job``: the same files, the same config seen by the task.

The pool launcher runs a job on configs it owns, without Hydra's copies (the task's config is
composed without its ``hydra`` node; ``HydraConfig`` is the job's config itself):
hydra_plugins/mpclab_launcher/job.py. Both ways are run here on the same job and compared.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
from hydra import initialize_config_dir
from hydra._internal.callbacks import Callbacks
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobStatus, run_job
from hydra.types import HydraContext, RunMode
from omegaconf import DictConfig, OmegaConf, open_dict

from conftest import CONF
from hydra_plugins.mpclab_launcher.job import run_owned_job
from mpclab.registry import register_all
from mpclab.sweeps.compose import CachedComposeLoader

SWEEP = ["+experiment=car_cvxpy", "seed=range(0,3)", "controller.horizon=8,10",
         "+note=${hydra:job.name}-${seed}"]


def _seen(cfg: DictConfig) -> dict[str, Any]:
    """What a task sees: its config (resolved) and Hydra's, with interpolations resolved."""
    hc = HydraConfig.get()
    return {
        "task": OmegaConf.to_container(cfg, resolve=True),
        "keys": sorted(cfg),
        "output_dir": hc.runtime.output_dir,
        "job": (hc.job.name, hc.job.num, hc.job.id, hc.job.override_dirname),
        "overrides": list(hc.overrides.task),
        "log_file": hc.job_logging.handlers.file.filename,
        "choices": dict(hc.runtime.choices),
        "mode": hc.mode,
    }


def _files(job_dir: Path) -> dict[str, str]:
    return {p.name: p.read_text() for p in sorted((job_dir / ".hydra").iterdir())}


@pytest.fixture(autouse=True)
def _hydra_config_restored():
    """The test sets Hydra's global config; later tests must not see it."""
    saved = HydraConfig.instance().cfg
    yield
    HydraConfig.instance().cfg = saved


@pytest.mark.parametrize("job", [["+experiment=car_cvxpy", "seed=2", "controller.horizon=10",
                                  "+note=${hydra:job.name}-${seed}"]])
def test_a_pool_job_is_hydras_job(tmp_path: Path, job: list[str]) -> None:
    register_all()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration(
            "config", [*SWEEP, f"hydra.sweep.dir={tmp_path}", "hydra.mode=MULTIRUN"],
            RunMode.MULTIRUN)
        HydraConfig.instance().set_config(master)
        before = HydraConfig.instance().cfg
        ctx = HydraContext(config_loader=loader, callbacks=Callbacks(None))
        seen: list[dict[str, Any]] = []

        def task(cfg: DictConfig) -> int:
            seen.append(_seen(cfg))
            return 7

        def numbered(cfg: DictConfig) -> DictConfig:
            with open_dict(cfg):
                cfg.hydra.job.id, cfg.hydra.job.num = f"{cfg.hydra.job.name}_5", 5
            return cfg

        want = run_job(hydra_context=ctx, task_function=task,
                       config=numbered(loader.load_sweep_config(master, job)),
                       job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
        want_files = _files(tmp_path / "5")
        shutil.rmtree(tmp_path / "5")

        cached = CachedComposeLoader(loader)
        got = run_owned_job(ctx, numbered(cached.load_sweep_config(master, job)),
                            cached.load_task_config(master, job), task)
        got_files = _files(tmp_path / "5")
        assert HydraConfig.instance().cfg is before  # Hydra's global config restored

    assert got.status == want.status == JobStatus.COMPLETED
    assert (got.return_value, got.overrides, got.working_dir, got.task_name) == (
        want.return_value, want.overrides, want.working_dir, want.task_name)
    assert seen[1] == seen[0]
    assert seen[0]["task"]["note"] == f"{seen[0]['job'][0]}-2" and "hydra" not in seen[0]["keys"]
    assert got_files == want_files
