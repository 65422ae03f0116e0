"""The one ``instantiate`` helper: config node -> object, with options checked first.

Hydra's ``instantiate`` reports an unknown keyword only as a ``TypeError`` from deep inside
the call. :func:`build` walks the node first and, for every ``_target_`` in it, checks that
the target is registered (:func:`mpclab.config.registry.require_registered`: a config builds
mpclab's components and nothing else) and compares the given keys with the target's signature, so a
typo names the key, its path and the valid ones.
"""

from __future__ import annotations

import functools
import inspect
from typing import Any

from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf

from mpclab.config.registry import require_registered
from mpclab.core.errors import ConfigError, bad_input_message, check_keys

_HYDRA_KEYS = {"_target_", "_convert_", "_recursive_", "_partial_", "_args_"}


def check_targets(node: Any, path: str, deps: tuple[str, ...] = ()) -> None:
    """Raise :class:`ConfigError` if any ``_target_`` below ``node`` is not registered or
    gets unknown options."""
    if isinstance(node, DictConfig):
        if "_target_" in node.keys():  # not ``in node``: a struct node raises inside for a
            _check_one(node, path, deps)  # missing key, and most nodes have no target
        for key, child in node.items_ex(resolve=False):
            check_targets(child, f"{path}.{key}" if path else str(key))
    elif isinstance(node, ListConfig):
        for i, child in enumerate(node):
            check_targets(child, f"{path}[{i}]")


def _check_one(node: DictConfig, path: str, deps: tuple[str, ...]) -> None:
    target = node["_target_"]
    names, any_keyword = _options_of(require_registered(target, path))
    if any_keyword:
        return
    valid = [n for n in names if n not in deps]
    given = {k: None for k in node if k not in _HYDRA_KEYS}
    check_keys(given, valid, where=f"{path} ({target})")


@functools.lru_cache(maxsize=512)
def _options_of(obj: Any) -> tuple[tuple[str, ...], bool]:
    """The parameter names of ``obj``'s signature and whether it takes ``**kwargs``
    (found once per process: a sweep builds the same targets job after job)."""
    params = inspect.signature(obj).parameters.values()
    return tuple(p.name for p in params), any(p.kind is p.VAR_KEYWORD for p in params)


def build(node: DictConfig, path: str, **deps: Any) -> Any:
    """Instantiate ``node`` after checking every option name.

    ``deps`` are the objects the caller can inject (plant, objective, rng, ...); each is passed
    only if the target's signature takes it, so a component asks for what it needs by naming
    it as a parameter.
    """
    if node is None or (isinstance(node, DictConfig) and "_target_" not in node):
        raise ConfigError(f"{path}: no _target_ to instantiate; got {OmegaConf.to_yaml(node)!r}")
    check_targets(node, path, tuple(deps))
    target = require_registered(node["_target_"], path)
    params, _ = _options_of(target)
    deps = {k: v for k, v in deps.items() if k in params}
    try:
        if _is_flat(node):
            return _call(target, node, deps)
        return instantiate(node, _convert_="all", **deps)
    except InstantiationException as exc:
        # the cause, keyed by where it happened, not Hydra's wrapper; a bug keeps its traceback
        message = bad_input_message(exc)
        if message is None:
            raise
        raise ConfigError(message) from exc


def _is_flat(node: DictConfig) -> bool:
    """True if ``node``'s only Hydra key is its own ``_target_``: no nested target, no
    ``_args_``, ``_partial_``, ``_convert_`` or ``_recursive_`` anywhere below."""

    def flat(child: Any, top: bool) -> bool:
        if isinstance(child, DictConfig):
            keys = set(child.keys())
            if keys & (_HYDRA_KEYS - ({"_target_"} if top else set())):
                return False
            return all(flat(v, False) for _, v in child.items_ex(resolve=False))
        if isinstance(child, ListConfig):
            return all(flat(v, False) for v in child)
        return True

    return flat(node, True)


def _call(target: Any, node: DictConfig, deps: dict[str, Any]) -> Any:
    """What Hydra's ``instantiate(node, _convert_="all", **deps)`` does for a flat node,
    without its copy of the node and merge of ``deps`` into it (most of a warm sweep job's
    build time): the options as plain Python values, the dependencies as they are, and an
    error in the call wrapped as Hydra wraps it."""
    options = OmegaConf.to_container(node, resolve=True, throw_on_missing=True)
    assert isinstance(options, dict)
    options.pop("_target_")
    try:
        return target(**options, **deps)
    except Exception as exc:
        raise InstantiationException(
            f"Error in call to target '{node['_target_']}':\n{exc!r}") from exc
