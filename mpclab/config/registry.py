"""Structured-config schemas: every config group choice is checked at compose time.

A component registers the dataclass describing its options under ``schema/<group>/<name>``,
derived from its constructor (:func:`schema_from_init`: one field per option, typed and
defaulted as the signature says, the injected dependencies left out), so that an option and
its default are written once; its YAML file in ``conf/<group>/`` sets what differs from the
defaults and lists the schema first in its defaults list::

    defaults:
      - /schema/controller@_here_: cvxpy
      - _self_

so a typo'd key or a wrong type fails while Hydra composes, naming the key.
:func:`register_all` imports every component module, which runs their registrations.

Registering is also what lets a config build a class: :data:`TARGETS` holds every class or
function a ``_target_`` may name (the components, objective terms and constraints by
subclassing, anything else by :func:`register_target`), and :func:`require_registered`
refuses any other. Modules of the user's own components are imported by name from the
config's ``plugins`` list (:func:`import_plugins`), which runs their registrations.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import enum
import importlib
import inspect
import pkgutil
import re
import sys
import types
import typing
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any, Optional, Union

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, OmegaConf

from mpclab.core.errors import ConfigError, did_you_mean

#: packages whose modules register schemas when imported
COMPONENT_PACKAGES = (
    "mpclab.plants",
    "mpclab.constraints",
    "mpclab.controllers",
    "mpclab.objectives",
    "mpclab.supervisors",
    "mpclab.world",
    "mpclab.recorders",
)

#: group -> name -> component class (for the names written into run records)
COMPONENTS: dict[str, dict[str, type]] = {}

#: import path -> the class or function a config's ``_target_`` may name: nothing else is built
TARGETS: dict[str, Any] = {}


def register_target(obj: Any) -> Any:
    """Decorator: let a config build ``obj`` (name it as ``_target_``). Components get this
    from :func:`component`, objective terms and constraints from subclassing their base."""
    TARGETS[target(obj)] = obj
    return obj


def require_registered(name: Any, path: str) -> Any:
    """The registered class or function ``name`` (a ``_target_`` at config key ``path``);
    :class:`ConfigError` naming the key and the target for anything else."""
    found = TARGETS.get(name) if isinstance(name, str) else None
    if found is None:
        raise ConfigError(
            f"{path}._target_: {name!r} is not a registered mpclab component, and a config "
            "builds nothing else. A component of your own is registered by its decorator "
            "and its module listed under plugins (docs/extending.md)."
            + did_you_mean(str(name), TARGETS))
    return found


_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


def check_module_name(name: Any, where: str) -> None:
    """:class:`ConfigError` naming config key ``where`` unless ``name`` is a module name a
    config may have imported: not one of Python's standard library (they register nothing,
    and some act when imported: ``antigravity`` opens a browser)."""
    if not isinstance(name, str) or not _MODULE.fullmatch(name):
        raise ConfigError(f"{where}: expected a module name (my_terms, my_pkg.plants), "
                          f"got {name!r}")
    if name.split(".")[0] in sys.stdlib_module_names:
        raise ConfigError(f"{where}: {name!r} is a module of Python's standard library, not "
                          "one of your components")


def import_plugins(names: Any, key: str = "plugins") -> None:
    """Import the modules of the user's own components, listed by name at config ``key``
    (``plugins: [my_terms]``), which registers them. A module is looked up on Python's path
    (the working folder of ``python -m mpclab``, ``PYTHONPATH``); the standard library's are
    refused (:func:`check_module_name`)."""
    for i, name in enumerate(names or ()):
        where = f"{key}[{i}]"
        check_module_name(name, where)
        if name in sys.modules:
            continue
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name is None or not (name == exc.name or name.startswith(exc.name + ".")):
                raise  # the module is there; something it imports is not: its traceback
            raise ConfigError(f"{where}: no module {name!r} on Python's path (run from the "
                              f"folder that holds it, or add that folder to PYTHONPATH)"
                              ) from None


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
        register_target(component)


def component(
    group: str, name: str, schema: type | None = None, *, injected: Collection[str] = (),
    open_keys: tuple[str, ...] = (), hydra_keys: Mapping[str, Any] | None = None,
) -> Any:
    """Class decorator: register the decorated component's schema.

    ``schema`` None (the rule): derived from the constructor by :func:`schema_from_init`,
    ``injected`` naming the parameters the run passes in (plant, objective, ...) and
    ``hydra_keys`` Hydra's own keys to add (``{"_recursive_": False}``). A hand-written
    ``schema`` is for options with nested structure the signature does not spell out;
    ``tests/test_schemas.py`` checks it against the constructor.
    """

    def deco(cls: type) -> type:
        cls.registered_name = name  # type: ignore[attr-defined]
        conf = schema or schema_from_init(cls, injected, hydra_keys or {})
        # free-form options (a solver's own, dict[str, Any]) take new keys without Hydra's +
        free = free_keys(conf)
        register_schema(group, name, conf, cls, (*open_keys, *free) if schema is None
                        else open_keys)
        return cls

    return deco


def schema_from_init(
    cls: type, injected: Collection[str] = (), hydra_keys: Mapping[str, Any] | None = None,
) -> type:
    """A dataclass ``<Class>Conf`` with ``_target_`` and one field per option of
    ``cls.__init__``: the annotation made one OmegaConf checks (``Enum | str`` -> the enum,
    ``Mapping[str, float] | None`` -> ``dict[str, float]``, ``Sequence[x]`` -> ``list[x]``),
    the default as given (an empty or absent mapping or sequence -> an empty one; no default
    -> ``???``, required)."""
    hints = typing.get_type_hints(cls.__init__)
    fields: list[tuple[str, Any, Any]] = [
        ("_target_", str, dataclasses.field(default=target(cls)))]
    for key, value in (hydra_keys or {}).items():
        fields.append((key, type(value), dataclasses.field(default=value)))
    for p in inspect.signature(cls.__init__).parameters.values():
        if p.name == "self" or p.name in injected or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        typ = _conf_type(hints.get(p.name, Any))
        fields.append((p.name, *_conf_field(typ, p.default)))
    schema = dataclasses.make_dataclass(f"{cls.__name__}Conf", fields)
    # importable by name, so that configs holding it pickle (sweep workers copy them); a
    # module not in sys.modules while it runs (Hydra's plugin scan) binds the name itself
    schema.__module__ = cls.__module__
    if cls.__module__ in sys.modules:
        setattr(sys.modules[cls.__module__], schema.__name__, schema)
    return schema


def free_keys(conf: type, prefix: str = "") -> tuple[str, ...]:
    """Dotted paths of the free-form options (``dict[str, Any]``) of schema ``conf``, its
    option groups' included."""
    found: list[str] = []
    for f in dataclasses.fields(conf):
        if f.type == dict[str, Any]:
            found.append(prefix + f.name)
        elif isinstance(f.type, type) and dataclasses.is_dataclass(f.type):
            found += free_keys(f.type, f"{prefix}{f.name}.")
    return tuple(found)


