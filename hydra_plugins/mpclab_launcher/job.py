"""Hydra's ``run_job`` for a job config the worker owns, without its copies of the config.

:func:`hydra.core.utils.run_job` deep-copies the job's config twice (about 20 ms each for a
Zumo job) and sets Hydra's global config several times; a warm worker spends more time there
than building its job. :func:`run_owned_job` does the same steps in the same order on a config
that nobody else holds (fresh from :mod:`mpclab.sweeps.compose`): the job folder, the job's
log file, ``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml``, ``env_set``, the
callbacks' ``on_job_start``/``on_job_end``, the task function's return value or exception
(the ``.hydra`` files written by libyaml's emitter: the same text, 20 ms sooner).

Two copies are left out: the task function gets its own copy of the config without its
``hydra`` node, composed from the cache (a tenth of a deep copy's time), and Hydra's global
config (``HydraConfig``) is the job's config itself, where Hydra keeps a copy of its ``hydra``
node whose parent is that config: ``HydraConfig.get()`` and every interpolation resolve
alike (tests/test_pool_job.py runs a job both ways and compares).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml
from hydra.conf import HydraConf
from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import (
    JobReturn,
    JobRuntime,
    JobStatus,
    _flush_loggers,
    configure_log,
    env_override,
)
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict, read_write
from omegaconf._utils import OmegaConfDumper

_Dumper = getattr(yaml, "CDumper", yaml.Dumper)


class _FastDumper(_Dumper):
    """OmegaConf's YAML dumper (its quoting of strings that read as bool, int or float) on
    libyaml's emitter where PyYAML has it: 3-5 times faster than the Python emitter."""


_FastDumper.add_representer(str, OmegaConfDumper.str_representer)


def to_yaml(cfg: DictConfig | ListConfig) -> str:
    """``OmegaConf.to_yaml(cfg)``, emitted by :class:`_FastDumper`."""
    return _dump(OmegaConf.to_container(cfg, resolve=False, enum_to_str=True))


def _dump(container: Any) -> str:
    return yaml.dump(container, default_flow_style=False, allow_unicode=True, sort_keys=False,
                     Dumper=_FastDumper)


def set_hydra_config(config: DictConfig) -> None:
    """``HydraConfig.instance().set_config(config)`` without its copy of ``config.hydra``:
    the same checks and read-only flag; ``HydraConfig.get()`` is ``config.hydra`` itself."""
    OmegaConf.set_readonly(config.hydra, True)
    node_type = OmegaConf.get_type(config, "hydra")
    assert node_type is not None and issubclass(node_type, HydraConf)
    HydraConfig.instance().cfg = config  # type: ignore[assignment]


def run_owned_job(
    hydra_context: HydraContext, config: DictConfig, task_cfg: DictConfig,
    task_function: TaskFunction,
) -> JobReturn:
    """Run one sweep job as ``run_job(..., job_dir_key="hydra.sweep.dir",
    job_subdir_key="hydra.sweep.subdir")`` would; the result holds no configs.

    ``task_cfg`` is the task function's own copy of ``config`` without its ``hydra`` node
    (:meth:`mpclab.sweeps.compose.CachedComposeLoader.load_task_config`).
    """
    callbacks = hydra_context.callbacks
    old_cwd = os.getcwd()
    orig_hydra_cfg = HydraConfig.instance().cfg
    out = os.path.join(str(OmegaConf.select(config, "hydra.sweep.dir")),
                       str(OmegaConf.select(config, "hydra.sweep.subdir")))
    with read_write(config.hydra.runtime), open_dict(config.hydra.runtime):
        config.hydra.runtime.output_dir = os.path.abspath(out)
    set_hydra_config(config)
    chdir = bool(config.hydra.job.chdir)
    try:
        ret = JobReturn(overrides=OmegaConf.to_container(config.hydra.overrides.task))
        Path(out).mkdir(parents=True, exist_ok=True)
        if chdir:
            os.chdir(out)
            ret.working_dir = out
        else:
            ret.working_dir = os.getcwd()
        configure_log(config.hydra.job_logging, config.hydra.verbose)
        if config.hydra.output_subdir is not None:
            hydra_output = Path(config.hydra.runtime.output_dir) / config.hydra.output_subdir
            hydra_output.mkdir(parents=True, exist_ok=True)
            hydra_node = OmegaConf.to_container(config.hydra, resolve=False, enum_to_str=True)
            for text, name in ((to_yaml(task_cfg), "config.yaml"),
                               (_dump({"hydra": hydra_node}), "hydra.yaml"),
                               (to_yaml(config.hydra.overrides.task), "overrides.yaml")):
                (hydra_output / name).write_text(text, encoding="utf-8")
        with env_override(config.hydra.job.env_set):
            callbacks.on_job_start(config=config, task_function=task_function)
            try:
                ret.return_value = task_function(task_cfg)
                ret.status = JobStatus.COMPLETED
            except Exception as exc:  # as Hydra: the sweeper raises it from the return value
                ret.return_value = exc
                ret.status = JobStatus.FAILED
        ret.task_name = JobRuntime.instance().get("name")
        _flush_loggers()
        callbacks.on_job_end(config=config, job_return=ret)
        return ret
    finally:
        HydraConfig.instance().cfg = orig_hydra_cfg
        if chdir:
            os.chdir(old_cwd)
