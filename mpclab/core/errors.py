"""Input checking that names what was given, what was expected and the valid choices.

:func:`number` is the one check of a numeric option (finite, at or above a bound), and
:func:`whole_number` of a count;
:func:`exit_on_bad_input` ends a tool's command line with that message;
:func:`bad_input_message` turns any error that comes from bad input (mpclab's own
:class:`ConfigError`, Hydra's composition and instantiation errors, OmegaConf's, a YAML
syntax error, a file that cannot be read or written) into one short message, and returns None
for anything else (a bug, which deserves its traceback).
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
from collections.abc import Iterable, Mapping
from enum import Enum
from typing import Any, NoReturn

import yaml
from hydra.errors import CompactHydraException, InstantiationException, MissingConfigException
from omegaconf import DictConfig
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException


class ConfigError(ValueError):
    """A configuration value or key that mpclab cannot use."""


def unknown(kind: str, given: str, valid: Iterable[str], where: str = "") -> ConfigError:
    """An error for ``given`` not being one of ``valid``, with a did-you-mean hint."""
    valid = sorted(valid)
    at = f" in {where}" if where else ""
    return ConfigError(f"unknown {kind} {given!r}{at}.{did_you_mean(given, valid)} "
                       f"Valid {kind}s: {', '.join(valid) or '(none)'}")


def did_you_mean(given: str, valid: Iterable[str]) -> str:
    """`` Did you mean 'x'?`` for the closest of ``valid`` to ``given``; "" if none is."""
    close = difflib.get_close_matches(given, list(valid), n=1)
    return f" Did you mean {close[0]!r}?" if close else ""


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


def number(value: Any, key: str, *, above: float | None = None,
           at_least: float | None = None) -> float:
    """``value`` as a finite float, ``> above`` and ``>= at_least`` when given.

    Raises :class:`ConfigError` naming ``key``, the value and what is valid: a string that
    is not a number (``C1=high``), NaN, infinity or a value out of range.
    """
    want = "a finite number"
    if above is not None:
        want += f" > {above:g}"
    if at_least is not None:
        want += f" >= {at_least:g}"
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}: expected {want}, got {value!r}") from None
    if (not math.isfinite(v) or (above is not None and not v > above)
            or (at_least is not None and not v >= at_least)):
        raise ConfigError(f"{key}: expected {want}, got {value!r}")
    return v


def whole_number(value: Any, key: str, *, at_least: int,
                 also: Mapping[int, str] | None = None) -> int:
    """``value`` as an int ``>= at_least``, or one of the keys of ``also`` (a value with its
    own meaning, e.g. ``{-1: "one worker per core"}``).

    Raises :class:`ConfigError` naming ``key``, the value and what is valid: a string or a
    float that is not a whole number, a bool, or a value out of range.
    """
    want = f"a whole number >= {at_least}" + "".join(
        f", or {k} ({meaning})" for k, meaning in (also or {}).items())
    try:
        f = float(value)
        v = int(f) if not isinstance(value, bool) and math.isfinite(f) and f == int(f) else None
    except (TypeError, ValueError):
        v = None
    if v is None or not (v >= at_least or v in (also or {})):
        raise ConfigError(f"{key}: expected {want}, got {value!r}")
    return v


def exit_on_bad_input(parser: argparse.ArgumentParser, exc: Exception) -> NoReturn:
    """For a tool's command line: ``parser.error`` (usage, one message, exit 2) when ``exc``
    comes from bad input or a path (a file not found, a folder that cannot be written);
    ``exc`` raised again otherwise (a bug keeps its traceback)."""
    message = bad_input_message(exc)
    if message is None and isinstance(exc, OSError):
        message = str(exc)  # a path error mpclab raised itself, with its own message
    if message is None:
        raise exc
    parser.error(message)


def bad_input_message(exc: BaseException) -> str | None:
    """One short message for an error caused by bad input; None for any other error."""
    if isinstance(exc, InstantiationException):
        return _instantiation_message(exc)
    if isinstance(exc, ConfigError):
        return str(exc)
    if isinstance(exc, MissingConfigException) and exc.options:  # an unknown choice
        name = str(exc.missing_cfg_file or "").rsplit("/", 1)[-1]
        close = difflib.get_close_matches(name, list(exc.options), n=1)
        hint = f" Did you mean {close[0]!r}?" if close else ""
        return f"{str(exc).strip().splitlines()[0]}.{hint} Valid: {', '.join(exc.options)}"
    if isinstance(exc, CompactHydraException):  # composition: the key and what is valid
        cause = exc.__cause__
        text = str(exc)
        if isinstance(cause, yaml.YAMLError):
            return yaml_message(cause)
        if (isinstance(cause, ConfigAttributeError | ConfigKeyError) and cause.key is not None
                and isinstance(cause.parent_node, DictConfig)):  # a mistyped existing key
            parent = str(cause.full_key or cause.key).rpartition(".")[0]
            valid = [str(k) for k in cause.parent_node if str(k) != "hydra"]
            head = text.strip().splitlines()[0].rstrip(".")  # Hydra's "Could not override 'K'"
            return f"{head}: {unknown('key', str(cause.key), valid, parent or 'the config')}"
        if isinstance(cause, OmegaConfBaseException) and str(cause) not in text:
            text += "\n" + str(cause)
        return _trim(text)
    if isinstance(exc, OmegaConfBaseException):
        return _trim(str(exc))
    if isinstance(exc, yaml.YAMLError):
        return yaml_message(exc)
    if (isinstance(exc, FileExistsError) and exc.filename is not None
            and os.path.exists(exc.filename) and not os.path.isdir(exc.filename)):
        return f"not a folder (a file is there): {exc.filename}"  # making an output folder
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.strerror or exc}: {exc.filename}"
    return None


def yaml_message(exc: yaml.YAMLError) -> str:
    """A YAML syntax error as ``file, line L, column C: problem``."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc)
    context = getattr(exc, "context", None)
    what = f"{context}: {problem}" if context else problem
    if mark is None:
        return f"YAML syntax error: {what}"
    where = f"{mark.name}, line {mark.line + 1}, column {mark.column + 1}"
    return f"YAML syntax error in {where}: {what}"


