"""The NN's training data: a sweep's runs merged into one parquet file.

Generation is a Hydra sweep of an MPC experiment with ``recorder=dataset``
(:mod:`mpclab.recorders.dataset`): one job per start seed, each writing ``dataset.parquet``
into its run folder; this merges them.

    uv run python -m mpclab.approx.dataset OUTPUT_DIR... -o data.parquet
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import OmegaConf

from mpclab.core.errors import exit_on_bad_input
from mpclab.recorders.dataset import ROWS, config_hash


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
        raise FileNotFoundError("no run folders (with .hydra/config.yaml) below "
                                + ", ".join(map(str, paths)))
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
        raise FileNotFoundError(f"none of the {len(dirs)} runs below "
                                f"{', '.join(map(str, paths))} wrote {ROWS}")
    data = pd.concat(tables, ignore_index=True)
    report = MergeReport(len(data), len(tables), missing, sorted(hashes))
    data.attrs["mpclab"] = json.dumps(report.__dict__)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    data.to_parquet(out, index=False)
    return report


def read(path: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A merged dataset and its metadata (runs, missing runs, config hashes)."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"no dataset at {path} (python -m mpclab.approx.dataset merges "
                                "one; the pipeline's data stage makes it)")
    data = pd.read_parquet(path)
    return data, json.loads(data.attrs.get("mpclab", "{}"))


def main(argv: list[str] | None = None) -> MergeReport:
    ap = argparse.ArgumentParser(prog="python -m mpclab.approx.dataset",
                                 description="Merge a sweep's dataset rows into one file.")
    ap.add_argument("paths", nargs="+", type=Path, help="sweep or outputs folders")
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args(argv)
    try:
        report = merge(args.paths, args.output)
    except OSError as exc:  # no such folder, no rows, an output that cannot be written
        exit_on_bad_input(ap, exc)
    print(f"{args.output}: {report.rows} rows from {report.runs} runs; "
          f"configs {', '.join(report.config_hashes)}")
    if report.missing:
        print(f"{len(report.missing)} runs wrote no rows:", *report.missing, sep="\n  ",
              file=sys.stderr)
    return report


if __name__ == "__main__":
    main()
