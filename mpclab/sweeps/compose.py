"""Composing configs cheaply: the defaults tree once per set of group choices.

Hydra composes every config from scratch (about 0.2-0.35 s for a Zumo job: reading and
merging every YAML file and schema of its defaults tree), and a sweep over seeds composes
the same tree again and again. A command's overrides are of two kinds (Hydra's own rule, in
``hydra._internal.defaults_list``): *group* overrides (``scenario=zumo_random``,
``+experiment=zumo_bug2``) choose the defaults tree; *value* overrides (``seed=3``,
``controller.horizon=20``) are applied to the composed config afterwards, and *sweep*
overrides (``seed=range(0,48)``) are not applied at all until they become a job's values.
So :class:`CachedComposeLoader` composes with Hydra once per distinct list of group
overrides, keeps that config, and for each call applies the value overrides to a copy with
Hydra's own function, then fills in the ``hydra.overrides`` lists and
``hydra.job.override_dirname`` as Hydra would; what fails to compose fails the same way
(tests/test_sweep_warm.py checks both against Hydra's full compose).

Within :func:`composing_once` (``python -m mpclab``), Hydra's two compositions of a command's
config (to read its ``hydra.mode``, then to run it) and a sweep's jobs share one tree: the
launching process composes it once, and the pool launcher's workers, forked after that,
inherit it. Between commands, :mod:`mpclab.sweeps.compose_store` keeps the tree on disk.

The cache is per process (module level), so that a warm worker keeps it between jobs; it is
not pickled with the loader (joblib and Ray ship the loader to their workers). It holds each
composed config pickled: loading a fresh copy takes 3 ms where a deep copy takes 20 ms (a
config that does not pickle is deep-copied instead).
"""

from __future__ import annotations

import contextlib
import copy
import functools
import importlib
import io
import pickle
from collections import OrderedDict
from collections.abc import Iterator
from typing import Any

from hydra._internal.config_loader_impl import ConfigLoaderImpl, get_overrides_dirname
from hydra._internal.hydra import Hydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from mpclab.sweeps import compose_store

_Frozen = bytes | DictConfig  # a config pickled, or itself where it does not pickle

#: composed base configs kept per process, most recent last: (whole, without ``hydra``)
_BASES: OrderedDict[tuple[Any, ...], tuple[_Frozen, _Frozen]] = OrderedDict()
_MAX_BASES = 16


def _override_dirname(cfg: DictConfig, app: list[Override]) -> str:
    conf = cfg.hydra.job.config.override_dirname
    return get_overrides_dirname(overrides=app, kv_sep=conf.kv_sep, item_sep=conf.item_sep,
                                 exclude_keys=conf.exclude_keys)


class CachedComposeLoader:
    """A Hydra config loader that composes each defaults tree once per process.

    ``load_configuration`` (and ``load_sweep_config``, which calls it) compose the tree of the
    group overrides with Hydra, keep it, and apply the value overrides to a fresh copy;
    everything else is delegated to the wrapped loader.
    """

    def __init__(self, loader: Any) -> None:
        self.loader = loader

    def __getstate__(self) -> dict[str, Any]:
        return {"loader": self.loader}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.loader = state["loader"]

    def __getattr__(self, name: str) -> Any:
        if name == "loader":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.loader, name)

    def load_configuration(
        self, config_name: str | None, overrides: list[str], run_mode: RunMode,
        from_shell: bool = True, validate_sweep_overrides: bool = True,
    ) -> DictConfig:
        """What ``ConfigLoaderImpl.load_configuration`` returns, from a cached tree."""
        return _compose(self.loader, self.loader.load_configuration, config_name=config_name,
                        overrides=list(overrides), run_mode=run_mode, from_shell=from_shell,
                        validate_sweep_overrides=validate_sweep_overrides)

    def load_sweep_config(
        self, master_config: DictConfig, sweep_overrides: list[str],
    ) -> DictConfig:
        """What ``ConfigLoaderImpl.load_sweep_config`` returns, composed from a cached tree."""
        return self._job_config(master_config, sweep_overrides, task=False)

    def load_task_config(
        self, master_config: DictConfig, sweep_overrides: list[str],
    ) -> DictConfig:
        """``load_sweep_config(...)`` without its ``hydra`` node, as Hydra hands a job's
        config to the task function (a copy with ``hydra`` deleted), from a kept tree that
        has no ``hydra`` node (half the copying)."""
        return self._job_config(master_config, sweep_overrides, task=True)

    def _job_config(
        self, master_config: DictConfig, sweep_overrides: list[str], task: bool,
    ) -> DictConfig:
        hydra_overrides = list(OmegaConf.to_container(master_config.hydra.overrides.hydra))
        cfg = _compose(self.loader, self.loader.load_configuration, task=task,
                       config_name=master_config.hydra.job.config_name,
                       overrides=hydra_overrides + list(sweep_overrides), run_mode=RunMode.RUN,
                       from_shell=True, validate_sweep_overrides=True)
        OmegaConf.copy_cache(from_config=master_config, to_config=cfg)
        return cfg