_GROUP_SCHEMAS: dict[type, type] = {}


def group_schema(cls: type) -> type:
    """The schema of the option group ``cls`` (:mod:`mpclab.core.options`): a dataclass
    ``<Group>Conf`` with one field per field of ``cls``, typed and defaulted as
    :func:`schema_from_init` types a constructor's options."""
    if cls in _GROUP_SCHEMAS:
        return _GROUP_SCHEMAS[cls]
    hints = typing.get_type_hints(cls)
    fields = []
    for f in dataclasses.fields(cls):
        default: Any = f.default
        if default is dataclasses.MISSING:
            default = (inspect.Parameter.empty if f.default_factory is dataclasses.MISSING
                       else f.default_factory())
        typ = _conf_type(hints.get(f.name, Any))
        fields.append((f.name, *_conf_field(typ, default)))
    schema = dataclasses.make_dataclass(f"{cls.__name__}Conf", fields)
    schema.__module__ = cls.__module__
    if cls.__module__ in sys.modules:
        setattr(sys.modules[cls.__module__], schema.__name__, schema)
    _GROUP_SCHEMAS[cls] = schema
    return schema


def _group_default(schema: type, value: Any) -> Any:
    """The schema instance of an option group's default ``value`` (a group instance): its
    fields as the schema holds them (None for a mapping or a list: an empty one)."""
    given = {}
    for f in dataclasses.fields(schema):
        v = getattr(value, f.name)
        origin = typing.get_origin(f.type)
        if v is None and origin in (dict, list):
            v = origin()
        given[f.name] = _plain(v)
    return schema(**given)


