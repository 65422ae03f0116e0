"""The Pareto front of a sweep: the configurations no other beats in every objective.

A **point** is one configuration: the values of the parameters the sweep varies, except the
seed, over all its seeds (layouts). Each objective is minimized (:class:`ParetoObjective`):

* ``arrival_s``: the arrival time [s];
* ``tracking_rms_m``: the position tracking RMS [m];
* ``step_p95_ms``: the 95th percentile of the controller's wall time per call [ms];
* ``step_cpu_p95_ms``: the same in CPU time (for a sweep that ran contended) [ms];
* ``input_cpu_p95_ms``: the CPU time of a call up to its input, 95th percentile: the
  real-time iteration's feedback (its preparation runs after the input), the whole call for
  any other controller [ms];
* ``step_m4_p95_ms``: the run's Cortex-M4 estimate per controller call, 95th percentile, as
  its summary records it [ms];

each per seed, and the point's value the median over its seeds, with the seeds' spread
beside it (``_min``, ``_max``). A point is **feasible** when
every seed arrived, none collided or failed, and none missed a deadline (runs under
``sim.latency``). The **front** is the feasible points that no feasible point dominates (at
most as large in every objective and smaller in one, where values within
:data:`TIE_TOLERANCE` of each other count as equal: two builds that track alike to 1e-5 m
are not told apart by their tracking, only by their compute). The **knee** is the front point
nearest the ideal one (every objective at its best on the front), the objectives scaled to [0, 1]
over the front. The **default** is the point of the values the sweep's base config gives
the varied parameters (the configuration that ships), when the sweep has one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mpclab.core.errors import ConfigError, parse_choice
from mpclab.record import files as record
from mpclab.tables.groups import NOT_GROUPED, numeric_column


class ParetoObjective(StrEnum):
    arrival_s = "arrival_s"
    tracking_rms_m = "tracking_rms_m"
    step_p95_ms = "step_p95_ms"
    step_cpu_p95_ms = "step_cpu_p95_ms"
    input_cpu_p95_ms = "input_cpu_p95_ms"
    step_m4_p95_ms = "step_m4_p95_ms"


#: each objective's axis label
LABELS = {
    ParetoObjective.arrival_s: "arrival time, median over seeds [s]",
    ParetoObjective.tracking_rms_m: "position tracking RMS, median over seeds [m]",
    ParetoObjective.step_p95_ms: "compute per controller call, p95 (wall), median over seeds [ms]",
    ParetoObjective.step_cpu_p95_ms: "compute per controller call, p95 (CPU), median over seeds "
                                     "[ms]",
    ParetoObjective.input_cpu_p95_ms: "compute per controller call up to its input, p95 (CPU), "
                                      "median over seeds [ms]",
    ParetoObjective.step_m4_p95_ms: "Cortex-M4 estimate per controller call, p95, median over "
                                    "seeds [ms]",
}
#: the summary field a per-seed objective is the median of
_PER_SEED = {ParetoObjective.arrival_s: "arrival_time_s",
             ParetoObjective.tracking_rms_m: "rms_position",
             ParetoObjective.step_m4_p95_ms: "step_m4_p95_ms"}
#: objective values closer than this fraction of the larger one's magnitude are a tie for
#: dominance (below any difference a closed-loop objective resolves)
TIE_TOLERANCE = 1e-3
#: the objectives of a sweep that says none
DEFAULT_OBJECTIVES = (ParetoObjective.arrival_s, ParetoObjective.step_p95_ms)


def parse_objectives(names: Sequence[str] | str | None, key: str = "pareto.objectives",
                     ) -> tuple[ParetoObjective, ...]:
    """``["arrival_s", "step_p95_ms"]`` (or ``"arrival_s,step_p95_ms"``) as objectives; at
    least two, each once."""
    if names is None:
        return DEFAULT_OBJECTIVES
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    out = tuple(parse_choice(ParetoObjective, n, key) for n in names)
    if len(out) < 2 or len(set(out)) != len(out):
        raise ConfigError(f"{key} must name at least two different objectives, got "
                          f"{list(map(str, names))}; valid: "
                          f"{', '.join(o.value for o in ParetoObjective)}")
    return out


def point_keys(df: pd.DataFrame) -> list[str]:
    """The parameters that make a point: those the sweep varies, except the seed, and the
    backend where it varies (for a ``controller`` group, whose column holds the summary's
    controller name, which two choices can share: ``casadi`` for fatrop and IPOPT)."""
    varied = [p for p in df.attrs.get("params", []) if p in df and p not in NOT_GROUPED
              and df[p].astype(str).nunique(dropna=False) > 1]
    if "backend" in df and df["backend"].nunique(dropna=False) > 1:
        return ["backend", *(p for p in varied if p != "controller")]
    return varied


def pareto_points(
    df: pd.DataFrame, objectives: Sequence[ParetoObjective],
    step_ms: Mapping[str, np.ndarray] | None = None,
    default: Mapping[str, Any] | None = None,
) -> pd.DataFrame:
    """One row per point of the runs table ``df`` (:func:`mpclab.tables.collect_runs`):
    its parameters, ``overrides``, the seeds' outcomes, each objective with its spread, and
    the flags ``feasible``, ``front``, ``knee`` and ``default`` (module docstring).

    ``step_ms``: each run's controller-call times [ms] by run folder (else read from its
    steps); ``default``: the shipped values of the point's parameters.
    """
    keys = point_keys(df)
    rows = []
    groups = df.groupby(keys, dropna=False, sort=True) if keys else [((), df)]
    for values, g in groups:
        values = values if isinstance(values, tuple) else (values,)
        point = dict(zip(keys, values, strict=True))
        misses = numeric_column(g, "deadline_misses").fillna(0).sum()
        row = {**point, "overrides": point_overrides(point),
               "runs": len(g), "arrived": int((g["status"] == "arrived").sum()),
               "collisions": int((g["status"] == "collision").sum()),
               "errors": int((g["status"] == "error").sum()), "deadline_misses": int(misses),
               "seeds": ",".join(str(s) for s in g["seed"].tolist()) if "seed" in g else ""}
        row["feasible"] = (row["arrived"] == row["runs"] and row["errors"] == 0
                           and row["collisions"] == 0 and row["deadline_misses"] == 0)
        for obj in objectives:
            row.update(_objective(obj, g, step_ms or {}))
        rows.append(row)
    out = pd.DataFrame(rows)
    names = [o.value for o in objectives]
    out["front"] = _non_dominated(out, names)
    out["knee"] = _knee(out, names)
    out["default"] = _is_default(out, keys, default) if default else False
    out.attrs["keys"], out.attrs["objectives"] = keys, names
    return out


def point_overrides(point: Mapping[str, Any]) -> str:
    """A point's parameters as overrides: ``controller.horizon=10 controller.dt=0.2``."""
    return " ".join(f"{k}={override_value(v)}" for k, v in point.items())