def _compose(loader: Any, compose: Any, task: bool = False, **kw: Any) -> DictConfig:
    """Hydra's ``load_configuration(**kw)``: the tree of its group overrides (composed by
    ``compose`` in RUN mode once, then kept), its value overrides applied to a copy, and the
    ``hydra.overrides`` lists and ``hydra.job.override_dirname`` filled in as Hydra fills them.

    A group swept in a multirun, or a tree that does not compose in RUN mode (a mandatory
    group left ``???``, which a multirun skips), goes to ``compose`` as it is: what Hydra
    does, and the error Hydra raises, stay Hydra's. With ``task``, the config without its
    ``hydra`` node (the value overrides of ``hydra.*`` are not applied: that node is gone).
    """
    parsed = [_parse(line) for line in kw["overrides"]]
    if kw["validate_sweep_overrides"]:
        loader.validate_sweep_overrides_legal(overrides=parsed, run_mode=kw["run_mode"],
                                              from_shell=kw["from_shell"])
    repo = loader.repository
    is_value = [_is_value_override(o, repo) for o in parsed]
    values = [o for o, v in zip(parsed, is_value, strict=True) if v]
    group = [o for o, v in zip(parsed, is_value, strict=True) if not v]
    if any(o.is_sweep_override() for o in group):
        return _without_hydra(compose(**kw)) if task else compose(**kw)
    lines = tuple(o.input_line for o in _in_job_order(group))
    key = (kw["config_name"], lines)
    base = _BASES.get(key)
    if base is None:
        # a command line that moves the search path composes with Hydra every time
        stored = compose_store.enabled() and not any(
            o.key_or_group == "hydra.searchpath" for o in parsed)
        cfg = compose_store.load(repo, kw["config_name"], lines) if stored else None
        composed = cfg is None
        if composed:
            try:
                cfg = compose(config_name=kw["config_name"], overrides=list(lines),
                              run_mode=RunMode.RUN)
            except Exception:  # noqa: BLE001  (Hydra's own call raises Hydra's own error)
                if kw["run_mode"] == RunMode.RUN:
                    raise
                return compose(**kw)
        frozen = _frozen(cfg)
        if stored and composed and isinstance(frozen, bytes):
            compose_store.save(repo, kw["config_name"], lines, frozen, cfg)
        base = _BASES[key] = (frozen, _frozen(_without_hydra(_thawed(frozen))))
        while len(_BASES) > _MAX_BASES:
            _BASES.popitem(last=False)
    else:
        _BASES.move_to_end(key)
    values = [o for o in values if not o.is_sweep_override()]
    if task:
        cfg = _thawed(base[1])
        ConfigLoaderImpl._apply_overrides_to_config(
            [o for o in values if not o.is_hydra_override()], cfg)
        return cfg
    cfg = _thawed(base[0])
    ConfigLoaderImpl._apply_overrides_to_config(values, cfg)
    with open_dict(cfg.hydra):
        cfg.hydra.overrides.hydra = [o.input_line for o in parsed if o.is_hydra_override()]
        app = [o for o in parsed if not o.is_hydra_override()]
        cfg.hydra.overrides.task = [o.input_line for o in app]
        cfg.hydra.job.override_dirname = _override_dirname(cfg, app)
    return cfg


