"""Where a config key came from: the files (and command-line overrides) that set it.

A bad-input message names the key (``scenario.start: unknown state label 'phi'``); when an
experiment reuses another experiment's objective or scenario, the key was merged in from a
file the user never opened. :func:`where_set` finds, among the files of the run's defaults
(the chosen file of the key's group, the files that one extends, the experiment file) and
the command line, those that set the key, so the message can say which to edit.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

#: a dotted key at the start of a message (``scenario.start: ...``), an objective term
#: named as the objective's messages name it, and the labels a message quotes
_PATH = re.compile(r"^([A-Za-z_]\w*(?:\.\w+)+)[: ]")
_TERM = re.compile(r"^objective term '(\w+)'")
_QUOTED = re.compile(r"'([A-Za-z_]\w*)'")
#: ``PATH: KEY: ...``: a component's message about its own option, keyed by where it was built
_OPTION = re.compile(r"^[A-Za-z_][\w.]*: ([A-Za-z_][\w.]*): ")


@dataclass(frozen=True)
class RunOrigin:
    """What Hydra chose for one run: its group choices, its command-line overrides and the
    config folders it searched (in Hydra's order: the first that has a file provides it)."""

    choices: dict[str, Any]
    overrides: tuple[str, ...]
    folders: tuple[Path, ...] = ()

    @classmethod
    def from_hydra(cls) -> RunOrigin | None:
        """The Hydra run this process is in (None outside one), read by the task function
        itself: elsewhere Hydra's global config may hold another run."""
        if not HydraConfig.initialized():
            return None
        hc = HydraConfig.get()
        folders = tuple(Path(s.path) for s in hc.runtime.config_sources
                        if s.schema == "file" and s.path)
        return cls(dict(hc.runtime.choices), tuple(hc.overrides.task), folders)


def where_set(cfg: DictConfig, message: str, conf_dir: Path, run: RunOrigin | None) -> str:
    """``" (set in FILE, then ...)"`` for the key ``message`` is about, in the order Hydra
    merged them (the last one's value is the one used), or ``""`` when it cannot be told (no
    run origin, no key path in the message, nothing found)."""
    m, term = _PATH.match(message), _TERM.match(message)
    if (m is None and term is None) or run is None:
        return ""
    path = m.group(1) if m else f"objective.terms.{term.group(1)}"
    option = _OPTION.match(message)
    if option is not None and OmegaConf.select(cfg, f"{path}.{option.group(1)}",
                                                default=None) is not None:
        path = f"{path}.{option.group(1)}"  # the option itself, not its component
    node = OmegaConf.select(cfg, path, default=None)
    labels = set(_QUOTED.findall(message)) - ({term.group(1)} if term else set())
    keys = _keys_named(node, path, labels) if isinstance(node, DictConfig) else []
    folders = run.folders or (conf_dir,)
    found: list[str] = []
    for key in keys or [path]:
        found += [f for f in _files_setting(key, run.choices, folders) if f not in found]
        found += [f"the command line ({line})" for line in run.overrides
                  if _related(setting := line.lstrip("+~").split("=")[0], key)
                  and setting not in run.choices  # a group's choice: its file is named
                  and f"the command line ({line})" not in found]
    return f" (set in {', then '.join(found)})" if found else ""


def _related(a: str, b: str) -> bool:
    """Whether setting dotted key ``a`` sets (part of) ``b``: the same, or one inside the
    other."""
    return a == b or a.startswith(b + ".") or b.startswith(a + ".")


def _keys_named(node: DictConfig, path: str, labels: set[str]) -> list[str]:
    """Dotted keys below ``node`` (at ``path``) whose last part is one of ``labels``."""
    out = []
    for key, child in node.items_ex(resolve=False):
        here = f"{path}.{key}"
        if key in labels:
            out.append(here)
        if isinstance(child, DictConfig):
            out += _keys_named(child, here, labels)
    return out


def _files_setting(key: str, choices: dict[str, Any], folders: tuple[Path, ...]) -> list[str]:
    """The defaults files of this run that set the dotted ``key`` (or a part of it), in the
    order Hydra merges them: the key's group's file (after the files it extends), then the
    experiment's (after the experiments it extends)."""
    group, _, inner = key.partition(".")
    setting = []
    if choices.get(group):
        setting += [(path, inner) for path in _group_chain(folders, group, str(choices[group]))]
    if choices.get("experiment"):
        setting += [(path, key) for path in
                    _group_chain(folders, "experiment", str(choices["experiment"]))]
    return [_shown(path) for path, dotted in setting if _sets(_load(path), dotted)]


def _shown(path: Path) -> str:
    """A file as a user finds it: relative to the working folder when inside it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _find(folders: tuple[Path, ...], group: str, name: str) -> Path | None:
    """The file Hydra takes for ``group/name``: the first config folder that has it."""
    for folder in folders:
        path = folder / group / f"{name}.yaml"
        if path.is_file():
            return path
    return None


def _group_chain(folders: tuple[Path, ...], group: str, name: str) -> list[Path]:
    """A group's file and the files of its group it extends (its defaults list), base first."""
    path = _find(folders, group, name)
    if path is None:
        return []
    chain: list[Path] = []
    for entry in _load(path).get("defaults", []) or []:
        if isinstance(entry, str) and entry != "_self_" and "/" not in entry:
            chain += _group_chain(folders, group, entry)
    return [*chain, path]


def _load(path: Path) -> dict[str, Any]:
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _sets(doc: Any, dotted: str) -> bool:
    """Whether the YAML mapping ``doc`` holds the nested key ``dotted``."""
    for part in dotted.split(".") if dotted else []:
        if not isinstance(doc, dict) or part not in doc:
            return False
        doc = doc[part]
    return bool(dotted)
