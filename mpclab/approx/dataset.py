"""The NN's training data: a recorder that writes each run's (pose, ranges, input) rows, and
a merge of a sweep's runs into one parquet file.

Generation is a Hydra sweep of an MPC experiment with ``recorder=dataset``: one job per start
seed, each writing ``dataset.parquet`` into its run folder. The rows hold what the features
are made of (pose, goal pose, every ray's range, ``inf`` for none), not the features
themselves, so one dataset serves every feature set.

    uv run python -m mpclab.approx.dataset OUTPUT_DIR... -o data.parquet
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab.recording.base import Recorder
from mpclab.registry import component

ROWS = "dataset.parquet"
#: what is ignored when hashing a run's config: what differs between the jobs of one dataset
HASH_IGNORES = ("seed", "hydra")


@dataclass
class DatasetRecorderConf:
    _target_: str = "mpclab.approx.dataset.DatasetRecorder"
    # the injected run config must arrive as data, not be instantiated
    _recursive_: bool = False
    filename: str = ROWS


@component("recorder", "dataset", DatasetRecorderConf)
class DatasetRecorder(Recorder):
    """Writes one row per controller call: pose, goal pose, ranges, input, solver status.

    Parameters
    ----------
    out_dir
        Injected run folder.
    cfg
        Injected run config; its hash goes into every row (``config_hash``).
    filename
        File written into it.
    """

    def __init__(
        self, out_dir: Path | None = None, cfg: Any = None, filename: str = ROWS
    ) -> None:
        self.path = Path(out_dir or ".") / filename
        # the generating config's hash, taken now: a resumed sweep may rewrite the run's
        # .hydra/config.yaml later, and the rows must keep the config that made them
        self.config_hash = hash_config(cfg) if cfg is not None else None
        self._rows: list[np.ndarray] = []
        self._status: list[str] = []
        self._fallback: list[bool] = []

    def start(self, run: Any) -> None:
        p = run.plant
        if p.heading is None:
            raise ValueError("the dataset recorder needs a plant with a heading")
        self._ip = [p.state_index(s) for s in (*p.position, p.heading)]
        self._inputs = p.inputs
        self._seed: int | None = None

    def log_step(self, k: int, t: float, x: Any, step: Any, ctx: Any) -> None:
        x = np.asarray(x, dtype=float)
        self._rows.append(np.concatenate(
            ([k, t], x[self._ip], ctx.goal[self._ip], ctx.ranges, step.u)
        ))
        self._status.append(step.status)
        self._fallback.append(bool(step.fallback))

    def finish(self, x: Any, t: float, summary: dict[str, Any]) -> None:
        n_rays = (len(self._rows[0]) - 8 - len(self._inputs)) if self._rows else 0
        cols = ["step", "t", "x", "y", "theta", "x0", "y0", "theta0"]
        cols += [f"d{i}" for i in range(n_rays)] + list(self._inputs)
        table = pd.DataFrame(np.array(self._rows).reshape(len(self._rows), len(cols)),
                             columns=cols)
        table["step"] = table["step"].astype(int)
        table["status"] = pd.Series(self._status, dtype="string")
        table["fallback"] = np.array(self._fallback, dtype=bool)
        table["run_status"] = summary.get("status", "")
        if self.config_hash is not None:
            table["config_hash"] = self.config_hash
        self.path.parent.mkdir(parents=True, exist_ok=True)
        table.to_parquet(self.path, index=False)


def hash_config(cfg: Any) -> str:
    """Short hash of a run's config (interpolations unresolved, as Hydra saves it) without
    what differs between a sweep's jobs."""
    data = dict(OmegaConf.to_container(OmegaConf.create(cfg), resolve=False))
    for key in HASH_IGNORES:
        data.pop(key, None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:12]


def config_hash(run_dir: Path) -> str:
    """:func:`hash_config` of the config saved in a run folder's ``.hydra/config.yaml``."""
    return hash_config(OmegaConf.load(Path(run_dir) / ".hydra" / "config.yaml"))


def run_dirs(paths: list[Path]) -> list[Path]:
    """Every run folder (one holding ``.hydra/config.yaml``) below ``paths``, sorted."""
    found: set[Path] = set()
    for path in paths:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no such folder: {path}")
        found |= {p.parent.parent for p in path.rglob(".hydra/config.yaml")}
    return sorted(found)


@dataclass
class MergeReport:
    rows: int
    runs: int
    missing: list[str]
    config_hashes: list[str]


def merge(paths: list[Path], out: Path) -> MergeReport:
    """Concatenate the rows of every run below ``paths`` into ``out`` (parquet).

    Every run's rows are kept, tagged with ``run`` (folder) and ``seed``; a run without rows
    is listed in the report (and the file's metadata), never dropped silently. The file's
    metadata also holds the generating configs' hashes: the one each run's recorder wrote
    with its rows, or, for rows written without one, the hash of the run's saved config.
    """
    tables, missing, hashes = [], [], set()
    dirs = run_dirs(paths)
    if not dirs:
        raise FileNotFoundError(f"no run folders (with .hydra/config.yaml) below {paths}")
    for d in dirs:
        rows = d / ROWS
        if not rows.exists():
            missing.append(str(d))
            continue
        t = pd.read_parquet(rows)
        cfg = OmegaConf.load(d / ".hydra" / "config.yaml")
        t.insert(0, "seed", int(cfg.get("seed", -1)))
        t.insert(0, "run", str(d))
        if "config_hash" not in t:
            t["config_hash"] = config_hash(d)
        hashes.update(t["config_hash"].unique().tolist())
        tables.append(t)
    if not tables:
        raise FileNotFoundError(f"none of the {len(dirs)} runs below {paths} wrote {ROWS}")
    data = pd.concat(tables, ignore_index=True)
    report = MergeReport(len(data), len(tables), missing, sorted(hashes))
    data.attrs["mpclab"] = json.dumps(report.__dict__)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    data.to_parquet(out, index=False)
    return report


def read(path: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A merged dataset and its metadata (runs, missing runs, config hashes)."""
    data = pd.read_parquet(path)
    return data, json.loads(data.attrs.get("mpclab", "{}"))


def main(argv: list[str] | None = None) -> MergeReport:
    ap = argparse.ArgumentParser(description="Merge a sweep's dataset rows into one file.")
    ap.add_argument("paths", nargs="+", type=Path, help="sweep or outputs folders")
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args(argv)
    report = merge(args.paths, args.output)
    print(f"{args.output}: {report.rows} rows from {report.runs} runs; "
          f"configs {', '.join(report.config_hashes)}")
    if report.missing:
        print(f"{len(report.missing)} runs wrote no rows:", *report.missing, sep="\n  ",
              file=sys.stderr)
    return report


if __name__ == "__main__":
    main()