def _in_job_order(group: list[Override]) -> list[Override]:
    """The group overrides as a sweep's job lists them (Hydra's overrides first), so that a
    command and its jobs share one tree; in their own order where that could change the
    tree (a Hydra group added or deleted: its merge order against the others')."""
    hydra = [o for o in group if o.is_hydra_override()]
    if any(o.is_add() or o.is_force_add() or o.is_delete() for o in hydra):
        return group
    return hydra + [o for o in group if not o.is_hydra_override()]


class _ByName(pickle.Pickler):
    """Pickles a class by its module and name even where the module now holds an equal class
    of the same name (Hydra imports its plugins' modules more than once)."""

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, type):
            try:
                found = _lookup(obj.__module__, obj.__qualname__)
            except (ImportError, AttributeError):
                return NotImplemented
            if found is not obj:
                return _lookup, (obj.__module__, obj.__qualname__)
        return NotImplemented


def _lookup(module: str, qualname: str) -> Any:
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _thawed(frozen: _Frozen) -> DictConfig:
    """A fresh copy of a kept config."""
    return pickle.loads(frozen) if isinstance(frozen, bytes) else copy.deepcopy(frozen)


def _without_hydra(cfg: DictConfig) -> DictConfig:
    """``cfg`` with its ``hydra`` node deleted, as Hydra's ``run_job`` deletes it."""
    with read_write(cfg), open_dict(cfg):
        del cfg["hydra"]
    return cfg


def _frozen(cfg: DictConfig) -> _Frozen:
    """``cfg`` pickled (to load fresh copies from), or itself if it does not pickle."""
    buf = io.BytesIO()
    try:
        _ByName(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(cfg)
    except (pickle.PicklingError, TypeError, AttributeError):
        return cfg
    return buf.getvalue()


@functools.lru_cache(maxsize=4096)
def _parse(line: str) -> Override:
    """One override parsed (sweeps repeat most of their override lines from job to job)."""
    return OverridesParser.create().parse_overrides(overrides=[line])[0]


def _is_value_override(override: Override, repo: Any) -> bool:
    """Hydra's rule (``defaults_list.Overrides``): a dict value, or a key that is no group."""
    return isinstance(override.value(), dict) or not _is_group(repo, override.key_or_group)


@functools.lru_cache(maxsize=4096)
def _is_group(repo: Any, key: str) -> bool:
    """``repo.group_exists(key)``, asked once per process (each asks every config source's
    folders; a sweep asks it of the same keys for every job)."""
    return bool(repo.group_exists(key))


def cached(loader: Any) -> CachedComposeLoader:
    """``loader`` wrapped (once) in a :class:`CachedComposeLoader`."""
    return loader if isinstance(loader, CachedComposeLoader) else CachedComposeLoader(loader)


@contextlib.contextmanager
def composing_once() -> Iterator[None]:
    """Within this block, Hydra composes a command's configs with a :class:`CachedComposeLoader`.

    Hydra composes a command's config twice (once to read its ``hydra.mode``, once to run
    it), and a sweep's worker composes its first job's tree once more: the three share one
    tree, composed once (the workers inherit it when they are forked). The kept trees are
    dropped when the block starts and ends: a process that runs several commands (a notebook,
    a test) composes each anew, from the files as they are then.
    """
    get_mode = Hydra.get_mode
    wrapped: list[tuple[Hydra, Any]] = []

    def caching_get_mode(hydra: Hydra, config_name: str | None, overrides: list[str]) -> Any:
        if not isinstance(hydra.config_loader, CachedComposeLoader):
            wrapped.append((hydra, hydra.config_loader))
            hydra.config_loader = cached(hydra.config_loader)
        return get_mode(hydra, config_name, overrides)

    Hydra.get_mode = caching_get_mode  # type: ignore[method-assign]
    _BASES.clear()
    try:
        yield
    finally:
        _BASES.clear()
        Hydra.get_mode = get_mode  # type: ignore[method-assign]
        for hydra, loader in wrapped:
            hydra.config_loader = loader
