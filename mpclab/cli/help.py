"""``python -m mpclab [ARGS...] --help``: what there is to run, and the config ARGS make.

Hydra's own help lists every config group, the internal ``schema/*`` entries among them, and
prints the bare defaults (Study A's car without its terminal constraint). This lists what a
user picks from: the experiments (mpclab's and those in folders added with ``-cd``) with the
first line of their description, the choices of each group, the objective term and
constraint types (by the ``_target_`` an objective YAML names them with, and the backends
that can express each), the
chosen controller's options with their one-line meaning (from its constructor's docstring),
then the config the rest of the command line composes (what a bare run composes when it names
no experiment). Hydra's flags stay: ``--hydra-help``, ``--cfg job``, ``--info``.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import typing
from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from mpclab.config.expressible import Expressible
from mpclab.config.registry import TARGETS, register_all
from mpclab.config.root import BARE_DEFAULTS
from mpclab.constraints.base import Constraint
from mpclab.objectives.base import Term
from mpclab.runner.single_run import CONF_DIR, compose

#: config groups a user chooses from, in the order a run is assembled
GROUPS = ("plant", "controller", "objective", "scenario", "supervisor", "sim", "recorder")


def first_line(path: Path) -> str:
    """The first descriptive comment line of a YAML file (not ``# @package``)."""
    for line in path.read_text().splitlines():
        text = line.lstrip("# ").rstrip()
        if line.startswith("#") and text and not text.startswith("@package"):
            return text if len(text) <= 72 else text[:69].rstrip() + "..."
    return ""


def expressible_types(family: type[Expressible] = Term) -> list[tuple[str, list[str]]]:
    """``(_target_, backends)`` of every class of ``family`` (objective terms, or
    constraints)."""
    register_all()
    found: dict[str, list[str]] = {}
    todo = list(family.__subclasses__())
    while todo:
        cls = todo.pop()
        todo += cls.__subclasses__()
        if not cls.__name__.startswith("_") and not inspect.isabstract(cls):
            found[f"{cls.__module__}.{cls.__qualname__}"] = cls.backends()
    return sorted(found.items())


def options(cls: type) -> list[tuple[str, str]]:
    """``(name, its meaning's first sentence)`` of each parameter of a numpydoc docstring."""
    doc = inspect.getdoc(cls) or ""
    m = re.search(r"^Parameters\n-+\n(.*?)(?:\n\n[A-Z][a-z]+\n-+|\Z)", doc, re.S | re.M)
    if m is None:
        return []
    found: list[tuple[str, list[str]]] = []
    for line in m.group(1).splitlines():
        if line and not line.startswith(" "):
            found.append((line.split(":")[0].strip(), []))
        elif found and line.strip():
            found[-1][1].append(line.strip())
    rows = []
    for name, words in found:
        group = option_group(cls, name)
        if group is None:
            rows.append((name, _first_sentence(" ".join(words))))
        else:  # an option group: its fields, each as group.field
            rows += [(f"{name}.{field}", meaning) for field, meaning in options(group)]
    return rows


def option_group(cls: type, name: str) -> type | None:
    """The option group (:mod:`mpclab.core.options`) ``cls.__init__`` takes as ``name``,
    else None."""
    try:
        hint = typing.get_type_hints(cls.__init__).get(name)
    except (NameError, TypeError):
        return None
    kinds = typing.get_args(hint) or (hint,)
    return next((k for k in kinds if isinstance(k, type) and dataclasses.is_dataclass(k)), None)


def _first_sentence(text: str, width: int = 76) -> str:
    sentence = re.split(r"(?<=[^.]\.)\s(?=[A-Z`(])", text, maxsplit=1)[0]
    return sentence if len(sentence) <= width else sentence[:width - 3].rstrip() + "..."


def split_args(args: Sequence[str]) -> tuple[list[str], list[Path]]:
    """``(overrides, folders added with -cd/--config-dir)`` of a command line."""
    overrides, folders = [], []
    it = iter(args)
    for arg in it:
        if arg in ("-cd", "--config-dir"):
            folders.append(Path(next(it, ".")).expanduser())
        elif arg.startswith("--config-dir="):
            folders.append(Path(arg.split("=", 1)[1]).expanduser())
        elif not arg.startswith("-"):
            overrides.append(arg)
    return overrides, folders


def text(args: Sequence[str] = ()) -> str:
    """The whole help text for the command line ``args`` (``--help`` itself ignored)."""
    overrides, folders = split_args(args)
    confs = [Path(CONF_DIR), *folders]
    out = ["mpclab: declarative MPC experiments (Hydra).",
           "",
           "  python -m mpclab +experiment=NAME [group=choice ...] [key=value ...]",
           "  python -m mpclab -m +experiment=NAME 'seed=range(0,10)' controller=a,b   (a sweep)",
           "  python -m mpclab -cd MY_FOLDER +experiment=MINE      (experiments of your own)",
           "",
           "Experiments (+experiment=NAME):"]
    for conf in confs:
        if conf != Path(CONF_DIR):
            out.append(f"  in {conf}:")
        for path in sorted((conf / "experiment").glob("*.yaml")):
            out.append(f"  {path.stem:22s} {first_line(path)}")
    out += ["", "Choices per group (group=choice):"]
    for group in GROUPS:
        names = sorted({p.stem for conf in confs for p in (conf / group).glob("*.yaml")})
        out.append(f"  {group:11s} {', '.join(names)}")
    out += ["", "Objective term types (an objective's terms: {NAME: {_target_: TYPE, ...}}):"]
    for target, backends in expressible_types():
        out.append(f"  {target}  [{', '.join(backends)}]")
    out += ["", "Constraint types (an objective's constraints: {NAME: {_target_: TYPE, ...}};",
            "an option may rule a backend out, which the run then names):"]
    for target, backends in expressible_types(Constraint):
        out.append(f"  {target}  [{', '.join(backends)}]")
    what = f"The config of: {' '.join(overrides)}"
    if not any(o.lstrip("+").startswith("experiment=") for o in overrides):
        what = (f"Without +experiment=NAME a run composes {BARE_DEFAULTS}"
                + (f", with {' '.join(overrides)}" if overrides else "") + ":")
    cfg = compose(overrides, config_dir=folders[0] if folders else None)
    out += ["", *_controller_options(cfg)]
    body = OmegaConf.to_yaml(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]))
    out += ["", what, "", body.rstrip(), "",
            "Hydra: --hydra-help (its flags), --cfg job (this run's config), --info."]
    return "\n".join(out) + "\n"


def _controller_options(cfg: DictConfig) -> list[str]:
    """The composed controller's options with their meaning (``controller.KEY=...``)."""
    cls = TARGETS.get(str(OmegaConf.select(cfg, "controller._target_")))
    if not isinstance(cls, type):  # not a registered class: nothing to list
        return []
    injected = {"plant", "objective", "scenario"}
    rows = [(n, m) for n, m in options(cls) if not injected & {p.strip() for p in n.split(",")}]
    lines = [f"Options of controller {cfg.controller._target_} (controller.KEY=VALUE):"]
    return lines + [f"  {name:20s} {meaning}" for name, meaning in rows]
