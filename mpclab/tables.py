"""Run records -> pandas tables: one row per run, a grouped table, Markdown, a figure.

``python -m mpclab.tables PATH [PATH ...]`` aggregates every run record found below the
given folders (one sweep, several sweeps, a whole ``outputs/``) into ``summary.parquet``,
``summary.csv``, ``summary.md``, ``groups.csv`` and ``arrival_vs_compute.png`` in ``--out``
(default: the first PATH). The multirun callback does the same for each sweep folder.

Columns: ``sweep`` and ``job`` (where the run lies), the overridden parameters (one column
per override key, from ``.hydra/overrides.yaml``), ``backend``, then the summary fields.
A run folder without a readable ``summary.json`` is kept as a row with status ``incomplete``.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Iterable, Sequence
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from mpclab import record
from mpclab.status import SOLVE_KEYS, SolveStatus

#: status of a run folder whose summary.json is missing or unreadable
INCOMPLETE = "incomplete"
#: summary fields first in the table (others follow in the order they are met)
LEAD = (
    "experiment", "plant", "controller", "backend", "scenario", "seed", "status", "arrived",
    "arrival_time_s", "n_steps", "sim_time_s", "compute_total_s", "compute_median_ms",
    "compute_p95_ms", "compute_max_ms", "rtf", "min_clearance_m", "solver_failures",
    "converged_fraction", "error",
)
#: summary fields that are not table columns
DROPPED = ("versions", "overrides", "skipped")
#: columns of the Markdown runs table, after the parameters
SHOWN = (
    "backend", "scenario", "status", "arrival_time_s", "compute_median_ms", "compute_p95_ms",
    "rtf", "converged_fraction", "error",
)
FILES = {
    "parquet": "summary.parquet", "csv": "summary.csv", "markdown": "summary.md",
    "groups": "groups.csv", "figure": "arrival_vs_compute.png",
}


class XAxis(StrEnum):
    """What the arrival-vs-compute figure puts on its x axis."""

    STEP_MS = "step_ms"  # median compute per controller step, ms
    RTF = "rtf"          # compute time / simulated time


def find_runs(paths: Iterable[Path]) -> list[Path]:
    """Every run folder (holding ``summary.json`` or ``.hydra/``) at or below ``paths``."""
    found: set[Path] = set()
    for path in map(Path, paths):
        if not path.exists():
            raise FileNotFoundError(f"no such folder: {path}")
        for dirpath, dirnames, filenames in os.walk(path):
            here = Path(dirpath)
            if record.SUMMARY in filenames or ".hydra" in dirnames:
                found.add(here.resolve())
                dirnames.clear()  # a run folder holds no further runs
            else:
                dirnames[:] = [d for d in dirnames if not d.startswith(".")]
    return sorted(found)


def override_key(override: str) -> str:
    """``'+controller.horizon=10'`` -> ``'controller.horizon'`` (``+``, ``++``, ``~`` off)."""
    return override.split("=", 1)[0].lstrip("+~")


def parse_overrides(overrides: Sequence[str]) -> dict[str, Any]:
    """``["controller=cvxpy", "+seed=3"]`` -> ``{"controller": "cvxpy", "seed": 3}``."""
    out: dict[str, Any] = {}
    for item in overrides:
        key, value = override_key(item), item.partition("=")[2]
        if key.startswith("hydra.") or key.startswith("hydra/"):
            continue
        try:
            out[key] = yaml.safe_load(value) if value else None
        except yaml.YAMLError:
            out[key] = value
        if isinstance(out[key], dict | list):
            out[key] = value
    return out


def read_run(run_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(summary row, overridden parameters)`` of one run folder."""
    run_dir = Path(run_dir)
    try:
        summary: dict[str, Any] = record.read_summary(run_dir)
    except FileNotFoundError:
        summary = {"status": INCOMPLETE, "error": f"no {record.SUMMARY}"}
    except ValueError as exc:
        summary = {"status": INCOMPLETE, "error": f"unreadable {record.SUMMARY}: {exc}"}
    if summary["status"] == INCOMPLETE:  # name its components from Hydra's record, if any
        summary.update(_choices(run_dir / ".hydra" / "hydra.yaml"))
    overrides_file = run_dir / ".hydra" / "overrides.yaml"
    if overrides_file.is_file():
        overrides = yaml.safe_load(overrides_file.read_text()) or []
    else:
        overrides = summary.get("overrides") or []
    row = {k: v for k, v in summary.items() if k not in DROPPED}
    return _flatten(row), parse_overrides(overrides)


