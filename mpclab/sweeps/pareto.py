"""A sweep's Pareto front as files: ``pareto.csv``, ``pareto.png`` and ``pareto_points.csv``.

``pareto.csv`` holds the front's points (each with its override list, its seeds' outcomes
and each objective's spread over the seeds), ``pareto_points.csv`` every point, and
``pareto.png`` draws them: every feasible point grey, the excluded ones as crosses, the front
joined and numbered (the numbers named below the axes), the shipped default marked, the
knee ringed. The multirun callback
writes them when a sweep whose config asks for a front ends (``hydra.callbacks.sweep.pareto``,
the ``sweep=pareto_*`` configs); ``python -m mpclab.cli.tables --pareto DIR`` writes them for any
sweep folder. What a point, the front, the knee and the default are:
:mod:`mpclab.tables.pareto`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from mpclab import tables
from mpclab.config.registry import COMPONENTS, register_all, target
from mpclab.core.lazy_import import pyplot
from mpclab.tables.pareto import (
    LABELS,
    ParetoObjective,
    front,
    override_value,
    pareto_points,
    parse_objectives,
    point_keys,
)

log = logging.getLogger("mpclab.sweep")
FILES = {"front": "pareto.csv", "points": "pareto_points.csv", "figure": "pareto.png"}
MULTIRUN = "multirun.yaml"


def sweep_objectives(sweep_dir: Path) -> list[str] | None:
    """The objectives the sweep's config names (``hydra.callbacks.sweep.pareto``), if any."""
    cfg = _multirun(sweep_dir)
    found = OmegaConf.select(cfg, "hydra.callbacks.sweep.pareto.objectives") if cfg else None
    return list(found) if found is not None else None


def shipped_default(sweep_dir: Path, keys: Sequence[str],
                    backends: Sequence[str] = ()) -> dict[str, Any] | None:
    """The values the sweep's base config gives the varied parameters ``keys`` (a group's
    value is its choice; ``backend``: the base controller's name, with its solver where
    ``backends``, the sweep's, name it so): Hydra's ``multirun.yaml`` is the config composed
    without the swept values. None when the sweep folder has none."""
    cfg = _multirun(sweep_dir)
    if cfg is None or not keys:
        return None
    choices = OmegaConf.select(cfg, "hydra.runtime.choices") or {}
    out = {}
    for k in keys:
        try:
            out[k] = choices[k] if k in choices else OmegaConf.select(cfg, k, default=None)
        except Exception:  # noqa: BLE001  (an interpolation that does not resolve here)
            out[k] = None
    if "backend" in keys:
        out["backend"] = _base_backend(cfg, backends)
    return out


def _base_backend(cfg: Any, backends: Sequence[str]) -> str | None:
    """The sweep's base controller as the tables name it (``casadi:fatrop``)."""
    register_all()
    wanted = OmegaConf.select(cfg, "controller._target_")
    names = [n for n, cls in COMPONENTS.get("controller", {}).items() if target(cls) == wanted]
    solver = OmegaConf.select(cfg, "controller.solver", default=None)
    for name in names:
        for candidate in (f"{name}:{solver}", name):
            if candidate in backends:
                return candidate
    return None


def write_pareto(
    paths: Sequence[Path], out_dir: Path, objectives: Sequence[str] | str | None = None,
    figure: bool = True,
) -> tuple[pd.DataFrame, dict[str, Path]]:
    """Collect the runs below ``paths``; write the front's files into ``out_dir``.

    ``objectives``: names of :class:`~mpclab.tables.pareto.ParetoObjective` (default: the
    sweep's config's, else arrival time and compute p95). Returns every point and the files.
    """
    out_dir = Path(out_dir)
    df, step_ms = tables.collect_runs(paths, root=out_dir)
    if df.empty:
        return pd.DataFrame(), {}
    chosen = parse_objectives(objectives or sweep_objectives(Path(paths[0])))
    default = shipped_default(Path(paths[0]), point_keys(df), list(df["backend"].unique()))
    points = pareto_points(df, chosen, step_ms, default)
    for name in points.attrs["objectives"]:
        if points[name].isna().all():
            log.warning("pareto: no run below %s has a value of %s, so the front is empty",
                        ", ".join(map(str, paths)), name)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {key: out_dir / name for key, name in FILES.items()}
    front(points).to_csv(files["front"], index=False)
    points.to_csv(files["points"], index=False)
    if figure:
        plot_pareto(points, files["figure"], title=_title(df))
    else:
        del files["figure"]
    return points, files


