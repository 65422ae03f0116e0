"""Composed configs kept on disk between commands, taken back only while their sources hold.

Composing an experiment with Hydra (about 30 YAML files and schemas merged) is the largest
part of a command's start after the imports: 0.3-0.5 s for a Zumo experiment on the 2-core
machine, paid again by every command for the same files. :mod:`mpclab.sweeps.compose`
composes the tree of a command's group overrides once per process; this module keeps that
tree in ``<cache>/compose/`` (``$MPCLAB_CACHE`` or ``~/.cache/mpclab``) for the next
command, and gives it back only if nothing that composing read has changed:

* in the entry's name: the primary config's name, the group overrides, the search path
  (``--config-dir`` adds to it), the versions of Python, Hydra and OmegaConf, the job's
  name and Hydra's ``version_base``;
* checked on every load: the config sources the tree was composed from
  (``hydra.runtime.config_sources``): every YAML file under a ``file`` or ``pkg`` source,
  its path and bytes, and the config store (mpclab's schemas, Hydra's and its plugins'
  structured configs) as pickled now. A source of another kind is not stored.

What composing reads from the process is set again on load: the working directory
(``hydra.runtime.cwd``) and the variables named by ``hydra.job.env_copy``. A command that
changes the search path on its command line (``hydra.searchpath=...``) composes as before.
The store is a cache: an entry that cannot be read or written is composed anew, never an
error. ``MPCLAB_COMPOSE_CACHE=0`` turns it off.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import pickle
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import omegaconf
from hydra import __version__ as hydra_version
from hydra import version as hydra_versions
from hydra.core.config_store import ConfigStore
from hydra.core.utils import JobRuntime
from omegaconf import DictConfig, OmegaConf, open_dict

from mpclab.codegen.build import cache_dir

log = logging.getLogger(__name__)

#: set to ``0`` to compose every command with Hydra
SWITCH_VAR = "MPCLAB_COMPOSE_CACHE"
#: the entries' layout; a new one leaves older entries unread
FORMAT = 1
CONFIG_SUFFIXES = (".yaml", ".yml")
#: entries kept: one per command's group overrides, the oldest written dropped first
MAX_ENTRIES = 256


def enabled() -> bool:
    """Whether commands use the store (:data:`SWITCH_VAR` is not ``0``)."""
    return os.environ.get(SWITCH_VAR, "1") != "0"


def load(repo: Any, config_name: str | None, lines: Sequence[str]) -> DictConfig | None:
    """The tree stored for these group override ``lines`` composed from ``repo`` (Hydra's
    config repository: its search path), if its sources are unchanged; None on a miss."""
    ident = _ident(repo, config_name, lines)
    path = _path(ident)
    try:
        entry = pickle.loads(path.read_bytes())
        if entry["ident"] != ident:
            raise ValueError("another command's entry")
        if _fingerprint(entry["sources"]) != entry["fingerprint"]:
            raise ValueError("a config source has changed")
        cfg = pickle.loads(entry["config"])
    except Exception as exc:  # noqa: BLE001  (missing, torn, another layout: compose anew)
        log.debug("composing %s: not stored (%s: %s)", ident, type(exc).__name__, exc)
        return None
    _set_from_process(cfg)
    log.debug("composed %s: from %s", ident, path)
    return cfg


def save(repo: Any, config_name: str | None, lines: Sequence[str], frozen: bytes,
         cfg: DictConfig) -> None:
    """Keep ``frozen`` (``cfg`` pickled) for :func:`load` (nothing if its sources are of a
    kind this store cannot check, or the cache folder is not writable)."""
    ident = _ident(repo, config_name, lines)
    sources = [(str(s.schema), str(s.path)) for s in cfg.hydra.runtime.config_sources]
    try:
        fingerprint = _fingerprint(sources)
        if fingerprint is None:
            return
        blob = pickle.dumps({"ident": ident, "sources": sources,
                             "fingerprint": fingerprint, "config": frozen})
        path = _path(ident)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
        os.replace(tmp, path)  # whole or not at all, for a concurrent reader
        _prune(path.parent)
    except Exception:  # noqa: BLE001  (a cache that cannot be written: compose next time)
        return


def _prune(folder: Path) -> None:
    """Keep the :data:`MAX_ENTRIES` most recently written entries (each about 25 kB)."""
    entries = sorted(folder.glob("*.pkl"), key=lambda p: p.stat().st_mtime_ns)
    for old in entries[:-MAX_ENTRIES]:
        old.unlink(missing_ok=True)


def _ident(repo: Any, config_name: str | None, lines: Sequence[str]) -> str:
    """What names an entry: the versions, the job, the search path, the config and the group
    overrides."""
    base = hydra_versions.getbase()
    search_path = tuple((s.scheme(), s.path) for s in repo.get_sources())
    return repr((FORMAT, sys.version_info[:3], hydra_version, omegaconf.__version__,
                 str(JobRuntime.instance().get("name")),  # a job's name unless its config sets one
                 None if base is None else str(base), search_path, config_name, tuple(lines)))


def _path(ident: str) -> Path:
    return cache_dir() / "compose" / (hashlib.sha256(ident.encode()).hexdigest()[:32] + ".pkl")


def _fingerprint(sources: Sequence[tuple[str, str]]) -> str | None:
    """A hash of what composing reads from ``sources`` ((scheme, path) pairs), or None if a
    source is of a kind not hashed here."""
    digest = hashlib.sha256()
    for scheme, path in sources:
        digest.update(f"{scheme}://{path}\n".encode())
        if scheme == "structured":
            digest.update(pickle.dumps(ConfigStore.instance().repo, protocol=4))
            continue
        root = Path(path) if scheme == "file" else _package_dir(path) if scheme == "pkg" else None
        if root is None or not root.is_dir():
            return None
        for file in sorted(root.rglob("*")):
            if "__pycache__" in file.parts:
                continue
            digest.update(f"{file.relative_to(root)}\n".encode())
            if file.suffix in CONFIG_SUFFIXES and file.is_file():
                digest.update(file.read_bytes())
    return digest.hexdigest()


def _package_dir(package: str) -> Path | None:
    spec = importlib.util.find_spec(package.replace("/", "."))
    locations = list(spec.submodule_search_locations or []) if spec else []
    return Path(locations[0]) if len(locations) == 1 else None


def _set_from_process(cfg: DictConfig) -> None:
    """What Hydra's composing reads from this process, as Hydra sets it."""
    with open_dict(cfg.hydra):
        cfg.hydra.runtime.cwd = os.getcwd()
        for key in OmegaConf.select(cfg, "hydra.job.env_copy", default=None) or []:
            cfg.hydra.job.env_set[key] = os.environ[key]
