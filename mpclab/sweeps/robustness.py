"""The robustness figure of a sweep over a ``sim.*`` level (noise, latency scale, mismatch).

Success rate with its exact 95 % interval (Clopper-Pearson) and the median arrival time of
the runs that arrived, against the swept level, one line per backend. The sweep's callback
draws one ``robustness_<key>.png`` per swept numeric ``sim.*`` key.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from mpclab.stats import clopper_pearson  # noqa: E402


def robustness_levels(df: pd.DataFrame) -> list[str]:
    """The swept ``sim.*`` parameters with more than one numeric level."""
    out = []
    for key in df.attrs.get("params", []):
        if key.startswith("sim.") and key in df:
            levels = pd.to_numeric(df[key], errors="coerce")
            if levels.notna().all() and levels.nunique() > 1:
                out.append(key)
    return out


def robustness_table(df: pd.DataFrame, level: str) -> pd.DataFrame:
    """Per backend and level: runs, arrived, success rate and its 95 % interval, median
    arrival time."""
    rows = []
    levels = pd.to_numeric(df[level], errors="coerce")
    for (backend, value), g in df.assign(_level=levels).groupby(["backend", "_level"],
                                                                sort=True):
        arrived = g["status"] == "arrived"
        lo, hi = clopper_pearson(int(arrived.sum()), len(g))
        rows.append({"backend": backend, level: value, "runs": len(g),
                     "arrived": int(arrived.sum()), "success_rate": float(arrived.mean()),
                     "success_low": lo, "success_high": hi,
                     "arrival_median_s": float(g.loc[arrived, "arrival_time_s"].median())
                     if arrived.any() else np.nan})
    return pd.DataFrame(rows)


def plot_robustness(df: pd.DataFrame, level: str, path: Path, dpi: int = 110) -> Path:
    """Success rate (with its interval) and median arrival against ``level``."""
    table = robustness_table(df, level)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.5, 5.5), sharex=True)
    for backend, g in table.groupby("backend", sort=True):
        x = g[level].to_numpy(dtype=float)
        err = np.vstack([g["success_rate"] - g["success_low"],
                         g["success_high"] - g["success_rate"]])
        (line,) = top.plot(x, g["success_rate"], "o-", label=backend)
        top.errorbar(x, g["success_rate"], yerr=err, fmt="none", ecolor=line.get_color(),
                     capsize=3, alpha=0.7)
        bottom.plot(x, g["arrival_median_s"], "o-", color=line.get_color())
    top.set_ylabel("success rate (95 % interval)")
    top.set_ylim(-0.05, 1.05)
    top.grid(True, alpha=0.3)
    top.legend(fontsize=8)
    bottom.set_ylabel("median arrival time [s]")
    bottom.set_xlabel(level)
    bottom.grid(True, alpha=0.3)
    xs = table[level].to_numpy(dtype=float)
    if (xs > 0).all() and xs.max() > 20 * xs.min():
        bottom.set_xscale("log")
    top.set_title(f"robustness: {len(df)} runs", fontsize=10, loc="left")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