def first_seed_runs(df: pd.DataFrame, points: pd.DataFrame) -> dict[str, str]:
    """The run folder of each front point's first seed (the lowest), by its ``overrides``:
    ``df`` the runs table the ``points`` were made from (:func:`pareto_points`)."""
    keys = points.attrs.get("keys", [])
    if df.empty or "run_dir" not in df:
        return {}
    by_point = df.apply(lambda r: point_overrides({k: r[k] for k in keys}), axis=1)
    ordered = df.assign(_point=by_point).sort_values(
        ["seed"] if "seed" in df else ["run_dir"], kind="stable")
    first = ordered.groupby("_point", sort=False)["run_dir"].first()
    return {o: str(first[o]) for o in front(points)["overrides"] if o in first.index}


def front(points: pd.DataFrame) -> pd.DataFrame:
    """The front's points, ordered by the first objective."""
    names = points.attrs.get("objectives", [])
    out = points[points["front"]].sort_values(names[:1] or ["overrides"], kind="stable")
    out.attrs.update(points.attrs)
    return out


def _objective(obj: ParetoObjective, g: pd.DataFrame,
               step_ms: Mapping[str, np.ndarray]) -> dict[str, float]:
    """An objective's value for the runs ``g`` of one point, and its spread over seeds."""
    if obj in _PER_SEED:
        per_seed = numeric_column(g, _PER_SEED[obj]).dropna()
    else:
        per_run = [_call_ms(r, obj, step_ms) for r in g["run_dir"]]
        per_seed = pd.Series([np.percentile(v, 95) for v in per_run if v.size], dtype=float)
    value = float(per_seed.median()) if len(per_seed) else math.nan
    lo = float(per_seed.min()) if len(per_seed) else math.nan
    hi = float(per_seed.max()) if len(per_seed) else math.nan
    return {obj.value: value, f"{obj.value}_min": lo, f"{obj.value}_max": hi}


