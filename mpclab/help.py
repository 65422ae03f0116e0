"""``python -m mpclab --help``: what there is to run, and the default experiment's config.

Hydra's own help lists every config group, the internal ``schema/*`` entries among them, and
prints the bare defaults (Study A's car without its terminal constraint). This lists what a
user picks from: the experiments with the first line of their description, the choices of
each group, the objective term types (by the ``_target_`` an objective YAML names them with,
and the backends that can express each), then the config of the README's default command.
Hydra's flags stay: ``--hydra-help``, ``--cfg job``, ``--info``.
"""

from __future__ import annotations

import inspect
from pathlib import Path

from omegaconf import OmegaConf

from mpclab.experiment import CONF_DIR, compose
from mpclab.objectives.base import Term
from mpclab.registry import register_all

DEFAULT_EXPERIMENT = "zumo_bug2"
#: config groups a user chooses from, in the order a run is assembled
GROUPS = ("plant", "controller", "objective", "scenario", "supervisor", "sim", "recorder")


def first_line(path: Path) -> str:
    """The first descriptive comment line of a YAML file (not ``# @package``)."""
    for line in path.read_text().splitlines():
        text = line.lstrip("# ").rstrip()
        if line.startswith("#") and text and not text.startswith("@package"):
            return text if len(text) <= 72 else text[:69].rstrip() + "..."
    return ""


def term_types() -> list[tuple[str, list[str]]]:
    """``(_target_, backends)`` of every objective term class."""
    register_all()
    found: dict[str, list[str]] = {}
    todo = list(Term.__subclasses__())
    while todo:
        cls = todo.pop()
        todo += cls.__subclasses__()
        if not cls.__name__.startswith("_") and not inspect.isabstract(cls):
            found[f"{cls.__module__}.{cls.__qualname__}"] = cls.backends()
    return sorted(found.items())


def text() -> str:
    """The whole help text."""
    conf = Path(CONF_DIR)
    out = ["mpclab: declarative MPC experiments (Hydra).",
           "",
           "  python -m mpclab +experiment=NAME [group=choice ...] [key=value ...]",
           "  python -m mpclab -m +experiment=NAME 'seed=range(0,10)' controller=a,b   (a sweep)",
           "",
           "Experiments (+experiment=NAME):"]
    for path in sorted((conf / "experiment").glob("*.yaml")):
        out.append(f"  {path.stem:22s} {first_line(path)}")
    out += ["", "Choices per group (group=choice):"]
    for group in GROUPS:
        names = ", ".join(p.stem for p in sorted((conf / group).glob("*.yaml")))
        out.append(f"  {group:11s} {names}")
    out += ["", "Objective term types (an objective's terms: {NAME: {_target_: TYPE, ...}}):"]
    for target, backends in term_types():
        out.append(f"  {target}  [{', '.join(backends)}]")
    cfg = compose([f"+experiment={DEFAULT_EXPERIMENT}"])
    body = OmegaConf.to_yaml(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]))
    out += ["", f"The default experiment's config (+experiment={DEFAULT_EXPERIMENT}):", "",
            body.rstrip(), "",
            "Hydra: --hydra-help (its flags), --cfg job (this run's config), --info."]
    return "\n".join(out) + "\n"
