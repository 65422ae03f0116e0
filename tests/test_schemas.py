"""One source of truth per option: schema, constructor and YAML agree.

A component's schema is derived from its constructor (``registry.schema_from_init``) unless
its options have nested structure the signature does not spell out (scenarios, the sim
world, the objective): then the hand-written schema must name the same options with the
same plain defaults. A YAML in ``conf/<group>/`` sets only what differs from the defaults
it builds on (its schema's, or the YAML it extends), so that a default lives in one place.
"""

from __future__ import annotations

import dataclasses
import enum
import inspect
from pathlib import Path
from typing import Any

import pytest
import yaml
from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

from conftest import CONF
from hydra_plugins.mpclab_launcher.pool_launcher import PoolLauncher
from mpclab.config.registry import COMPONENTS, register_all

register_all()
#: what the run passes in (instantiate.build's dependencies): not options
INJECTED = {"plant", "objective", "scenario", "rng", "seed", "out_dir", "cfg"}
HYDRA_KEYS = {"_target_", "_recursive_"}


def schema(group: str, name: str) -> Any:
    return OmegaConf.to_container(ConfigStore.instance().load(
        f"schema/{group}/{name}.yaml").node, enum_to_str=True)


def options(cls: type, group: str) -> dict[str, Any]:
    params = inspect.signature(cls.__init__).parameters.values()
    skip = INJECTED | ({"dt"} if group == "sim" else set())  # the sim world gets the loop's dt
    return {p.name: p.default for p in params
            if p.name != "self" and p.name not in skip
            and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}


COMPONENT_LIST = [(g, n, c) for g, comps in COMPONENTS.items() if g != "plant"
                  for n, c in comps.items()] + [("hydra/launcher", "pool", PoolLauncher)]


@pytest.mark.parametrize("group, name, cls", COMPONENT_LIST,
                         ids=[f"{g}/{n}" for g, n, _ in COMPONENT_LIST])
def test_schema_names_the_constructors_options_with_its_defaults(group, name, cls) -> None:
    conf = schema(group, name)
    opts = options(cls, group)
    assert set(conf) - HYDRA_KEYS == set(opts), "schema and constructor name other options"
    for key, default in _plain_defaults(opts):
        if default is None and isinstance(_at(conf, key), (dict, list)):
            continue  # None: the constructor's own default structure, spelt in the schema
        assert _at(conf, key) == default, \
            f"{key}: schema {_at(conf, key)!r}, constructor {default!r}"


def _plain_defaults(opts: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """``(dotted key, default)`` of every plain default, an option group's fields included."""
    found = []
    for key, default in opts.items():
        if dataclasses.is_dataclass(default):  # an option group: its fields' defaults
            fields = {f.name: getattr(default, f.name) for f in dataclasses.fields(default)}
            found += _plain_defaults(fields, f"{prefix}{key}.")
            continue
        if isinstance(default, enum.Enum):
            default = default.value
        if isinstance(default, (int, float, str, bool)) or default is None:
            found.append((prefix + key, default))
    return found


def _at(conf: dict[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        conf = conf[part]
    return conf


def _schema_of(doc: dict[str, Any], group: str) -> tuple[str | None, str | None]:
    """(schema name, extended YAML) named by a YAML's defaults list."""
    found, parent = None, None
    for entry in doc.get("defaults", []):
        if isinstance(entry, dict):
            for key, value in entry.items():
                if key.startswith(f"/schema/{group}"):
                    found = value
        elif entry != "_self_":
            parent = entry
    return found, parent


def _defaults(group: str, stem: str) -> dict[str, Any]:
    """What a YAML in conf/<group>/ builds on: its schema's defaults, or the YAML it extends."""
    doc = yaml.safe_load((CONF / group / f"{stem}.yaml").read_text()) or {}
    own = {k: v for k, v in doc.items() if k != "defaults"}
    return OmegaConf.to_container(OmegaConf.merge(_base(doc, group, stem), own))


def _base(doc: dict[str, Any], group: str, stem: str) -> dict[str, Any]:
    """What the YAML ``doc`` builds on, before its own keys."""
    name, parent = _schema_of(doc, group)
    if parent is not None:
        return _defaults(group, parent)
    assert name is not None, f"conf/{group}/{stem}.yaml names no schema"
    return schema(group, name)


YAMLS = [(g, p.stem) for g in ("controller", "supervisor", "recorder", "sim", "scenario")
         for p in sorted((CONF / g).glob("*.yaml"))] + [("hydra/launcher", "local")]


@pytest.mark.parametrize("group, stem", YAMLS, ids=[f"{g}/{s}" for g, s in YAMLS])
def test_a_yaml_sets_only_what_differs_from_what_it_builds_on(group, stem) -> None:
    doc = yaml.safe_load((CONF / group / f"{stem}.yaml").read_text()) or {}
    base = _base(doc, group, stem)
    restated = sorted(k for k, v in doc.items()
                      if k != "defaults" and k in base and base[k] == v)
    assert not restated, f"conf/{group}/{stem}.yaml restates defaults: {restated}"


def test_the_derived_schema_rejects_what_the_constructor_would() -> None:
    from mpclab.core.errors import ConfigError  # noqa: F401  (the bad-input corpus covers messages)
    from mpclab.runner.single_run import compose

    with pytest.raises(Exception, match="horizon"):
        compose(["+experiment=car_cvxpy", "controller.horizon=ten"])
    with pytest.raises(Exception, match="solver"):
        compose(["+experiment=car_cvxpy", "controller.solver=GUROBI"])
    assert Path(CONF).is_dir()
