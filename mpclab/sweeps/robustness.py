"""The robustness figure of a sweep over a ``sim.*`` level (noise, latency scale, mismatch),
drawn from the grouped table.

Success rate with its exact 95 % interval (Clopper-Pearson) and the median arrival time of
the runs that arrived, against the swept level, one line per backend. The sweep's callback
draws one ``robustness_<key>.png`` per swept numeric ``sim.*`` key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.core.lazy_import import pyplot
from mpclab.record.figure_file import save_figure


def robustness_levels(df: pd.DataFrame) -> list[str]:
    """The swept ``sim.*`` parameters with more than one numeric level."""
    out = []
    for key in df.attrs.get("params", []):
        if key.startswith("sim.") and key in df:
            levels = pd.to_numeric(df[key], errors="coerce")
            if levels.notna().all() and levels.nunique() > 1:
                out.append(key)
    return out


def plot_robustness(groups: pd.DataFrame, level: str, path: Path, dpi: int = 110) -> Path:
    """Success rate (with its interval) and median arrival against ``level``, one line per
    backend (and scenario, when there are several), from the sweep's grouped table
    (:func:`mpclab.tables.group_table`: its rows per swept level, with ``success_low`` and
    ``success_high``)."""
    lines = [c for c in ("backend", "scenario") if groups[c].nunique(dropna=False) > 1]
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.5, 5.5), sharex=True)
    for key, g in groups.groupby(lines or ["backend"], sort=True, dropna=False):
        g = g.assign(_x=pd.to_numeric(g[level], errors="coerce")).sort_values("_x")
        x = g["_x"].to_numpy(dtype=float)
        err = np.vstack([g["success_rate"] - g["success_low"],
                         g["success_high"] - g["success_rate"]])
        label = " / ".join(map(str, key if isinstance(key, tuple) else (key,)))
        (line,) = top.plot(x, g["success_rate"], "o-", label=label)
        top.errorbar(x, g["success_rate"], yerr=err, fmt="none", ecolor=line.get_color(),
                     capsize=3, alpha=0.7)
        bottom.plot(x, pd.to_numeric(g["arrival_median_s"], errors="coerce"), "o-",
                    color=line.get_color())
    top.set_ylabel("success rate (95 % interval)")
    top.set_ylim(-0.05, 1.05)
    top.grid(True, alpha=0.3)
    top.legend(fontsize=8)
    bottom.set_ylabel("median arrival time [s]")
    bottom.set_xlabel(level)
    bottom.grid(True, alpha=0.3)
    xs = pd.to_numeric(groups[level], errors="coerce").to_numpy(dtype=float)
    if (xs > 0).all() and xs.max() > 20 * xs.min():
        bottom.set_xscale("log")
    top.set_title(f"robustness: {int(groups['runs'].sum())} runs", fontsize=10, loc="left")
    fig.tight_layout()
    return save_figure(fig, path, dpi)
