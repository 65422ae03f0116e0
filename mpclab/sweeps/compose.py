"""A sweep's job configs: jobs that differ only in values share one tree composed by Hydra.

Hydra composes every job of a multirun from scratch (0.2-0.35 s for a Zumo job: every YAML
file and schema of its defaults tree read and merged), although a sweep over seeds or
weights composes the same tree again and again. Hydra's own rule splits a job's overrides in
two: *structural* ones choose the tree (a config group, ``scenario=zumo_random``,
``+experiment=zumo_bug2``, ``~sim``, ``group@pkg=choice``; and here every ``hydra.*``
override, since ``hydra.searchpath`` and ``hydra.job.env_copy`` act while composing), and
*value* ones (``seed=3``, ``+controller.foo=1``, ``~seed``, a dict value) are applied to the
composed config afterwards. :class:`JobComposer` composes each distinct list of structural
overrides once, through the config loader's public ``load_sweep_config`` (Hydra's own
composition, search path included), applies a job's value overrides to a copy as Hydra does
(the same rules and messages) and fills in the three fields Hydra derives from a job's
overrides. ``tests/test_hydra_routes.py`` checks every job config against Hydra's own path.

Which keys are config groups is asked of the loader (``get_group_options``) with the
job's ``hydra.*`` overrides, so that a group that exists only in a folder added by
``hydra.searchpath`` counts as one.
"""

from __future__ import annotations

import copy
import functools
import importlib
import io
import pickle
import re
from collections import OrderedDict
from collections.abc import Sequence
from textwrap import dedent
from typing import Any

from hydra.core.config_loader import ConfigLoader
from hydra.core.object_type import ObjectType
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import ConfigCompositionException
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

#: composed trees kept per composer, most recent last
MAX_TREES = 64


@functools.lru_cache(maxsize=4096)
def parse(line: str) -> Override:
    """One override line parsed (a sweep repeats most lines from job to job)."""
    return OverridesParser.create().parse_overrides(overrides=[line])[0]


class JobComposer:
    """The configs of a sweep's jobs, each as Hydra's ``load_sweep_config`` composes it.

    Parameters
    ----------
    loader
        The sweep's config loader (``HydraContext.config_loader``).
    master
        The sweep's config (its ``hydra.overrides.hydra`` and config name; its resolver
        cache, so that ``${now:...}`` resolves alike in every job).
    """

    def __init__(self, loader: ConfigLoader, master: DictConfig) -> None:
        self.loader = loader
        self.master = master
        self._trees: OrderedDict[tuple[str, ...], bytes | DictConfig] = OrderedDict()
        self._groups: dict[tuple[str, tuple[str, ...]], frozenset[str]] = {}

    def prime(self, jobs: Sequence[Sequence[str]]) -> None:
        """Compose the tree of each job's structural overrides (each distinct one once, up to
        :data:`MAX_TREES`), so that processes forked afterwards inherit them. If no job's
        tree composes, raise the first job's error: nothing of the sweep could run."""
        first: Exception | None = None
        composed = 0
        seen: set[tuple[str, ...]] = set()
        for job in jobs:
            try:
                structural = self._split(job)[0]
                if structural in seen:
                    continue
                seen.add(structural)
                self._tree(structural)
            except Exception as exc:  # noqa: BLE001  (raised again by that job's job_config)
                first = first or exc
            else:
                composed += 1
                if composed >= MAX_TREES:
                    return
        if first is not None and composed == 0:
            raise first

    def job_config(self, overrides: Sequence[str]) -> DictConfig:
        """The config of the job with these overrides (``hydra`` node included)."""
        structural, values, parsed = self._split(overrides)
        cfg = _thawed(self._tree(structural))
        apply_value_overrides(cfg, values)
        app = [o for o in parsed if not o.is_hydra_override()]
        with open_dict(cfg.hydra):
            cfg.hydra.overrides.task = [o.input_line for o in app]
            conf = cfg.hydra.job.config.override_dirname
            cfg.hydra.job.override_dirname = override_dirname(
                app, list(conf.exclude_keys), conf.item_sep, conf.kv_sep)
        return cfg

    def _split(self, overrides: Sequence[str]
               ) -> tuple[tuple[str, ...], list[Override], list[Override]]:
        """(the structural lines, the value overrides, all of them parsed)."""
        parsed = [parse(line) for line in overrides]
        hydra = tuple(o.input_line for o in parsed if o.is_hydra_override())
        structural, values = hydra, []
        for o in parsed:
            if o.is_hydra_override():
                continue
            if self._is_group(o, hydra):
                structural += (o.input_line,)
            else:
                values.append(o)
        return structural, values, parsed

    def _tree(self, structural: tuple[str, ...]) -> bytes | DictConfig:
        tree = self._trees.get(structural)
        if tree is None:
            tree = _frozen(self.loader.load_sweep_config(self.master, list(structural)))
            self._trees[structural] = tree
            while len(self._trees) > MAX_TREES:
                self._trees.popitem(last=False)
        else:
            self._trees.move_to_end(structural)
        return tree

    def _is_group(self, override: Override, hydra_lines: tuple[str, ...]) -> bool:
        """Hydra's rule: a config-group override names a group and has no dict value."""
        if isinstance(override.value(), dict):
            return False
        parent, _, name = override.key_or_group.rpartition("/")
        return name in self._groups_in(parent, hydra_lines)

    def _groups_in(self, parent: str, hydra_lines: tuple[str, ...]) -> frozenset[str]:
        """The config groups in group ``parent`` ("" for the top), asked of the loader once
        per search path (a job's ``hydra.*`` overrides may move it)."""
        key = (parent, hydra_lines)
        found = self._groups.get(key)
        if found is None:
            hydra = [*OmegaConf.to_container(self.master.hydra.overrides.hydra), *hydra_lines]
            found = frozenset(self.loader.get_group_options(
                parent, results_filter=ObjectType.GROUP,
                config_name=self.master.hydra.job.config_name, overrides=hydra))
            self._groups[key] = found
        return found


