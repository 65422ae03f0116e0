"""``python -m mpclab.cli.merge PATH [PATH ...] [-o FILE]``: run recordings side by side.

Usage::

    uv run python -m mpclab.cli.merge outputs/multirun/NAME/TIME            # -> sweep.rrd
    uv run python -m mpclab.cli.merge RUN_A/run.rrd RUN_B/run.rrd -o both.rrd
    uv run rerun outputs/multirun/NAME/TIME/sweep.rrd

A folder argument stands for every ``run.rrd`` below it (:mod:`mpclab.recorders.merge`).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mpclab.core.errors import exit_on_bad_input
from mpclab.recorders.merge import MERGED, find_recordings, merge, run_labels
from mpclab.recorders.rerun import RRD


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mpclab.cli.merge",
        description="Merge run recordings (run.rrd) into one, each run under its own prefix.",
    )
    parser.add_argument("paths", nargs="+", type=Path,
                        help=f"{RRD} files, or folders searched for {RRD} (a sweep's folder)")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help=f"merged file (default: {MERGED} in the first folder given, "
                             "or next to the first file's run folder)")
    args = parser.parse_args(argv)
    try:
        rrds = find_recordings(args.paths)
        out = args.output or _default_output(args.paths[0])
        labels = run_labels(rrds)
        merge(rrds, out, labels)
    except OSError as exc:  # nothing to merge, an output that cannot be written
        exit_on_bad_input(parser, exc)
    print(f"merged {len(rrds)} recordings into {out}:")
    for label, rrd in zip(labels, rrds, strict=True):
        print(f"  /{label}  <- {rrd}")
    print(f"open it with: uv run rerun {out}")
    return 0


def _default_output(first: Path) -> Path:
    return first / MERGED if first.is_dir() else first.parent.parent / MERGED


if __name__ == "__main__":
    raise SystemExit(main())
