"""Where the configs live, and the root config schema: the top-level keys every config has.

:data:`CONF_DIR` is the one definition of the config folder: ``conf/`` at the top of the
source tree, which an installed wheel carries as ``mpclab/conf`` (``pyproject.toml``).
Component groups (``plant``, ``controller``, ...) carry their own schemas (see
:mod:`mpclab.registry`); here they are typed ``Any`` so that any registered choice fits.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

_PACKAGE = Path(__file__).resolve().parent
#: the config folder: shipped inside the installed package, else the source tree's
CONF_DIR = _PACKAGE / "conf" if (_PACKAGE / "conf").is_dir() else _PACKAGE.parent / "conf"


@dataclass
class FiguresConf:
    enabled: bool = True
    dpi: int = 110


@dataclass
class Config:
    name: str = "run"          # experiment name: run records and output folders carry it
    seed: int = 0              # every random draw of a run derives from it
    progress: bool = True      # a progress line for interactive runs
    resume: bool = True        # a multirun skips jobs whose run record is complete
    figures: FiguresConf = field(default_factory=FiguresConf)
    plant: Any = MISSING
    controller: Any = MISSING
    objective: Any = MISSING
    supervisor: Any = MISSING
    scenario: Any = MISSING
    sim: Any = MISSING
    recorder: Any = MISSING
    safety_filter: Any = None  # a filter of the applied input: +safety_filter=cbf
    # modules of your own components, imported by name (docs/extending.md): [my_terms]
    plugins: list[str] = field(default_factory=list)


ConfigStore.instance().store(name="config_schema", node=Config)
