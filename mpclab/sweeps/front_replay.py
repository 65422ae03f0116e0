"""A sweep's Pareto front replayed side by side: its points' recordings merged into one file.

``python -m mpclab.cli.tables --pareto DIR --rerun`` (or ``rerun: true`` beside the objectives in
``hydra.callbacks.sweep.pareto``, at the end of a sweep) writes ``DIR/pareto_front.rrd``: for
each front point the recording of its first seed (the lowest), under a prefix named by the
point's parameters (``casadi_fatrop_horizon_6_control_horizon_2``), the maps side by side and
the signals overlaid (:mod:`mpclab.recorders.merge`). Open it with ``uv run rerun FILE``.

A point whose run was recorded (its ``run.rrd``) is taken as it is. The Pareto sweeps run
without a recorder (``recorder=none``), so the others are run again, one process each: the
sweep's job as its ``.hydra`` record has it (its overrides, the sweeper and launcher chosen,
from the folder it was launched in) with ``recorder=rerun``, into ``DIR/front_runs/PREFIX/``
(which the tables leave out: :data:`mpclab.tables.REPLAYED_RUNS`). A run is repeatable on
its config and seed where the simulation is (``sim=nominal``; not under
``sim.latency=measured``), so each re-run's outcome (status, arrival time, steps) is checked
against the sweep's run and a difference is reported. A re-run already recorded with the
same overrides is reused.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import yaml

from mpclab import tables
from mpclab.record import files as record
from mpclab.recorders.merge import entity_name, merge, run_overrides
from mpclab.recorders.rerun import RRD
from mpclab.sweeps.pareto import point_label
from mpclab.tables.pareto import first_seed_runs, front

#: the merged recording, in the front's folder
FRONT_RECORDING = "pareto_front.rrd"
#: the recorder a re-run records with
RECORDER = "recorder=rerun"
#: summary fields that must agree between a run and its re-run
REPEATED = ("status", "arrival_time_s", "n_steps")


@dataclass
class ReplayedPoint:
    """One front point in the merged file (``rrd`` None: it could not be recorded)."""

    label: str
    overrides: str
    source: Path
    rrd: Path | None
    recorded_again: bool
    note: str = ""


def replay_front(paths: Sequence[Path], out_dir: Path, points: pd.DataFrame,
                 ) -> tuple[Path | None, list[ReplayedPoint]]:
    """Merge the front of ``points`` (:func:`mpclab.tables.pareto.pareto_points` of the runs
    below ``paths``) into ``out_dir/pareto_front.rrd``, recording its runs again where the
    sweep did not. Returns the file (None when no point could be recorded) and the points."""
    out_dir = Path(out_dir)
    df, _ = tables.collect_runs(paths, root=out_dir)
    first_runs = first_seed_runs(df, points)
    keys = points.attrs.get("keys", [])
    replayed = []
    for _, row in front(points).iterrows():
        if row["overrides"] not in first_runs:
            continue
        source = Path(first_runs[row["overrides"]])
        label = entity_name(point_label(row, keys) if keys else source.name)
        if (source / RRD).is_file():
            replayed.append(ReplayedPoint(label, row["overrides"], source, source / RRD, False))
        else:
            rrd, note = record_again(source, out_dir / tables.REPLAYED_RUNS / label)
            replayed.append(ReplayedPoint(label, row["overrides"], source, rrd, True, note))
    recorded = {p.label: p.rrd for p in replayed if p.rrd is not None}
    if not recorded:
        return None, replayed
    return merge(list(recorded.values()), out_dir / FRONT_RECORDING, list(recorded)), replayed


def rerun_command(run_dir: Path, dest: Path) -> tuple[list[str], Path]:
    """``(arguments of python -m mpclab, folder to run in)`` that run the sweep's job
    ``run_dir`` again with a Rerun recording into ``dest``."""
    task = [o for o in run_overrides(run_dir)
            if tables.override_key(o) != "recorder" and not o.startswith("hydra")]
    hydra_groups, cwd = [], Path.cwd()
    try:
        hydra_cfg = yaml.safe_load((run_dir / ".hydra" / "hydra.yaml").read_text())["hydra"]
        hydra_groups = [o for o in hydra_cfg["overrides"]["hydra"] if o.startswith("hydra/")]
        cwd = Path(hydra_cfg["runtime"]["cwd"])
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        pass  # a run without Hydra's record: its summary's overrides, from here
    args = [*task, RECORDER, *hydra_groups, f"hydra.run.dir={Path(dest).resolve()}"]
    return args, cwd if cwd.is_dir() else Path.cwd()


def record_again(run_dir: Path, dest: Path) -> tuple[Path | None, str]:
    """Run the job ``run_dir`` again into ``dest`` with a Rerun recording (reused when
    ``dest`` already holds it); ``(its run.rrd or None, what differs or failed)``."""
    args, cwd = rerun_command(run_dir, dest)
    task = [a for a in args if not a.startswith("hydra")]
    if not _recorded_with(dest, task):
        shutil.rmtree(dest, ignore_errors=True)
        proc = subprocess.run([sys.executable, "-m", "mpclab", *args], cwd=cwd,
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0 or not (dest / RRD).is_file():
            last = (proc.stderr.strip() or proc.stdout.strip() or "no output").splitlines()[-1]
            return None, f"not recorded: `python -m mpclab {' '.join(args)}` failed: {last}"
    return dest / RRD, _difference(run_dir, dest)


def _recorded_with(dest: Path, task: list[str]) -> bool:
    """``dest`` holds a complete recorded run of exactly the overrides ``task``."""
    return ((dest / RRD).is_file() and (dest / record.SUMMARY).is_file()
            and run_overrides(dest) == task)


def _difference(run_dir: Path, again: Path) -> str:
    """What the re-run ``again`` did otherwise than the sweep's run (empty: nothing)."""
    try:
        a = record.read_summary(run_dir)
        b = record.read_summary(again)
    except (OSError, ValueError) as exc:
        return f"not compared: {exc}"
    differ = [f"{k} {b.get(k)} against the sweep's {a.get(k)}" for k in REPEATED
              if not _same(a.get(k), b.get(k))]
    return ("the re-run differs: " + ", ".join(differ)) if differ else ""


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)
    return a == b


def replay_lines(merged: Path | None, replayed: Sequence[ReplayedPoint]) -> str:
    """What :func:`replay_front` did, a line per point and how to open the file."""
    if not replayed:
        return "no front point to replay"
    lines = [f"front replay: {len(replayed)} points -> {merged or 'nothing recorded'}"]
    for p in replayed:
        how = "recorded again" if p.recorded_again else "the sweep's recording"
        lines.append(f"  /{p.label}  <- {p.source} ({how}){'; ' + p.note if p.note else ''}")
    if merged is not None:
        lines.append(f"open it with: uv run rerun {merged}")
    return "\n".join(lines)
