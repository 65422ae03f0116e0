"""What an objective term and a constraint share: the backends that can express one.

A family (terms, constraints) names, per backend, the method that expresses one of its
members for that backend (:attr:`Expressible.backend_methods`); a member can be expressed
by the backends whose method its class overrides, less those an option of the member rules out
(:meth:`Expressible.accepted_by`). A backend asks :meth:`Expressible.require`, which refuses
with a message naming the member and the backends that accept it. Every
subclass is registered (:func:`mpclab.config.registry.register_target`): a config may name it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from mpclab.config.registry import register_target
from mpclab.core.errors import ConfigError


class Expressible:
    """Base of a family of things a backend expresses (terms, constraints)."""

    #: set from the config key by the objective that holds it
    name: str = ""
    #: backend name -> the method that expresses a member for it (set by the family's base)
    backend_methods: ClassVar[Mapping[str, str]] = {}
    #: what messages call a member ("objective term", "constraint")
    kind: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        register_target(cls)  # a term or constraint class is one a config may build

    @classmethod
    def backends(cls) -> list[str]:
        """Backends that can express this class (those whose method it overrides)."""
        family = next(c for c in cls.__mro__ if "backend_methods" in vars(c))
        return [b for b, m in cls.backend_methods.items()
                if getattr(cls, m) is not getattr(family, m)]

    def accepted_by(self) -> list[str]:
        """Backends that can express this member as configured: its class's
        (:meth:`backends`), unless one of its options rules a backend out."""
        return self.backends()

    def variant(self) -> str:
        """The options that decide :meth:`accepted_by`, as messages name them ("" if none)."""
        return ""

    def require(self, backend: str) -> None:
        """Raise :class:`ConfigError` unless this can be expressed for ``backend``."""
        accepted = self.accepted_by()
        if backend not in accepted:
            what = ", ".join(filter(None, (type(self).__name__, self.variant())))
            raise ConfigError(
                f"{self.kind} {self.name!r} ({what}) cannot be expressed "
                f"by the {backend} backend; backends that accept it: "
                f"{', '.join(accepted) or '(none)'}"
            )
