"""Where the configs live, and the root config schema: the top-level keys every config has.

:data:`CONF_DIR` is the one definition of the config folder: ``conf/`` at the top of the
source tree, which an installed wheel carries as ``mpclab/conf`` (``pyproject.toml``).
Component groups (``plant``, ``controller``, ...) carry their own schemas (see
:mod:`mpclab.config.registry`); here they are typed ``Any`` so that any registered choice fits.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

_PACKAGE = Path(__file__).resolve().parents[1]  # mpclab/
#: the config folder: shipped inside the installed package, else the source tree's
CONF_DIR = _PACKAGE / "conf" if (_PACKAGE / "conf").is_dir() else _PACKAGE.parent / "conf"

#: what ``conf/config.yaml`` composes when no ``+experiment=NAME`` is given
BARE_DEFAULTS = "the bare defaults (Study A's car without its terminal constraint)"


def config_file(path: str | Path) -> Path | None:
    """The file a config option names: an absolute path, or a relative one read from the
    working folder, else from the config folder (files shipped with the configs, such as the
    latency profiles and the net's weights); None where neither has it."""
    file = Path(str(path)).expanduser()
    for candidate in (file,) if file.is_absolute() else (file, CONF_DIR / file):
        if candidate.is_file():
            return candidate
    return None


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
