"""Run records -> pandas tables: one row per run, a grouped table, Markdown.

Columns: ``sweep`` and ``job`` (where the run lies), the overridden parameters (one column
per override key, from ``.hydra/overrides.yaml``), ``backend``, then the summary fields.
A run folder without a readable ``summary.json`` is kept as a row with status ``incomplete``.

A sweep streams its rows: as each job ends, :func:`stream_row` appends the job's row (and
its controller calls' solve times, for the grouped table) to ``<sweep>/.mpclab/rows.jsonl``,
so :func:`collect_runs` reads one file instead of every job's folder, and a sweep that dies
keeps every finished row. ``python -m mpclab.cli.tables`` (:mod:`mpclab.sweeps.report`) writes
the tables and the figure for any folders.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from mpclab.core import jsonl as stream
from mpclab.record import files as record
from mpclab.record.provenance import stamped
from mpclab.tables.groups import (
    _step_times_ms,
    group_keys,
    group_table,
    numeric_column,
)

#: PyYAML's safe loader, libyaml's where PyYAML has it (5-10 times faster)
_SafeLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
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
    "groups": "groups.csv",
}


class XAxis(StrEnum):
    """What the arrival-vs-compute figure (:mod:`mpclab.sweeps.figure`) puts on its x axis."""

    STEP_MS = "step_ms"  # median compute per controller step, ms
    RTF = "rtf"          # compute time / simulated time


#: where a sweep streams its rows, relative to the sweep folder
ROWS_FILE = Path(".mpclab") / "rows.jsonl"
#: a run's controller calls got less than this share of a core (CPU / wall time)
CONTENDED_SHARE = 0.9


#: a sweep's runs recorded again to replay its front (:mod:`mpclab.sweeps.front_replay`):
#: copies of runs the sweep holds, so not rows of its tables
REPLAYED_RUNS = "front_runs"


def find_runs(paths: Iterable[Path]) -> list[Path]:
    """Every run folder (holding ``summary.json`` or ``.hydra/``) at or below ``paths``, but
    none in a hidden folder or in :data:`REPLAYED_RUNS`."""
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
                dirnames[:] = [d for d in dirnames
                               if not d.startswith(".") and d != REPLAYED_RUNS]
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
            out[key] = yaml.load(value, Loader=_SafeLoader) if value else None
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
        overrides = yaml.load(overrides_file.read_text(), Loader=_SafeLoader) or []
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


def stream_row(sweep_dir: Path, run_dir: Path) -> None:
    """Append the row of the finished run ``run_dir`` to its sweep's ``rows.jsonl``."""
    run_dir = Path(run_dir).resolve()
    row, params = read_run(run_dir)
    steps = _step_times_ms([str(run_dir)])
    summary = run_dir / record.SUMMARY
    mtime = summary.stat().st_mtime_ns if summary.is_file() else None
    stream.append(Path(sweep_dir) / ROWS_FILE, record.jsonable({
        "run_dir": str(run_dir), "summary_mtime_ns": mtime, "row": row, "params": params,
        "step_ms": [round(float(v), 6) for v in steps],
    }))


def _streamed(paths: Iterable[Path]) -> dict[str, dict[str, Any]]:
    """Streamed rows below ``paths`` by run folder, if still current (same summary.json)."""
    out: dict[str, dict[str, Any]] = {}
    for path in map(Path, paths):
        for rows in (path / ROWS_FILE, *path.glob(f"**/{ROWS_FILE}")):
            for rec in stream.read(rows):
                out[rec["run_dir"]] = rec
    for run_dir in [r for r, rec in out.items()
                    if _mtime(Path(r) / record.SUMMARY) != rec["summary_mtime_ns"]]:
        del out[run_dir]
    return out


def _mtime(path: Path) -> int | None:
    try:
        return path.stat().st_mtime_ns
    except FileNotFoundError:
        return None


def collect(paths: Iterable[Path], root: Path | None = None) -> pd.DataFrame:
    """One row per run below ``paths``, sorted by sweep, parameters and job number.

    ``sweep`` is relative to ``root`` (default: the current folder); ``run_dir`` is absolute.
    The parameter columns are listed in ``df.attrs["params"]``.
    """
    return collect_runs(paths, root)[0]


