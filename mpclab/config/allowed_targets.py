"""What a composed config may make Python do: build registered components, nothing else.

Experiment files are shared like code, but a config is data. :func:`check_config` walks a
whole composed config (its ``hydra`` node too, where it has one) before anything in it is
built or applied, and refuses with one message naming the key:

* a ``_target_`` that is not registered (:func:`mpclab.config.registry.require_registered`), except
  that ``hydra.launcher`` and ``hydra.sweeper`` also take the Hydra plugins listed by
  :func:`allowed_plugins` (whose options start no other code);
* in Hydra's logging configs (``hydra.job_logging``, ``hydra.hydra_logging``: Python's
  ``logging.config.dictConfig`` calls whatever factory they name), a factory or ``class``
  other than logging's own stream, file and null handlers and formatters, an ``ext://``
  object other than ``sys.stdout`` and ``sys.stderr``, a log file not named ``*.log``;
* in ``hydra.job.env_set``, a variable other than a thread count, ``CUDA_VISIBLE_DEVICES`` or
  ``MPLBACKEND`` that would change the environment (``LD_PRELOAD``, ``CC`` or ``PYTHONPATH``
  make a child process or the compiler run other code);
* ``hydra.output_subdir`` outside the run's folder (absolute, ``..``, an interpolation);
* a launcher's ``runtime_env`` (Ray installs packages and runs hooks from it).

The modules listed under ``plugins`` are imported first, so that the user's own components
they register count (:func:`mpclab.config.registry.import_plugins`). :func:`check_multirun` adds the
rule that keeps each job of a sweep checked before Hydra applies its config.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import PurePath
from typing import Any

from hydra.core.plugins import Plugins
from hydra.plugins.launcher import Launcher
from hydra.plugins.sweeper import Sweeper
from omegaconf import DictConfig, ListConfig, OmegaConf

from mpclab.config.registry import import_plugins, require_registered, target
from mpclab.core.errors import ConfigError

#: mpclab's sweeper and launcher: each checks every job's config before Hydra applies it
CHECKING_SWEEPER = "hydra_plugins.mpclab_sweeper.tolerant_sweeper.TolerantSweeper"
CHECKING_LAUNCHER = "hydra_plugins.mpclab_launcher.pool_launcher.PoolLauncher"
#: mpclab's multi-objective search (its jobs checked by mpclab's launcher, as any sweep's)
SEARCH_SWEEPER = "hydra_plugins.mpclab_sweeper.pareto_search.ParetoSearchSweeper"
#: installed Hydra plugins a config may select besides Hydra's own and mpclab's (the Ray
#: launcher that starts or joins a cluster; not the one that provisions machines on AWS)
OTHER_PLUGINS = {
    "hydra.launcher": ("hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher",
                       "hydra_plugins.hydra_ray_launcher.ray_launcher.RayLauncher"),
    "hydra.sweeper": (),
}
_PLUGIN_KINDS: dict[str, type] = {"hydra.launcher": Launcher, "hydra.sweeper": Sweeper}

#: what Hydra's logging configs may name as a handler or formatter class (or factory)
LOGGING_CLASSES = ("logging.StreamHandler", "logging.FileHandler", "logging.NullHandler",
                   "logging.Formatter", "colorlog.ColoredFormatter")
LOGGING_STREAMS = ("ext://sys.stdout", "ext://sys.stderr")
#: environment variables a config may set (``hydra.job.env_set``)
SAFE_ENV = re.compile(r"[A-Z0-9_]*_(NUM|MAX|MAXIMUM)_THREADS|CUDA_VISIBLE_DEVICES|MPLBACKEND")


def allowed_plugins(key: str) -> list[str]:
    """The ``_target_`` values ``key`` (``hydra.launcher`` or ``hydra.sweeper``) may take:
    Hydra's own plugins of that kind, mpclab's, and :data:`OTHER_PLUGINS`."""
    found = [target(c) for c in Plugins.instance().discover(_PLUGIN_KINDS[key])]
    mine = (CHECKING_SWEEPER, CHECKING_LAUNCHER, SEARCH_SWEEPER)
    return sorted(t for t in found if t.startswith("hydra.") or t in mine
                  or t in OTHER_PLUGINS[key])


def check_config(cfg: DictConfig, app: bool = True) -> None:
    """Raise :class:`ConfigError` for the first thing in ``cfg`` a config may not do.

    ``app`` False: only its ``hydra`` node (a sweep's job, whose other keys are checked where
    the job is built: :func:`mpclab.runner.single_run.build_run`)."""
    import_plugins(OmegaConf.select(cfg, "plugins"))
    for key, node in cfg.items_ex(resolve=False):
        if key != "hydra" and not app:
            continue
        if isinstance(node, DictConfig | ListConfig):
            node = OmegaConf.to_container(node, resolve=False, throw_on_missing=False)
        _walk(node, str(key), _targets)
        if key == "hydra" and isinstance(node, dict):
            _check_hydra(node)


def check_multirun(cfg: DictConfig) -> None:
    """A sweep's jobs each get their own ``hydra`` node (a swept ``hydra.*`` key, a swept
    experiment that sets one): it must be checked before Hydra applies it, which mpclab's
    sweeper and its launcher do; Hydra's basic sweeper with another launcher would not."""
    sweeper = OmegaConf.select(cfg, "hydra.sweeper._target_")
    launcher = OmegaConf.select(cfg, "hydra.launcher._target_")
    if sweeper != CHECKING_SWEEPER and launcher != CHECKING_LAUNCHER:
        raise ConfigError(
            f"hydra.sweeper._target_: {sweeper!r} with hydra.launcher._target_ {launcher!r} "
            "would apply each job's config unchecked; use mpclab's sweeper "
            "(hydra/sweeper=tolerant, the default) or its launcher (hydra/launcher=local)")