def _call_ms(run_dir: str, obj: ParetoObjective,
             step_ms: Mapping[str, np.ndarray]) -> np.ndarray:
    """A run's controller-call times [ms], wall or CPU (none for a run without steps)."""
    steps = Path(run_dir) / record.STEPS
    if obj is ParetoObjective.step_p95_ms:
        if run_dir in step_ms:
            return np.asarray(step_ms[run_dir], dtype=float)
        return record.read_solve_times_s(Path(run_dir)) * 1e3 if steps.is_file() else np.zeros(0)
    if not steps.is_file():
        return np.zeros(0)
    calls = record.controller_steps(pd.read_parquet(steps))
    column = ("feedback_cpu_s" if obj is ParetoObjective.input_cpu_p95_ms
              and "feedback_cpu_s" in calls else "solve_cpu_s")
    if column not in calls:
        return np.zeros(0)
    return pd.to_numeric(calls[column], errors="coerce").dropna().to_numpy() * 1e3


def _non_dominated(points: pd.DataFrame, names: list[str]) -> pd.Series:
    """Feasible points with every objective finite that no such point dominates (ties
    within :data:`TIE_TOLERANCE`)."""
    if points.empty:
        return pd.Series(dtype=bool)
    F = points[names].to_numpy(dtype=float)
    ok = points["feasible"].to_numpy(dtype=bool) & np.isfinite(F).all(axis=1)
    on = np.zeros(len(points), dtype=bool)
    for i in np.flatnonzero(ok):
        others = F[ok]
        tie = TIE_TOLERANCE * np.maximum(np.abs(others), np.abs(F[i]))
        no_worse = (others <= F[i] + tie).all(axis=1)
        better = (others < F[i] - tie).any(axis=1)
        on[i] = not (no_worse & better).any()
    return pd.Series(on, index=points.index)


def _knee(points: pd.DataFrame, names: list[str]) -> pd.Series:
    """The front point nearest the ideal one, objectives scaled to [0, 1] over the front."""
    knee = pd.Series(False, index=points.index)
    on = points[points["front"]] if len(points) else points
    if len(on) < 3:  # two points have no knee between them
        return knee
    F = on[names].to_numpy(dtype=float)
    span = F.max(axis=0) - F.min(axis=0)
    scaled = (F - F.min(axis=0)) / np.where(span > 0, span, 1.0)
    knee[on.index[int(np.argmin(np.linalg.norm(scaled, axis=1)))]] = True
    return knee


def _is_default(points: pd.DataFrame, keys: list[str], default: Mapping[str, Any],
                ) -> pd.Series:
    """The points whose parameters all equal ``default``'s (the shipped configuration)."""
    if not keys or any(k not in default for k in keys):
        return pd.Series(False, index=points.index)
    want = {k: override_value(default[k]) for k in keys}
    return points.apply(lambda r: all(override_value(r[k]) == want[k] for k in keys), axis=1)


def override_value(value: Any) -> str:
    """A parameter value as an override writes it (``null`` for none, ``3`` for 3.0)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "null"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    if isinstance(value, list | tuple):
        return "[" + ",".join(override_value(v) for v in value) + "]"
    return str(value).replace(" ", "")