def _choices(hydra_yaml: Path) -> dict[str, Any]:
    """``plant``, ``controller``, ``scenario`` as Hydra chose them for a job (if recorded)."""
    try:
        choices = yaml.safe_load(hydra_yaml.read_text())["hydra"]["runtime"]["choices"]
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return {}
    return {k: choices[k] for k in ("plant", "controller", "scenario") if k in choices}


def _flatten(row: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts become dotted columns; lists become JSON text."""
    out: dict[str, Any] = {}
    for key, value in row.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + "."))
        elif isinstance(value, list | tuple):
            out[name] = json.dumps(value)
        else:
            out[name] = value
    return out


def _sweep_of(run_dir: Path) -> Path:
    """The nearest folder at or above ``run_dir``'s parent holding Hydra's ``multirun.yaml``."""
    for parent in run_dir.parents:
        if (parent / "multirun.yaml").is_file():
            return parent
    return run_dir.parent


def collect(paths: Iterable[Path], root: Path | None = None) -> pd.DataFrame:
    """One row per run below ``paths``, sorted by sweep, parameters and job number.

    ``sweep`` is relative to ``root`` (default: the current folder); ``run_dir`` is absolute.
    The parameter columns are listed in ``df.attrs["params"]``.
    """
    root = Path(root or Path.cwd()).resolve()
    rows, params = [], {}
    for run_dir in find_runs(paths):
        row, overridden = read_run(run_dir)
        for key, value in overridden.items():
            params.setdefault(key, None)
            row.setdefault(key, value)  # a summary field of the same name wins
        row["sweep_dir"] = os.path.relpath(_sweep_of(run_dir), root)
        row["job"] = os.path.relpath(run_dir, _sweep_of(run_dir))
        row["run_dir"] = str(run_dir)
        rows.append(row)
    df = pd.DataFrame(rows)
    if df.empty:
        df = pd.DataFrame(columns=["sweep_dir", "job", *LEAD, "run_dir"])
    for col in ("status", "controller", "scenario", "error"):
        if col not in df:
            df[col] = None
    df = _tidy(df)
    df["backend"] = _backend(df, list(params))
    param_cols = [p for p in params if p in df]
    lead = [c for c in LEAD if c in df]
    first = [p for p in param_cols if p not in lead]
    rest = [c for c in df if c not in {"sweep_dir", "job", "run_dir", *first, *lead}]
    df = df[["sweep_dir", "job", *first, *lead, *rest, "run_dir"]]
    job_num = pd.to_numeric(df["job"], errors="coerce")
    order = ["sweep_dir", *param_cols, "_job_num", "job"]
    df = (
        df.assign(_job_num=job_num)
        .sort_values(order, kind="stable", na_position="last")
        .drop(columns="_job_num")
        .reset_index(drop=True)
    )
    df.attrs["params"] = param_cols
    return df


def _tidy(df: pd.DataFrame) -> pd.DataFrame:
    """Make every column one type, so parquet can store it: numbers, or text."""
    for col in df.columns:
        if df[col].dtype != object:
            continue
        values = df[col].dropna()
        if values.map(lambda v: isinstance(v, bool)).all():
            continue
        numeric = values.map(lambda v: isinstance(v, int | float) and not isinstance(v, bool))
        if len(values) and numeric.all():
            df[col] = pd.to_numeric(df[col])
        else:
            df[col] = df[col].map(lambda v: v if v is None or pd.isna(v) else str(v))
    return df


def _backend(df: pd.DataFrame, params: list[str]) -> pd.Series:
    """The controller, with its solver when a sweep varies ``controller.solver``."""
    backend = df["controller"].fillna("?").astype(str)
    if "controller.solver" in params and df["controller.solver"].nunique() > 1:
        solver = df["controller.solver"].fillna("").astype(str)
        backend = backend.where(solver == "", backend + ":" + solver)
    return backend


def _step_times_ms(run_dirs: Iterable[str]) -> np.ndarray:
    """Every controller call's solve time (ms) of the runs, pooled (final rows left out)."""
    parts = []
    for run_dir in run_dirs:
        path = Path(run_dir) / record.STEPS
        if path.is_file():
            steps = pd.read_parquet(path, columns=["solve_time_s", "status"])
            parts.append(steps.loc[steps["status"] != "final", "solve_time_s"].to_numpy() * 1e3)
    return np.concatenate(parts) if parts else np.array([])


def group_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per backend x scenario: runs, success rate, median arrival, median and p95 step compute.

    Step compute pools every controller call of the group's runs from ``steps.parquet``.
    """
    rows = []
    for (backend, scenario), g in df.groupby(["backend", "scenario"], dropna=False, sort=True):
        ms = _step_times_ms(g["run_dir"])
        arrived = g["status"] == "arrived"
        rows.append({
            "backend": backend,
            "scenario": scenario,
            "runs": len(g),
            "arrived": int(arrived.sum()),
            "errors": int((g["status"] == "error").sum()),
            "success_rate": float(arrived.mean()),
            "arrival_median_s": float(g.loc[arrived, "arrival_time_s"].median())
            if arrived.any() else None,
            "step_median_ms": float(np.median(ms)) if ms.size else None,
            "step_p95_ms": float(np.percentile(ms, 95)) if ms.size else None,
            **_solve_shares(g),
        })
    return pd.DataFrame(rows, columns=[
        "backend", "scenario", "runs", "arrived", "errors", "success_rate",
        "arrival_median_s", "step_median_ms", "step_p95_ms", "converged_fraction",
        *SOLVE_COUNTS,
    ])


#: per-status solve counts of summary.json, summed over a group
SOLVE_COUNTS = tuple(SOLVE_KEYS.values())


def _solve_shares(g: pd.DataFrame) -> dict[str, Any]:
    """A group's solves by status (summed) and the converged share of all of them."""
    counts = {c: int(pd.to_numeric(g[c], errors="coerce").fillna(0).sum()) if c in g else 0
              for c in SOLVE_COUNTS}
    total = sum(counts.values())
    converged = counts[SOLVE_KEYS[SolveStatus.converged]]
    return {"converged_fraction": converged / total if total else None,
            **counts}


def markdown(df: pd.DataFrame, groups: pd.DataFrame | None = None) -> str:
    """The runs table (parameters and key results) and the grouped table, as Markdown."""
    groups = group_table(df) if groups is None else groups
    wanted = ["sweep_dir", "job", *df.attrs.get("params", []), *SHOWN]
    cols = [c for c in dict.fromkeys(wanted) if c in df]
    runs = df[cols].copy()
    if "error" in runs:
        runs["error"] = runs["error"].map(lambda e: e if not isinstance(e, str) else e[:100])
    parts = [
        "## By backend and scenario", "", markdown_table(groups), "",
        f"## Runs ({len(df)})", "", markdown_table(runs), "",
    ]
    return "\n".join(parts)


def markdown_table(df: pd.DataFrame) -> str:
    """``df`` as a Markdown table (numbers to 4 significant digits, empty for missing)."""
    if df.empty:
        return "(no runs)"
    shown = df.astype(object)
    return shown.where(shown.notna(), None).to_markdown(index=False, floatfmt=".4g", missingval="")


def write_tables(
    df: pd.DataFrame, out_dir: Path, figure: bool = True, x: XAxis = XAxis.STEP_MS,
) -> dict[str, Path]:
    """Write the runs table, the grouped table, Markdown and the figure into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {key: out_dir / name for key, name in FILES.items()}
    groups = group_table(df)
    df.to_parquet(paths["parquet"], index=False)
    df.to_csv(paths["csv"], index=False)
    groups.to_csv(paths["groups"], index=False)
    paths["markdown"].write_text(markdown(df, groups))
    if figure:
        from mpclab.sweeps.figure import plot_arrival_vs_compute

        plot_arrival_vs_compute(df, paths["figure"], XAxis(x))
    else:
        del paths["figure"]
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mpclab.tables", description=__doc__.split("\n\n")[0],
    )
    parser.add_argument("paths", nargs="+", type=Path, help="outputs or sweep folders")
    parser.add_argument("--out", type=Path, help="where the tables go (default: first PATH)")
    parser.add_argument("--x", choices=[a.value for a in XAxis], default=XAxis.STEP_MS.value,
                        help="figure x axis: compute per step (ms) or compute/simulated time")
    parser.add_argument("--no-figure", action="store_true", help="tables only")
    args = parser.parse_args(argv)
    out = args.out or args.paths[0]
    df = collect(args.paths, root=out)
    if df.empty:
        parser.error(f"no run records below {', '.join(map(str, args.paths))}")
    paths = write_tables(df, out, figure=not args.no_figure, x=XAxis(args.x))
    print(markdown_table(group_table(df)))
    print(f"\n{len(df)} runs -> " + ", ".join(str(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