def plot_pareto(points: pd.DataFrame, path: Path, title: str = "sweep", dpi: int = 110) -> Path:
    """The first objective (y) against the second (x): every point, the front, its labels,
    the default and the knee (module docstring)."""
    plt = pyplot()
    names = points.attrs["objectives"]
    ycol, xcol = names[0], names[1]
    keys = points.attrs["keys"]
    fig, ax = plt.subplots(figsize=(8.0, 5.6))
    ok = points[points["feasible"]]
    bad = points[~points["feasible"] & points[xcol].notna() & points[ycol].notna()]
    ax.scatter(ok[xcol], ok[ycol], color="0.7", s=28, zorder=2, label="feasible point")
    if len(bad):
        ax.scatter(bad[xcol], bad[ycol], color="0.8", marker="x", s=28, zorder=2,
                   label="excluded (a seed failed to arrive or collided)")
    on = front(points)
    if len(on):
        ax.errorbar(on[xcol], on[ycol], color="0.35", lw=0.8, capsize=2, zorder=3, alpha=0.4,
                    xerr=_spread(on, xcol), yerr=_spread(on, ycol), fmt="none")
        ax.plot(on[xcol], on[ycol], "-o", color="k", ms=5, zorder=4,
                label="front (bars: its seeds' min to max)")
    for flag, style in (("knee", dict(s=220, facecolors="none", edgecolors="tab:red",
                                      linewidths=2, label="knee")),
                        ("default", dict(s=160, marker="*", color="tab:blue",
                                         label="shipped default"))):
        sel = points[points[flag]]
        if len(sel):
            ax.scatter(sel[xcol], sel[ycol], zorder=5, **style)
    excluded = int((~points["feasible"]).sum())
    ax.set_xlabel(LABELS[ParetoObjective(xcol)])
    ax.set_ylabel(LABELS[ParetoObjective(ycol)])
    ax.set_title(f"{title}: {len(on)} of {len(points)} points on the front"
                 + (f", {excluded} excluded" if excluded else ""), fontsize=10)
    xs = pd.to_numeric(points[xcol], errors="coerce").dropna()
    if len(xs) and (xs > 0).all() and xs.max() > 20 * xs.min():  # decades apart
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(plt.FuncFormatter(  # 2 and 5 of each decade, plainly
            lambda v, _: f"{v:g}" if f"{v:g}"[0] in "25" else ""))
    _frame_medians(ax, points, xcol, ycol)
    # each front point numbered at its marker and named in the key below the figure (long
    # labels beside the points overlap where the front is dense)
    key_lines = []
    for i, (_, r) in enumerate(on.iterrows(), start=1):  # alternately above and below
        _annotate(ax, str(i), r[xcol], r[ycol], 5 if i % 2 else -11, "k")
        marks = (" (knee)" if r["knee"] else "") + (" (default)" if r["default"] else "")
        key_lines.append(f"{i}: {point_label(r, keys)}{marks}")
    for _, r in points[points["default"] & ~points["front"]].iterrows():  # named, off the front
        _annotate(ax, "D", r[xcol], r[ycol], 7, "tab:blue")
        key_lines.append(f"D: {point_label(r, keys)} (default, off the front)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3, fontsize=8,
              frameon=False)  # below the axes: no point hides behind it
    fig.tight_layout()
    if key_lines:
        fig.text(0.06, -0.02, "\n".join(key_lines), ha="left", va="top", fontsize=8,
                 family="monospace")
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return Path(path)


#: a label's background, so that it reads over the lines and bars behind it
_LABEL_BOX = dict(boxstyle="round,pad=0.15", facecolor="white", edgecolor="none", alpha=0.75)


def _annotate(ax: Any, text: str, x: float, y: float, dy: float, color: str) -> None:
    """``text`` beside the point ``(x, y)``: to its right in the frame's left half, to its
    left in the right half (so that it stays in the frame)."""
    right_half = ax.transLimits.transform(ax.transScale.transform((x, y)))[0] > 0.5
    ax.annotate(text, (x, y), xytext=(-10 if right_half else 8, dy), textcoords="offset points",
                ha="right" if right_half else "left", fontsize=7, color=color, bbox=_LABEL_BOX)


def _frame_medians(ax: Any, points: pd.DataFrame, xcol: str, ycol: str) -> None:
    """Limits that hold the feasible points and the default with a margin: the seeds'
    spread (a layout's difficulty more than a configuration's) and the excluded points run
    out of the frame rather than squeezing the front into a corner."""
    shown = points[points["feasible"] | points["default"]]
    for col, set_lim, log in ((xcol, ax.set_xlim, ax.get_xscale() == "log"),
                              (ycol, ax.set_ylim, False)):
        v = pd.to_numeric(shown[col], errors="coerce").dropna()
        if v.empty:
            continue
        lo, hi = float(v.min()), float(v.max())
        if log:
            set_lim(lo / 1.3, hi * 1.3)
        else:
            pad = 0.12 * ((hi - lo) or abs(hi) or 1.0)
            set_lim(max(lo - pad, 0.0) if lo >= 0 else lo - pad, hi + pad)


def _spread(points: pd.DataFrame, col: str) -> np.ndarray:
    """``(2, n)`` error bar lengths from a value to its seeds' min and max."""
    lo = (points[col] - points[f"{col}_min"]).clip(lower=0).fillna(0)
    hi = (points[f"{col}_max"] - points[col]).clip(lower=0).fillna(0)
    return np.vstack([lo.to_numpy(dtype=float), hi.to_numpy(dtype=float)])


def point_label(row: pd.Series, keys: Sequence[str]) -> str:
    """A point's parameters, each by the last part of its key (``horizon=10``)."""
    return ", ".join(str(row[k]) if k == "backend" else
                     f"{k.rsplit('.', 1)[-1]}={override_value(row[k])}" for k in keys)


def _title(df: pd.DataFrame) -> str:
    names = sorted(df["experiment"].dropna().astype(str).unique()) if "experiment" in df else []
    return ", ".join(names) if 0 < len(names) <= 3 else "sweep"


def _multirun(sweep_dir: Path) -> Any:
    path = Path(sweep_dir) / MULTIRUN
    try:
        return OmegaConf.load(path) if path.is_file() else None
    except Exception:  # noqa: BLE001  (an unreadable record: no objectives, no default)
        return None
