"""Structured-config schemas: every config group choice is checked at compose time.

A component registers the dataclass describing its options under ``schema/<group>/<name>``;
its YAML file in ``conf/<group>/`` lists that schema first in its defaults list::

    defaults:
      - /schema/controller@_here_: cvxpy
      - _self_

so a typo'd key or a wrong type fails while Hydra composes, naming the key.
:func:`register_all` imports every component module, which runs their registrations.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

#: packages whose modules register schemas when imported
COMPONENT_PACKAGES = (
    "mpclab.plants",
    "mpclab.controllers",
    "mpclab.objectives",
    "mpclab.supervisors",
    "mpclab.world",
    "mpclab.recording",
)

#: group -> name -> component class (for the names written into run records)
COMPONENTS: dict[str, dict[str, type]] = {}


def register_schema(
    group: str, name: str, schema: type, component: type | None = None,
    open_keys: tuple[str, ...] = (),
) -> None:
    """Store ``schema`` (a dataclass) as ``schema/<group>/<name>`` in Hydra's ConfigStore.

    ``open_keys``: dotted paths of the schema's dicts that take new keys from the command
    line without Hydra's ``+`` (``sim.plant_params.r=0.021``); their values keep their type.
    """
    if not dataclasses.is_dataclass(schema):
        raise TypeError(f"schema for {group}/{name} must be a dataclass, got {schema!r}")
    node: Any = schema
    if open_keys:
        node = OmegaConf.structured(schema)
        for path in open_keys:
            OmegaConf.set_struct(OmegaConf.select(node, path), False)
    ConfigStore.instance().store(group=f"schema/{group}", name=name, node=node)
    if component is not None:
        COMPONENTS.setdefault(group, {})[name] = component


def component(group: str, name: str, schema: type, open_keys: tuple[str, ...] = ()) -> Any:
    """Class decorator: register ``schema`` for the decorated component class."""

    def deco(cls: type) -> type:
        cls.registered_name = name  # type: ignore[attr-defined]
        register_schema(group, name, schema, cls, open_keys)
        return cls

    return deco


def target(cls: type) -> str:
    """The import path Hydra instantiates ``cls`` from."""
    return f"{cls.__module__}.{cls.__qualname__}"


_done = False


def register_all() -> None:
    """Import every component module so that all schemas are in the ConfigStore."""
    global _done
    if _done:
        return
    from mpclab import config  # noqa: F401  (root schema)

    for pkg_name in COMPONENT_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=pkg_name + "."):
            importlib.import_module(info.name)
    _done = True
