"""The sweep figure: arrival time against compute, one colour and marker per configuration.

A configuration is one value of every parameter the sweep varies except the seed
(:func:`mpclab.tables.group_keys`: the backend, the scenario and every swept key), so a sweep
over ``controller.horizon=8,10`` draws two. The compute axis is wall time, or CPU time when
some run was contended (:func:`mpclab.tables.contended`: its wall times are inflated). Runs
that did not arrive get a strip of their own below, drawn only when there are such runs.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from mpclab.core.lazy_import import pyplot
from mpclab.record.figure_file import save_figure
from mpclab.tables import XAxis, group_keys, numeric_column

#: per x axis: (wall column, CPU column, label, unit)
_X = {
    XAxis.STEP_MS: ("compute_median_ms", "compute_cpu_median_ms", "median {} per step", "ms"),
    XAxis.RTF: ("rtf", "_cpu_rtf", "{} / simulated time", ""),
}
_MARKERS = "os^Dv<>P*Xph"
#: the colour cycle (tab10); with the markers, 10 x 12 configurations stay apart
_N_COLOURS = 10


def configurations(df: pd.DataFrame) -> tuple[pd.Series, list[str], str]:
    """Each run's configuration as a legend label, the labels in the order of their values
    (numbers as numbers), and the legend's title: the values of the grouping keys that vary
    (``controller.horizon=8``; backend and scenario by name)."""
    keys = group_keys(df)
    varying = [k for k in keys if k in df and df[k].astype(str).nunique(dropna=False) > 1]
    shown = varying or ["backend"]

    def label(row: pd.Series) -> str:
        return ", ".join(str(row[k]) if k in ("backend", "scenario") else f"{k}={row[k]}"
                         for k in shown)

    title = ", ".join(k for k in shown if k in ("backend", "scenario")) or "configuration"
    if not len(df):
        return pd.Series(dtype=str), [], title
    labels = df.apply(label, axis=1)
    order = labels[df.sort_values(shown, kind="stable", na_position="last").index]
    return labels, list(dict.fromkeys(order)), title


def compute_axis(df: pd.DataFrame, x: XAxis) -> tuple[pd.Series, str]:
    """The x values of every run and the axis label: CPU time when some run was contended
    and every timed run has its CPU time, else wall time."""
    wall_col, cpu_col, text, unit = _X[XAxis(x)]
    wall = numeric_column(df, wall_col)
    if cpu_col == "_cpu_rtf":
        cpu = numeric_column(df, "compute_cpu_total_s") / numeric_column(df, "sim_time_s")
    else:
        cpu = numeric_column(df, cpu_col)
    flagged = df["contended"].fillna(False).astype(bool) if "contended" in df else None
    n = 0 if flagged is None else int(flagged.sum())
    if n and cpu[wall.notna()].notna().all():
        label = text.format("CPU time") + (f" [{unit}]" if unit else "")
        return cpu, f"{label}\n({n} of {len(df)} runs contended: CPU time, not wall time)"
    label = text.format("compute (wall)") + (f" [{unit}]" if unit else "")
    return wall, label + (f"\n({n} runs contended)" if n else "")


def plot_arrival_vs_compute(
    df: pd.DataFrame, path: Path, x: XAxis = XAxis.STEP_MS, dpi: int = 110,
) -> Path:
    """Arrivals (time against compute) above; runs that did not arrive in a strip below.

    Parameters
    ----------
    df
        A runs table from :func:`mpclab.tables.collect`.
    path
        The PNG to write.
    x
        ``step_ms``: median compute per controller step; ``rtf``: compute / simulated time.
    """
    plt = pyplot()
    df = df.assign(**{c: df.get(c) for c in ("arrival_time_s", "experiment")})
    configs, names, legend_title = configurations(df)
    style = {c: (plt.cm.tab10(i % _N_COLOURS), _MARKERS[(i // _N_COLOURS + i) % len(_MARKERS)])
             for i, c in enumerate(names)}
    xs, xlabel = compute_axis(df, x)
    arrived = (df["status"] == "arrived") & xs.notna()
    failed = (df["status"] != "arrived") & xs.notna()
    untimed = int(xs.isna().sum())
    statuses = sorted(df.loc[failed, "status"].fillna("?").unique())
    panels = [p for p, have in (("arrived", arrived.any()), ("failed", failed.any())) if have]
    ratios = [4 if p == "arrived" else max(1, len(statuses)) for p in panels] or [1]
    fig, axes = plt.subplots(len(ratios), 1, figsize=(7.0, 1.2 + sum(ratios)), sharex=True,
                             gridspec_kw={"height_ratios": ratios}, squeeze=False)
    axes = list(axes[:, 0])
    by_panel = dict(zip(panels, axes, strict=False))
    for name in names:
        colour, marker = style[name]
        mine = configs == name
        if "arrived" in by_panel and (arrived & mine).any():
            by_panel["arrived"].scatter(xs[arrived & mine], df.loc[arrived & mine,
                                        "arrival_time_s"], color=colour, marker=marker, s=40,
                                        alpha=0.85, edgecolors="none")
        if "failed" in by_panel and (failed & mine).any():
            ys = [statuses.index(s) for s in df.loc[failed & mine, "status"].fillna("?")]
            by_panel["failed"].scatter(xs[failed & mine], ys, color=colour, marker=marker,
                                       s=40, alpha=0.85, edgecolors="none")
    if "arrived" in by_panel:
        ax = by_panel["arrived"]
        ax.set_ylabel("arrival time [s]")
        ax.grid(True, alpha=0.3)
    if "failed" in by_panel:
        ax = by_panel["failed"]
        ax.set_yticks(range(len(statuses)), statuses)
        ax.set_ylim(-0.7, len(statuses) - 0.3)
        ax.set_ylabel("did not arrive")
        ax.grid(True, axis="x", alpha=0.3)
    if not panels:
        axes[0].set_axis_off()
        axes[0].text(0.5, 0.5, "no run has compute timing", ha="center", va="center")
    else:
        axes[-1].set_xlabel(xlabel)
        timed = xs.dropna()
        if len(timed) and (timed > 0).all() and timed.max() > 20 * timed.min():
            axes[-1].set_xscale("log")  # backends decades apart
            axes[-1].xaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v:g}"))
        handles = [plt.Line2D([], [], color=style[n][0], marker=style[n][1], ls="none", ms=7)
                   for n in names]
        axes[0].legend(handles, names, title=legend_title, loc="upper left",
                       bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=8,
                       title_fontsize=8)
    experiments = sorted(df["experiment"].dropna().astype(str).unique())
    what = (", ".join(experiments) if len(experiments) <= 3 else
            f"{len(experiments)} experiments") or "sweep"
    counts = f"{int(arrived.sum())} of {len(df)} runs arrived" + (
        f"; {untimed} without timing (e.g. errors before the first step)" if untimed else "")
    axes[0].set_title(f"{what}: arrival time against compute\n{counts}", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi)