def check_value(value: Any, key: str) -> None:
    """Check a plain value (a swept override's) about to be set at config ``key``: a
    ``_target_`` in it, or it as the ``_target_``, must be registered."""
    parent, _, last = key.rpartition(".")
    if last == "_target_":
        value, key = {"_target_": value}, parent
    _walk(value, key, _targets)


def _walk(node: Any, path: str, visit: Callable[[dict, str], None]) -> None:
    """``visit(d, path)`` for every dict ``d`` in the plain tree ``node``."""
    if isinstance(node, dict):
        visit(node, path)
        for key, child in node.items():
            _walk(child, f"{path}.{key}" if path else str(key), visit)
    elif isinstance(node, list):
        for i, child in enumerate(node):
            _walk(child, f"{path}[{i}]", visit)


def _targets(node: dict, path: str) -> None:
    if "_target_" not in node:
        return
    if path in _PLUGIN_KINDS and node["_target_"] in allowed_plugins(path):
        return
    require_registered(node["_target_"], path)


def _check_hydra(hydra: dict) -> None:
    for name in ("hydra_logging", "job_logging"):
        _walk(hydra.get(name), f"hydra.{name}", _logging)
    env = (hydra.get("job") or {}).get("env_set") or {}
    for name, value in env.items():
        if not SAFE_ENV.fullmatch(str(name)) and os.environ.get(str(name)) != str(value):
            raise ConfigError(
                f"hydra.job.env_set.{name}: a config may set thread counts "
                f"(OMP_NUM_THREADS, ...), CUDA_VISIBLE_DEVICES and MPLBACKEND, not {name!r} "
                "(it could make a child process run other code); set it in the shell")
    sub = hydra.get("output_subdir")
    if sub is not None and (PurePath(str(sub)).is_absolute() or ".." in PurePath(str(sub)).parts
                            or "${" in str(sub)):
        raise ConfigError(f"hydra.output_subdir: {sub!r} would leave the run's folder; "
                          "expected a relative folder name (default .hydra) or null")
    _walk(hydra.get("launcher"), "hydra.launcher", _no_runtime_env)


def _logging(node: dict, path: str) -> None:
    for key, value in node.items():
        text = str(value)
        if key in ("()", "class") and text not in LOGGING_CLASSES:
            raise ConfigError(f"{path}.{key}: {text!r} is not a logging class a config may "
                              f"name; valid: {', '.join(LOGGING_CLASSES)}")
        if isinstance(value, str) and value.startswith("ext://") and value not in LOGGING_STREAMS:
            raise ConfigError(f"{path}.{key}: {value!r} is not a stream a config may name; "
                              f"valid: {', '.join(LOGGING_STREAMS)}")
        if key == "filename" and not text.endswith(".log"):
            raise ConfigError(f"{path}.filename: {text!r}: a log file's name must end in .log")


def _no_runtime_env(node: dict, path: str) -> None:
    if node.get("runtime_env"):
        raise ConfigError(f"{path}.runtime_env: a config may not give Ray a runtime "
                          "environment (it installs packages and runs hooks); set it up "
                          "outside mpclab")
