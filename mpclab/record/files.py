"""The run record: what every run writes into its folder, and how to read it back.

``steps.parquet`` (one row per controller call plus the final state), ``horizons.parquet``
(every predicted horizon, long format: ``step``, ``k``, ``t``, states, inputs) and
``summary.json``. Hydra adds ``.hydra/config.yaml``.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

STEPS = "steps.parquet"
HORIZONS = "horizons.parquet"
SUMMARY = "summary.json"

#: columns of steps.parquet whose values depend on wall-clock timing (sensing with the
#: supervisor; the last four: the real-time iteration's phases, only in its runs)
TIMING_COLUMNS = ("solve_time_s", "solve_cpu_s", "sense_cpu_s", "prep_s", "feedback_s",
                  "feedback_cpu_s", "prep_overrun")
#: the ``status`` of steps.parquet's last row: the final state, after the last controller call
FINAL = "final"


def controller_steps(steps: pd.DataFrame) -> pd.DataFrame:
    """The rows of a step log that are controller calls (every row but the final state)."""
    return steps[steps["status"] != FINAL]

_VERSIONED = (
    "mpclab", "numpy", "scipy", "pandas", "casadi", "cvxpy", "clarabel", "osqp",
    "hydra-core", "rerun-sdk",
)


@functools.cache
def _versions() -> tuple[tuple[str, str], ...]:
    """Versions of Python and the packages, looked up once per process."""
    import platform

    out = {"python": platform.python_version()}
    for name in _VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return tuple(out.items())


def versions() -> dict[str, str]:
    """Versions of Python and the packages a run's numbers depend on."""
    return dict(_versions())


def write(
    out_dir: Path, steps: pd.DataFrame, horizons: pd.DataFrame, summary: dict[str, Any]
) -> None:
    """Write the three files of a run record into ``out_dir`` (created if needed)."""
    out_dir = Path(out_dir)
    with writing(out_dir, "the run record"):
        out_dir.mkdir(parents=True, exist_ok=True)
        for frame, name in ((steps, STEPS), (horizons, HORIZONS)):
            # what ``frame.to_parquet(path, index=False)`` writes, without pandas' wrapper
            # around pyarrow (0.3 ms a file; a sweep writes two per job)
            pq.write_table(pa.Table.from_pandas(frame, preserve_index=False), out_dir / name)
        # summary last: its presence marks a complete record
        write_summary(out_dir, summary)


@contextlib.contextmanager
def writing(out_dir: Path, what: str) -> Iterator[None]:
    """An error while writing ``what`` into ``out_dir`` (read-only, full, not a folder)
    raised again as one that names the folder, not a C++ frame or a file descriptor: the
    command line's one message (``No space left on device``, ``Read-only file system``)."""
    try:
        yield
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {what} ({exc.strerror or exc})",
                      str(out_dir)) from exc


def write_summary(out_dir: Path, summary: dict[str, Any]) -> None:
    """Write ``summary.json`` atomically (a reader never sees half a file)."""
    tmp = Path(out_dir) / (SUMMARY + ".tmp")
    tmp.write_text(json.dumps(jsonable(summary), indent=2, allow_nan=False) + "\n")
    tmp.replace(Path(out_dir) / SUMMARY)


def read_summary(run_dir: Path) -> dict[str, Any]:
    """A run's summary; ValueError for a file that is not one (torn, hand-made, no status)."""
    summary = json.loads((Path(run_dir) / SUMMARY).read_text())
    if not isinstance(summary, dict) or "status" not in summary:
        raise ValueError("not a run summary (no 'status')")
    return summary


def read_steps(run_dir: Path) -> pd.DataFrame:
    return pd.read_parquet(Path(run_dir) / STEPS)


def read_solve_times_s(run_dir: Path) -> np.ndarray:
    """``solve_time_s`` of the controller calls in a run's step log (:func:`controller_steps`'
    rows), read with pyarrow alone: a sweep reads it for every job's row."""
    table = pq.read_table(Path(run_dir) / STEPS, columns=["solve_time_s", "status"])
    calls = pc.fill_null(pc.not_equal(table["status"], FINAL), True)  # as pandas' ``!=``
    return table.filter(calls)["solve_time_s"].to_numpy()


def read_horizons(run_dir: Path) -> pd.DataFrame:
    return pd.read_parquet(Path(run_dir) / HORIZONS)


def jsonable(value: Any) -> Any:
    """NaN/inf become null so summary.json is strict JSON."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item"):  # numpy scalars
        return jsonable(value.item())
    return value