def _instantiation_message(exc: InstantiationException) -> str | None:
    """Hydra's wrapper ``Error in call to target ...`` unwrapped to the cause, keyed."""
    text = str(exc)
    full_key = ""
    for line in text.splitlines():
        if line.startswith("full_key:"):
            full_key = line.split(":", 1)[1].strip()
    cause = exc.__cause__
    if cause is None:
        return _trim(text.replace(", set env var HYDRA_FULL_ERROR=1 to see chained exception", ""))
    inner = bad_input_message(cause)
    if isinstance(cause, MemoryError):
        inner = (f"out of memory while building it ({cause}); a smaller problem (e.g. a "
                 "shorter controller.horizon) may fit")
    if inner is None:
        if not isinstance(cause, ValueError | TypeError):
            return None  # a bug in a constructor: its traceback says more than a message
        inner = str(cause) if isinstance(cause, ValueError) else f"{type(cause).__name__}: {cause}"
    if full_key and not inner.startswith((*_TOP_LEVEL_KEYS, full_key)):  # say where, unless it does
        inner = f"{full_key}: {inner}"
    return inner


#: the composed config's top-level keys: a message starting with one already says where
_TOP_LEVEL_KEYS = ("plant", "controller", "objective", "supervisor", "scenario", "recorder",
                   "sim", "seed")


def _trim(text: str) -> str:
    """Drop OmegaConf's ``object_type=`` detail lines; keep the key and the message."""
    keep = [ln.rstrip() for ln in text.strip().splitlines()
            if not ln.strip().startswith(("object_type=", "reference_type="))]
    return "\n".join(keep)
