"""The sweep figure: arrival time against compute, one marker per run, coloured by backend."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from mpclab.lazy import pyplot
from mpclab.tables import XAxis

_X = {
    XAxis.STEP_MS: ("compute_median_ms", "median compute per step [ms]"),
    XAxis.RTF: ("rtf", "compute time / simulated time"),
}
#: marker per scenario (cycled), so that scenarios stay apart within a backend's colour
_MARKERS = "os^Dv<>P*X"


def plot_arrival_vs_compute(
    df: pd.DataFrame, path: Path, x: XAxis = XAxis.STEP_MS, dpi: int = 110,
) -> Path:
    """Arrivals above (time against compute); runs that did not arrive in a strip below.

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
    xcol, xlabel = _X[XAxis(x)]
    df = df.assign(**{c: df.get(c) for c in (xcol, "arrival_time_s", "experiment")})
    backends = sorted(df["backend"].dropna().unique())
    colours = {b: plt.cm.tab10(i % 10) for i, b in enumerate(backends)}
    scenarios = sorted(df["scenario"].fillna("?").unique())
    markers = {s: _MARKERS[i % len(_MARKERS)] for i, s in enumerate(scenarios)}
    arrived = df[df["status"] == "arrived"]
    failed = df[df["status"] != "arrived"]
    timed = failed[failed[xcol].notna()]
    statuses = sorted(failed["status"].fillna("?").unique())

    fig, (ax, axf) = plt.subplots(
        2, 1, figsize=(7.0, 5.6), sharex=True, gridspec_kw={"height_ratios": [4, 1]},
    )
    for (backend, scenario), g in arrived.groupby(["backend", "scenario"], dropna=False):
        ax.scatter(g[xcol], g["arrival_time_s"], color=colours.get(backend, "k"),
                   marker=markers.get(scenario, "o"), s=36, alpha=0.8, edgecolors="none")
    for _, r in timed.iterrows():
        axf.scatter(r[xcol], statuses.index(r["status"]), color=colours.get(r["backend"], "k"),
                    marker="x", s=40)
    for b in backends:
        ax.scatter([], [], color=colours[b], marker="o", label=b)
    if len(scenarios) > 1:
        for s in scenarios:
            ax.scatter([], [], color="0.4", marker=markers[s], label=s)
    ax.set_ylabel("arrival time [s]")
    ax.grid(True, alpha=0.3)
    if backends:
        ax.legend(loc="best", fontsize=8, title="backend" if len(scenarios) == 1 else None)
    n_untimed = len(failed) - len(timed)
    axf.set_yticks(range(len(statuses)), statuses)
    axf.set_ylim(-0.7, max(len(statuses), 1) - 0.3)
    axf.set_title(
        f"did not arrive: {len(failed)} of {len(df)}"
        + (f" ({n_untimed} without timing, e.g. errors before the first step)" if n_untimed
           else ""),
        fontsize=9, loc="left",
    )
    axf.grid(True, axis="x", alpha=0.3)
    axf.set_xlabel(xlabel)
    xs = pd.to_numeric(df[xcol], errors="coerce").dropna()
    if len(xs) and (xs > 0).all() and xs.max() > 20 * xs.min():  # backends decades apart
        axf.set_xscale("log")
        axf.xaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v:g}"))
    names = sorted(df["experiment"].dropna().astype(str).unique())
    title = ", ".join(names) if len(names) <= 3 else f"{len(names)} experiments"
    title = title or "sweep"
    ax.set_title(f"{title}: arrival time against compute ({len(df)} runs)")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)