def collect_runs(
    paths: Iterable[Path], root: Path | None = None,
) -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """:func:`collect`, and every run's controller-call times in ms by ``run_dir``.

    A run whose row its sweep streamed (and whose summary.json has not changed since) is
    read from the stream; the others from their folders.
    """
    paths = list(map(Path, paths))
    root = Path(root or Path.cwd()).resolve()
    streamed = _streamed(paths)
    rows, params, step_ms = [], {}, {}
    for run_dir in find_runs(paths):
        rec = streamed.get(str(run_dir))
        if rec is not None:
            row, overridden = dict(rec["row"]), rec["params"]
            step_ms[str(run_dir)] = np.asarray(rec["step_ms"], dtype=float)
        else:
            row, overridden = read_run(run_dir)
        for key, value in overridden.items():
            params.setdefault(key, None)
            row.setdefault(key, value)  # a summary field of the same name wins
        sweep = _sweep_of(run_dir)
        row["sweep_dir"] = os.path.relpath(sweep, root)
        row["job"] = os.path.relpath(run_dir, sweep)
        row["run_dir"] = str(run_dir)
        rows.append(row)
    return _frame(rows, list(params)), step_ms


def _frame(rows: list[dict[str, Any]], params: list[str]) -> pd.DataFrame:
    """The runs table of ``rows``: typed columns, ``backend``, sorted (see :func:`collect`)."""
    df = pd.DataFrame(rows)
    if df.empty:
        df = pd.DataFrame(columns=["sweep_dir", "job", *LEAD, "run_dir"])
    for col in ("status", "controller", "scenario", "error"):
        if col not in df:
            df[col] = None
    df = _tidy(df)
    df["backend"] = _backend(df)
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
    df["contended"] = contended(df)
    df.attrs["params"] = param_cols
    return df


def contended(df: pd.DataFrame) -> pd.Series:
    """Runs whose compute columns a loaded machine may have inflated.

    True where the controller calls got less than :data:`CONTENDED_SHARE` of a core (CPU
    time / wall time), or the sweep ran more workers than there are cores, or the 1-minute
    load average exceeded the cores during the job; False where none of these was seen;
    missing where the run has no timing.
    """
    share, cores, workers = (numeric_column(df, c) for c in
                             ("compute_cpu_share", "load.cores", "load.workers"))
    load = np.fmax(numeric_column(df, "load.load_1m_start"), numeric_column(df, "load.load_1m_end"))
    flag = (share < CONTENDED_SHARE) | (workers > cores) | (load > cores)
    return flag.astype("boolean").where(share.notna(), pd.NA)


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


def _backend(df: pd.DataFrame) -> pd.Series:
    """The controller and its solver (``casadi:fatrop``, ``cvxpy:CLARABEL``): the solver its
    summary records, else the one its config sets; the controller alone where neither says.
    One label per backend and solver, whichever runs share the table."""
    backend = df["controller"].fillna("?").astype(str)
    solver = pd.Series("", index=df.index)
    for col in ("controller.solver", "solver"):  # the summary's word last: it wins
        if col in df:
            said = df[col].fillna("").astype(str)
            solver = said.where(said != "", solver)
    return backend.where(solver == "", backend + ":" + solver)


def markdown(df: pd.DataFrame, groups: pd.DataFrame | None = None) -> str:
    """The runs table (parameters and key results) and the grouped table, as Markdown."""
    groups = group_table(df) if groups is None else groups
    wanted = ["sweep_dir", "job", *df.attrs.get("params", []), *SHOWN]
    cols = [c for c in dict.fromkeys(wanted) if c in df]
    runs = df[cols].copy()
    if "error" in runs:
        runs["error"] = runs["error"].map(lambda e: e if not isinstance(e, str) else e[:100])
    parts = [
        f"## By {', '.join(group_keys(df))}", "", markdown_table(groups), "",
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
    df: pd.DataFrame, out_dir: Path, groups: pd.DataFrame | None = None,
) -> dict[str, Path]:
    """Write the runs table, the grouped table (default: :func:`group_table` of ``df``) and
    Markdown into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {key: out_dir / name for key, name in FILES.items()}
    groups = group_table(df) if groups is None else groups
    df.to_parquet(paths["parquet"], index=False)
    df.to_csv(paths["csv"], index=False)
    groups.to_csv(paths["groups"], index=False)
    paths["markdown"].write_text(stamped(markdown(df, groups)))
    return paths
