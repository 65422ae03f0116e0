"""A sweep's report: the tables of :mod:`mpclab.tables` and the arrival-vs-compute figure.

:func:`write_report` (the command ``python -m mpclab.cli.tables PATH [PATH ...]``)
aggregates every run record found below the given folders (one sweep, several sweeps, a whole
``outputs/``) into ``summary.parquet``, ``summary.csv``, ``summary.md``, ``groups.csv`` and
``arrival_vs_compute.png`` in ``--out`` (default: the first PATH), and for a sweep over a
numeric ``sim.*`` level (noise, latency scale, mismatch) ``robustness_<level>.png``; with
``--pareto`` also the Pareto front (``pareto.csv``, ``pareto.png``, ``pareto_points.csv``:
:mod:`mpclab.sweeps.pareto`), and with ``--rerun`` its runs side by side in one Rerun file
(:mod:`mpclab.sweeps.front_replay`). The multirun callback does the same for each sweep folder when
it ends, from the rows the jobs streamed.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from mpclab import tables
from mpclab.sweeps.figure import plot_arrival_vs_compute
from mpclab.sweeps.robustness import plot_robustness, robustness_levels
from mpclab.tables import XAxis

FIGURE = "arrival_vs_compute.png"


@dataclass
class Report:
    """The runs table, the grouped table and the files written."""

    runs: pd.DataFrame
    groups: pd.DataFrame
    files: dict[str, Path]


def write_report(
    paths: Iterable[Path], out_dir: Path, figure: bool = True, x: XAxis = XAxis.STEP_MS,
) -> Report:
    """Collect the runs below ``paths``; write tables (and the figure) into ``out_dir``.

    Nothing is written when there are no runs.
    """
    df, step_ms = tables.collect_runs(paths, root=out_dir)
    if df.empty:
        return Report(df, pd.DataFrame(), {})
    groups = tables.group_table(df, step_ms)
    files = tables.write_tables(df, out_dir, groups)
    if figure:
        files["figure"] = plot_arrival_vs_compute(df, Path(out_dir) / FIGURE, XAxis(x))
        for level in robustness_levels(df):  # a sweep over a sim.* level
            files[f"robustness:{level}"] = plot_robustness(
                groups, level, Path(out_dir) / f"robustness_{level.removeprefix('sim.')}.png")
    return Report(df, groups, files)
