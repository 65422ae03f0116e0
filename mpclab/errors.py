"""Input checking that names what was given, what was expected and the valid choices."""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from enum import Enum
from typing import Any


class ConfigError(ValueError):
    """A configuration value or key that mpclab cannot use."""


def unknown(kind: str, given: str, valid: Iterable[str], where: str = "") -> ConfigError:
    """An error for ``given`` not being one of ``valid``, with a did-you-mean hint."""
    valid = sorted(valid)
    close = difflib.get_close_matches(given, valid, n=1)
    hint = f" Did you mean {close[0]!r}?" if close else ""
    at = f" in {where}" if where else ""
    return ConfigError(
        f"unknown {kind} {given!r}{at}.{hint} Valid {kind}s: {', '.join(valid) or '(none)'}"
    )


def check_keys(given: Mapping[str, Any], valid: Iterable[str], where: str) -> None:
    """Raise :class:`ConfigError` for the first key of ``given`` not in ``valid``."""
    valid = list(valid)
    for key in given:
        if key not in valid:
            raise unknown("key", str(key), valid, where)


def parse_choice(cls: type[Enum], value: Any, key: str) -> Any:
    """``value`` as a member of the enum ``cls``; a :class:`ConfigError` naming ``key``, the
    value and the valid choices otherwise."""
    try:
        return cls(value.value if isinstance(value, Enum) else value)
    except ValueError:
        valid = ", ".join(str(m.value) for m in cls)
        raise ConfigError(f"{key}: unknown choice {value!r}; valid: {valid}") from None
