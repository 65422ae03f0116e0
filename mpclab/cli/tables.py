"""``python -m mpclab.cli.tables PATH [PATH ...]``: the tables and the figure of any run records.

Aggregates every run record found below the given folders (one sweep, several sweeps, a whole
``outputs/``) into ``summary.parquet``, ``summary.csv``, ``summary.md``, ``groups.csv`` and
``arrival_vs_compute.png`` in ``--out`` (default: the first PATH); with ``--pareto`` also the
Pareto front, with ``--rerun`` its runs side by side in one Rerun file
(:mod:`mpclab.sweeps.report`). The table it prints (the grouped one, or the front) is stamped
(command, commit, CPU, date); ``--md FILE`` writes it to a file as well, for a page to show.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mpclab import tables
from mpclab.core.errors import ConfigError, exit_on_bad_input
from mpclab.record.provenance import write_stamped
from mpclab.sweeps.front_replay import FRONT_RECORDING, replay_front, replay_lines
from mpclab.sweeps.pareto import write_pareto
from mpclab.sweeps.report import write_report
from mpclab.tables import XAxis
from mpclab.tables.pareto import ParetoObjective, front


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mpclab.cli.tables", description=__doc__.split("\n\n")[0],
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
    parser.add_argument("--md", type=Path, default=None,
                        help="also write the printed table (with --pareto: the front or "
                             "--points), stamped, to this file")
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
    shown_table = tables.markdown_table(report.groups)
    if args.pareto:
        print(shown_table)
        objectives = points.attrs["objectives"]
        if args.points:
            spread = [f"{o}{s}" for o in objectives for s in ("", "_min", "_max")]
            shown = ["overrides", "runs", "arrived", *spread, "front", "knee", "default"]
            title, table = "Every point", points
        else:
            shown = ["overrides", "runs", *objectives, "knee", "default"]
            title, table = "Pareto front", front(points)
        shown = [c for c in shown if c in table]
        print(f"\n## {title}\n")
        shown_table = tables.markdown_table(table[shown])
    try:
        write_stamped(args.md, shown_table)
    except OSError as exc:  # an --md that cannot be written
        exit_on_bad_input(parser, exc)
    if args.rerun:
        print("\n" + replay_lines(merged, replayed))
    print(f"\n{len(report.runs)} runs -> " + ", ".join(str(p) for p in report.files.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
