"""Check the config a command line composes before Hydra acts on any of it.

Hydra acts on parts of a composed config before mpclab's task function sees it: it
configures logging from ``hydra.hydra_logging`` (Python's ``dictConfig`` calls the factories
it names), instantiates every ``hydra.callbacks`` entry and, in a multirun, the sweeper and
the launcher (each with any ``_target_`` nested in it). Hydra has no public hook between
composing and those steps, so :func:`check_command_line` first composes the same config
through Hydra's public config loader (``GlobalHydra.config_loader().load_configuration``:
the same primary config, search path, run mode and overrides that ``@hydra.main`` uses for
that command line) and checks it with :func:`mpclab.config.allowed_targets.check_config`.

Composing itself imports the package named by a ``pkg://`` entry of ``hydra.searchpath``
(which only the command line and the primary config set): such an entry naming a module of
the standard library is refused before anything is composed, for every command. Commands
that only print (``--cfg``, ``--info``, ``--shell-completion``) are not checked further:
Hydra composes for them without configuring logging or building anything.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

from hydra import initialize_config_dir
from hydra.core.config_loader import ConfigLoader
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from mpclab.config.allowed_targets import check_config, check_multirun, check_value
from mpclab.config.registry import check_module_name
from mpclab.config.root import CONF_DIR
from mpclab.core.errors import ConfigError

#: the config folder and name of ``python -m mpclab`` (its ``@hydra.main``)
MAIN_CONFIG = "config"
#: what a relative ``--config-path`` is relative to: the folder of the ``@hydra.main`` file
MAIN_FILE_DIR = Path(__file__).resolve().parent


def hydra_arguments() -> argparse.ArgumentParser:
    """The command line ``@hydra.main`` parses (Hydra 1.3's flags), to read the same way."""
    p = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    p.add_argument("--help", "-h", action="store_true")
    p.add_argument("--hydra-help", action="store_true")
    p.add_argument("--version", action="store_true")
    p.add_argument("overrides", nargs="*")
    p.add_argument("--cfg", "-c", choices=["job", "hydra", "all"])
    p.add_argument("--resolve", action="store_true")
    p.add_argument("--package", "-p")
    p.add_argument("--run", "-r", action="store_true")
    p.add_argument("--multirun", "-m", action="store_true")
    p.add_argument("--shell-completion", "-sc", action="store_true")
    p.add_argument("--config-path", "-cp")
    p.add_argument("--config-name", "-cn")
    p.add_argument("--config-dir", "-cd")
    p.add_argument("--experimental-rerun")
    p.add_argument("--info", "-i", const="all", nargs="?")
    return p


def check_command_line(argv: Sequence[str]) -> None:
    """Raise :class:`ConfigError` if the config ``python -m mpclab ARGV`` composes may not
    be run (:func:`mpclab.config.allowed_targets.check_config`). A command line that does not parse
    or compose is left to Hydra, which refuses it in the same way before acting on anything."""
    try:  # not parse_args: it prints its usage for an argument it does not know
        args, unknown = hydra_arguments().parse_known_args(list(argv))
    except (argparse.ArgumentError, SystemExit):
        return
    if unknown:
        return
    if args.experimental_rerun is not None:
        raise ConfigError("--experimental-rerun loads a pickled config, which can run any "
                          "code; mpclab does not take it (run the command line again)")
    if args.version or args.shell_completion:
        return
    main_dir = _main_dir(args.config_path)
    name = None if args.hydra_help else (args.config_name or MAIN_CONFIG)
    try:
        parsed = OverridesParser.create().parse_overrides(list(args.overrides))
        given = next((o for o in parsed if o.get_key_element() == "hydra.searchpath"), None)
        searchpath = given.value() if given else _primary_searchpath(main_dir, name)
    except Exception:  # noqa: BLE001  (an override or a primary file Hydra refuses alike)
        return
    if not isinstance(searchpath, list) or not all(isinstance(p, str) for p in searchpath):
        return  # Hydra refuses it: a list of strings
    for i, entry in enumerate(searchpath):  # read while composing, before anything else
        if entry.startswith("pkg://"):
            check_module_name(entry[len("pkg://"):].split("/")[0], f"hydra.searchpath[{i}]")
    if args.cfg or args.info is not None:
        return  # printed: Hydra configures no logging and builds nothing
    if args.config_dir is not None:
        folder = os.path.abspath(os.path.expanduser(args.config_dir))
        if not os.path.isdir(folder):
            return  # Hydra refuses the folder
        # searched after the primary folder, before hydra.searchpath's (as Hydra places it)
        quoted = ", ".join(f"'{p}'" for p in [f"file://{folder}", *searchpath])
        overrides = [o for o in args.overrides if given is None or o != given.input_line]
        overrides.append(f"hydra.searchpath=[{quoted}]")
    else:
        overrides = list(args.overrides)
    if not os.path.isdir(main_dir):
        return
    GlobalHydra.instance().clear()  # an earlier @hydra.main run in this process leaves it set
    with initialize_config_dir(config_dir=main_dir, version_base="1.3"):
        try:
            cfg, multirun = _load(GlobalHydra.instance().config_loader(), name, overrides,
                                  args.multirun and not args.hydra_help)
        except Exception:  # noqa: BLE001  (Hydra fails alike, before acting on anything)
            return
    check_config(cfg)
    if multirun:
        check_multirun(cfg)
        _check_swept_values(overrides)


def _check_swept_values(overrides: list[str]) -> None:
    """The values a sweep override gives a key (``plant._target_=a,b``) are checked up
    front, like the config's, rather than each as a job's error row."""
    for o in OverridesParser.create().parse_overrides(overrides):
        if not o.is_sweep_override():
            continue
        try:
            values = list(o.sweep_iterator())
        except Exception:  # noqa: BLE001  (a glob over a group's choices: no values here)
            continue
        for value in values:
            check_value(value, o.key_or_group)


def _load(loader: ConfigLoader, name: str | None, overrides: list[str],
          multirun: bool) -> tuple[DictConfig, bool]:
    """The config Hydra composes and whether it runs it as a multirun: with
    ``--multirun``, or when the config's own ``hydra.mode`` says so."""
    if multirun:
        return loader.load_configuration(name, overrides, RunMode.MULTIRUN), True
    try:
        cfg = loader.load_configuration(name, overrides, RunMode.RUN)
    except Exception:
        # sweep overrides without --multirun compose only if the config says MULTIRUN
        probe = loader.load_configuration(name, overrides, RunMode.MULTIRUN,
                                          validate_sweep_overrides=False)
        if probe.hydra.mode != RunMode.MULTIRUN:
            raise
        cfg = probe
    if cfg.hydra.mode == RunMode.MULTIRUN:
        return loader.load_configuration(name, overrides, RunMode.MULTIRUN), True
    return cfg, False


def _main_dir(config_path: str | None) -> str:
    """The primary config folder: ``--config-path`` (absolute, or relative to the folder of
    the ``@hydra.main`` file, as Hydra reads it), else mpclab's."""
    if config_path is None:
        return str(CONF_DIR)
    return os.path.normpath(os.path.join(MAIN_FILE_DIR, os.path.expanduser(config_path)))


def _primary_searchpath(main_dir: str, name: str | None) -> list[str]:
    """``hydra.searchpath`` of the primary config file, if it sets one."""
    path = Path(main_dir) / f"{name}.yaml"
    if name is None or not path.is_file():
        return []
    found = OmegaConf.select(OmegaConf.load(path), "hydra.searchpath")
    return [str(p) for p in found or []]
