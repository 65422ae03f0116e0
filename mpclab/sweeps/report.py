"""A sweep's report: the tables of :mod:`mpclab.tables` and the arrival-vs-compute figure.

``python -m mpclab.tables PATH [PATH ...]`` (or ``python -m mpclab.sweeps.report``)
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

import argparse
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from mpclab import tables
from mpclab.errors import ConfigError, exit_on_bad_input
from mpclab.provenance import stamp
from mpclab.sweeps.figure import plot_arrival_vs_compute
from mpclab.sweeps.front_replay import FRONT_RECORDING, replay_front, replay_lines
from mpclab.sweeps.pareto import write_pareto
from mpclab.sweeps.robustness import plot_robustness, robustness_levels
from mpclab.tables import XAxis
from mpclab.tables.pareto import ParetoObjective, front

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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mpclab.tables", description=__doc__.split("\n\n")[0],
    )
    parser.add_argument("paths", nargs="+", type=Path, help="outputs or sweep folders")
    parser.add_argument("--out", type=Path, help="where the tables go (default: first PATH)")
    parser.add_argument("--x", choices=[a.value for a in XAxis], default=XAxis.STEP_MS.value,
                        help="figure x axis: compute per step (ms) or compute/simulated time")
    parser.add_argument("--no-figure", action="store_true", help="tables only")
    parser.add_argument("--pareto", action="store_true",
                        help="also the Pareto front: pareto.csv, pareto.png")
    parser.add_argument("--points", action="store_true",
                        help="with --pareto: print every point with its seeds' spread, not "
                             "only the front")
    parser.add_argument("--rerun", action="store_true",
                        help=f"with --pareto: also {FRONT_RECORDING}, the front's runs (each "
                             "point's first seed) side by side in Rerun; runs the sweep did "
                             f"not record are run again into {tables.REPLAYED_RUNS}/")
    parser.add_argument("--objectives", default=None,
                        help="the front's objectives, comma-separated (default: the sweep's "
                             "config's, else arrival_s,step_p95_ms): "
                             + ", ".join(o.value for o in ParetoObjective))
    args = parser.parse_args(argv)
    out = args.out or args.paths[0]
    if (args.points or args.rerun) and not args.pareto:
        parser.error("--points and --rerun go with --pareto")
    for path in args.paths:
        if not path.exists():
            parser.error(f"no such folder: {path}")
    try:
        report = write_report(args.paths, out, figure=not args.no_figure, x=XAxis(args.x))
        if args.pareto and not report.runs.empty:
            points, files = write_pareto(args.paths, out, args.objectives,
                                         figure=not args.no_figure)
            report.files.update({f"pareto:{k}": v for k, v in files.items()})
            if args.rerun:
                merged, replayed = replay_front(args.paths, out, points)
    except (OSError, ConfigError) as exc:  # an --out that cannot be written, a bad objective
        exit_on_bad_input(parser, exc)
    if report.runs.empty:
        parser.error(f"no run records below {', '.join(map(str, args.paths))}")
    print(tables.markdown_table(report.groups))
    if args.pareto:
        objectives = points.attrs["objectives"]
        if args.points:
            spread = [f"{o}{s}" for o in objectives for s in ("", "_min", "_max")]
            shown = ["overrides", "runs", "arrived", *spread, "front", "knee", "default"]
            title, table = "Every point", points
        else:
            shown = ["overrides", "runs", *objectives, "knee", "default"]
            title, table = "Pareto front", front(points)
        shown = [c for c in shown if c in table]
        print(f"\n## {title}\n\n{tables.markdown_table(table[shown])}")
        print(f"\n{stamp()}")
    if args.rerun:
        print("\n" + replay_lines(merged, replayed))
    print(f"\n{len(report.runs)} runs -> " + ", ".join(str(p) for p in report.files.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