def _plain(value: Any) -> Any:
    """A group field's default as the schema holds it (tuples as lists, paths as text)."""
    if isinstance(value, Path):
        return str(value)
    return _copy(value)


_MAPPINGS = (collections.abc.Mapping, collections.abc.MutableMapping, dict)
_SEQUENCES = (collections.abc.Sequence, collections.abc.MutableSequence, list, tuple)
_PLAIN = (int, float, str, bool)


def _conf_type(t: Any) -> Any:
    """The type OmegaConf checks for a constructor's annotation ``t``."""
    origin, args = typing.get_origin(t), typing.get_args(t)
    if origin in (Union, types.UnionType):
        kinds = [a for a in args if a is not type(None)]
        groups = [a for a in kinds if isinstance(a, type) and dataclasses.is_dataclass(a)]
        if groups:  # an option group, or a mapping of its fields
            return group_schema(groups[0])
        enums = [a for a in kinds if isinstance(a, type) and issubclass(a, enum.Enum)]
        base = enums[0] if enums else (_conf_type(kinds[0]) if len(kinds) == 1 else Any)
        if type(None) in args and typing.get_origin(base) not in (dict, list):
            return Optional[base]  # noqa: UP045  (a typing object OmegaConf reads)
        return base
    if origin in _MAPPINGS:
        return dict[_conf_type(args[0]), _conf_type(args[1])] if args else dict[str, Any]
    if origin in _SEQUENCES:
        return list[_conf_type(args[0])] if args else list[Any]
    if t is Path:
        return str
    if isinstance(t, type) and dataclasses.is_dataclass(t):
        return group_schema(t)
    if t in _PLAIN or (isinstance(t, type) and issubclass(t, enum.Enum)):
        return t
    return Any


def _conf_field(typ: Any, default: Any) -> tuple[Any, Any]:
    """``(type, dataclass field)`` for an option of type ``typ`` with ``default``."""
    container = typing.get_origin(typ) in (dict, list)
    if default is inspect.Parameter.empty:
        return typ, dataclasses.field(default=MISSING)
    if isinstance(typ, type) and dataclasses.is_dataclass(typ):  # an option group
        given = default
        return typ, dataclasses.field(
            default_factory=lambda: typ() if given is None else _group_default(typ, given))
    if container:
        empty = dict if typing.get_origin(typ) is dict else list
        value = empty() if default is None else empty(default)
        return typ, dataclasses.field(default_factory=lambda: _copy(value))
    if isinstance(default, Path):
        default = str(default)
    return typ, dataclasses.field(default=default)


def _copy(value: Any) -> Any:
    """A fresh copy of a default container (each config gets its own)."""
    if isinstance(value, Mapping):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_copy(v) for v in value]
    return value


def target(cls: Any) -> str:
    """The import path Hydra instantiates ``cls`` (a class or function) from."""
    return f"{cls.__module__}.{cls.__qualname__}"


_done = False


def register_all() -> None:
    """Import every component module so that all schemas are in the ConfigStore."""
    global _done
    if _done:
        return
    from mpclab.config import root  # noqa: F401  (root schema)

    for pkg_name in COMPONENT_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=pkg_name + "."):
            importlib.import_module(info.name)
    _done = True