class _ByName(pickle.Pickler):
    """Pickles a class by its module and name even where that name now holds an equal class
    (Hydra's plugin scan imports the plugins' modules, and so their schema classes, again)."""

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


def _frozen(cfg: DictConfig) -> bytes | DictConfig:
    """``cfg`` pickled, to load fresh copies from (a third of a deep copy's time), or
    ``cfg`` itself where it does not pickle."""
    buf = io.BytesIO()
    try:
        _ByName(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(cfg)
    except (pickle.PicklingError, TypeError, AttributeError):
        return cfg
    return buf.getvalue()


def _thawed(tree: bytes | DictConfig) -> DictConfig:
    """A fresh copy of a kept tree."""
    return pickle.loads(tree) if isinstance(tree, bytes) else copy.deepcopy(tree)


def apply_value_overrides(cfg: DictConfig, overrides: Sequence[Override]) -> None:
    """Apply value overrides to ``cfg`` as Hydra applies them after composing: ``key=v``
    changes an existing key, ``+key=v`` adds one, ``++key=v`` adds or changes, ``~key[=v]``
    deletes; a refused override raises Hydra's :class:`ConfigCompositionException` with
    Hydra's message."""
    for override in overrides:
        line = override.input_line
        if override.package is not None:
            raise ConfigCompositionException(
                f"Override {line} looks like a config group override, but config group "
                f"'{override.key_or_group}' does not exist.")
        key, value = override.key_or_group, override.value()
        try:
            if override.is_delete():
                _delete(cfg, key, value)
            elif override.is_add():
                if (OmegaConf.select(cfg, key, throw_on_missing=False) is not None
                        and not isinstance(value, dict | list)):
                    raise ConfigCompositionException(dedent(f"""\
                        Could not append to config. An item is already at '{key}'.
                        Either remove + prefix: '{line[1:]}'
                        Or add a second + to add or override '{key}': '+{line}'
                        """))
                OmegaConf.update(cfg, key, value, merge=True, force_add=True)
            elif override.is_force_add():
                OmegaConf.update(cfg, key, value, merge=True, force_add=True)
            else:
                try:
                    OmegaConf.update(cfg, key, value, merge=True)
                except (ConfigAttributeError, ConfigKeyError) as exc:
                    raise ConfigCompositionException(
                        f"Could not override '{key}'.\nTo append to your config use +{line}"
                    ) from exc
        except OmegaConfBaseException as exc:
            raise ConfigCompositionException(f"Error merging override {line}") from exc


def _delete(cfg: DictConfig, key: str, value: Any) -> None:
    found = OmegaConf.select(cfg, key, throw_on_missing=False)
    if found is None:
        raise ConfigCompositionException(
            f"Could not delete from config. '{key}' does not exist.")
    if value is not None and value != found:
        raise ConfigCompositionException(
            f"Could not delete from config. The value of '{key}' is {found} and not {value}.")
    parent, _, leaf = key.rpartition(".")
    with open_dict(cfg):
        del (OmegaConf.select(cfg, parent) if parent else cfg)[leaf]


def override_dirname(overrides: Sequence[Override], exclude_keys: Sequence[str],
                     item_sep: str, kv_sep: str) -> str:
    """``hydra.job.override_dirname``: the overrides' lines but the excluded keys, sorted,
    joined by ``item_sep``, with ``=`` written as ``kv_sep``."""
    lines = sorted(o.input_line for o in overrides if o.key_or_group not in exclude_keys)
    return re.sub("[=]", kv_sep, item_sep.join(lines))
