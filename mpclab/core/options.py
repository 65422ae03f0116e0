"""Option groups: a constructor takes related options as one small dataclass.

A component whose options split into kinds (the problem, how its solver runs, how it is
built, ...) takes each kind as one frozen dataclass, documented field by field in its
``Parameters`` section, instead of a long row of keyword arguments::

    @dataclass(frozen=True)
    class SolveOptions:
        max_iter: int = 100
        tol: float = 1e-6

    class MyMPC(Controller):
        def __init__(self, plant, objective, horizon=10, solve=SolveOptions()): ...
            self.solve = group(SolveOptions, solve, "controller.solve")

In a config the group is a nested node (``controller.solve.max_iter=50``), checked while
Hydra composes: the component's schema derives the node's schema from the dataclass
(:func:`mpclab.config.registry.schema_from_init`). From Python, pass the dataclass, or a
mapping of some of its fields (:func:`group` fills in the rest and names an unknown key).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

from mpclab.core.errors import ConfigError, check_keys

T = TypeVar("T")


def group(cls: type[T], value: T | Mapping[str, Any] | None, key: str) -> T:
    """``value`` as the option group ``cls``: itself, ``cls()`` for None, or ``cls`` with
    the fields a mapping gives (a config's node); :class:`ConfigError` naming ``key`` for
    a key ``cls`` has no field for, or anything else."""
    if isinstance(value, cls):
        return value
    if value is None:
        return cls()
    if not isinstance(value, Mapping):
        raise ConfigError(f"{key}: expected a mapping of {cls.__name__}'s fields, "
                          f"got {value!r}")
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    check_keys(value, names, where=key)
    return cls(**value)
