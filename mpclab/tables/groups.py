"""The grouped table: per configuration (all seeds of it), arrival and collision rates with
exact intervals, time-outs, the least clearance and compute per controller call."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mpclab.core.status import SOLVE_KEYS, SolveStatus
from mpclab.record import files as record
from mpclab.record.stats import bootstrap_mean, clopper_pearson

#: parameters never grouped by: repetitions of the same configuration (the seed; a BARN
#: world, one of the benchmark's sample, pooled as the challenge pools them)
NOT_GROUPED = ("seed", "scenario.world")


def numeric_column(df: pd.DataFrame, col: str) -> pd.Series:
    """Column ``col`` as floats (all NaN if ``df`` has no such column)."""
    if col not in df:
        return pd.Series(np.nan, index=df.index, dtype=float)
    return pd.to_numeric(df[col], errors="coerce").astype(float)


def _step_times_ms(run_dirs: Iterable[str]) -> np.ndarray:
    """Every controller call's solve time (ms) of the runs, pooled (final rows left out)."""
    parts = []
    for run_dir in run_dirs:
        if (Path(run_dir) / record.STEPS).is_file():
            parts.append(record.read_solve_times_s(Path(run_dir)) * 1e3)
    return np.concatenate(parts) if parts else np.array([])


def group_keys(df: pd.DataFrame) -> list[str]:
    """What the grouped table groups by: backend, scenario and every other parameter the
    sweep varies, except :data:`NOT_GROUPED` (a group is the repetitions of one
    configuration)."""
    named = {"controller", "scenario", *NOT_GROUPED}
    if "controller.solver" in df and "controller.solver" in df.attrs.get("params", []):
        named.add("controller.solver")  # in ``backend``
    swept = [p for p in df.attrs.get("params", []) if p in df and p not in named
             and df[p].astype(str).nunique(dropna=False) > 1]
    return ["backend", "scenario", *swept]


def group_table(
    df: pd.DataFrame, step_ms: Mapping[str, np.ndarray] | None = None,
) -> pd.DataFrame:
    """Per group (:func:`group_keys`): runs; the arrival (success) rate and the collision
    rate, each with its exact 95 % interval (Clopper-Pearson: ``success_low``,
    ``success_high``, ``collision_low``, ``collision_high``); time-outs; the least clearance
    of any run (continuous time); median arrival, median and p95
    compute per controller call (wall and CPU), and runs flagged :func:`contended`; on BARN
    worlds, its time-out rate and mean score with their intervals (:data:`BARN_COLUMNS`).

    Step compute pools every controller call of the group's runs, from ``step_ms`` (run folder
    -> ms, as :func:`collect_runs` gives) or else from each run's ``steps.parquet``.
    """
    keys = group_keys(df)
    step_ms = step_ms or {}
    barn = "barn_score" in df
    rows = []
    for values, g in df.groupby(keys, dropna=False, sort=True):
        missing = [r for r in g["run_dir"] if r not in step_ms]
        parts = [step_ms[r] for r in g["run_dir"] if r in step_ms]
        ms = np.concatenate([*parts, _step_times_ms(missing)])
        arrived = g["status"] == "arrived"
        flagged = g["contended"] if "contended" in g else pd.Series(dtype="boolean")
        rows.append({
            **dict(zip(keys, values, strict=True)),
            "runs": len(g),
            "arrived": int(arrived.sum()),
            "collisions": int((g["status"] == "collision").sum()),
            "timeouts": int((g["status"] == "timeout").sum()),
            "errors": int((g["status"] == "error").sum()),
            **_rate("success", int(arrived.sum()), len(g)),
            **_rate("collision", int((g["status"] == "collision").sum()), len(g)),
            "min_clearance_m": float(numeric_column(g, "min_clearance_m").min())
            if numeric_column(g, "min_clearance_m").notna().any() else None,
            "arrival_median_s": float(g.loc[arrived, "arrival_time_s"].median())
            if arrived.any() else None,
            "step_median_ms": float(np.median(ms)) if ms.size else None,
            "step_p95_ms": float(np.percentile(ms, 95)) if ms.size else None,
            "step_cpu_median_ms": float(numeric_column(g, "compute_cpu_median_ms").median())
            if numeric_column(g, "compute_cpu_median_ms").notna().any() else None,
            "contended_runs": int(flagged.fillna(False).sum()),
            **_solve_shares(g),
            **(_barn(g) if barn else {}),
        })
    return pd.DataFrame(rows, columns=[
        *keys, "runs", "arrived", "collisions", "timeouts", "errors",
        "success_rate", "success_low", "success_high",
        "collision_rate", "collision_low", "collision_high", "min_clearance_m",
        "arrival_median_s",
        "step_median_ms", "step_p95_ms", "step_cpu_median_ms", "contended_runs",
        "converged_fraction", *SOLVE_COUNTS, *(BARN_COLUMNS if barn else ()),
    ])


#: the grouped table's BARN columns (runs on ``scenario=barn``): time-outs as the challenge
#: counts them (a stall included) and the mean score, each with its 95 % interval
BARN_COLUMNS = ("barn_timeout_rate", "barn_timeout_low", "barn_timeout_high",
                "barn_score_mean", "barn_score_low", "barn_score_high")


def _barn(g: pd.DataFrame) -> dict[str, Any]:
    """A group's BARN figures: the time-out rate (exact interval) and the mean score
    (bootstrap interval; a run without a score, as one that failed to start, scores 0)."""
    timeouts = int(g["status"].isin(("timeout", "stalled")).sum())
    scores = numeric_column(g, "barn_score").fillna(0.0).to_numpy()
    lo, hi = bootstrap_mean(scores)
    return {**_rate("barn_timeout", timeouts, len(g)),
            "barn_score_mean": float(scores.mean()) if scores.size else float("nan"),
            "barn_score_low": lo, "barn_score_high": hi}


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




def _rate(name: str, count: int, runs: int) -> dict[str, float]:
    """``<name>_rate`` of ``count`` in ``runs`` with its exact 95 % interval."""
    lo, hi = clopper_pearson(count, runs)
    return {f"{name}_rate": count / runs if runs else float("nan"),
            f"{name}_low": lo, f"{name}_high": hi}
