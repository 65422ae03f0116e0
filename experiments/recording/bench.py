"""What recording costs: whole runs with ``recorder=rerun`` against ``recorder=none``.

For each experiment named, one process composes it twice (figures off, no progress line),
runs one warm-up of each (importing rerun and its first recording happen once per process;
their cost is printed separately), then alternates ``--rounds`` pairs (none, rerun / rerun,
none, ...) and times ``run_experiment`` from config to written run record: the run's wall time,
and the CPU time of the whole process (rerun's writer threads included), which other jobs on
the machine disturb less.

    uv run python experiments/recording/bench.py car_cvxpy [zumo_bug2 ...] [--rounds 7]
        [--override KEY=VALUE ...]   # extra Hydra overrides for every run
        [--md FILE]                  # also write the stamped table there

The table is printed with its stamp (command, commit, CPU, date).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.config.registry import register_all
from mpclab.record.provenance import write_stamped
from mpclab.runner.single_run import compose, run_experiment

RECORDERS = ("none", "rerun")


def compose_run(experiment: str, recorder: str, overrides: list[str]):
    return compose([f"+experiment={experiment}", f"recorder={recorder}", "figures.enabled=false",
                    "progress=false", *overrides])


def timed_run(cfg, out: Path) -> tuple[float, dict]:
    """Wall time [s] of one run from config to written record, and its summary."""
    seconds, _, summary = timed_run_cpu(cfg, out)
    return seconds, summary


def timed_run_cpu(cfg, out: Path) -> tuple[float, float, dict]:
    """Wall and CPU time [s] (every thread of this process) of one run, and its summary."""
    c0, t0 = time.process_time(), time.perf_counter()
    result = run_experiment(cfg, out)
    return time.perf_counter() - t0, time.process_time() - c0, result.summary


def bench(experiment: str, rounds: int, overrides: list[str], tmp: Path) -> dict:
    cfgs = {rec: compose_run(experiment, rec, overrides) for rec in RECORDERS}
    t_import = time.perf_counter()
    import rerun  # noqa: F401  (a one-time cost, measured on its own)

    t_import = time.perf_counter() - t_import
    warm = {rec: timed_run(cfgs[rec], tmp / f"{experiment}_warm_{rec}")[0] for rec in RECORDERS}
    times: dict[str, list[float]] = {rec: [] for rec in RECORDERS}
    cpu: dict[str, list[float]] = {rec: [] for rec in RECORDERS}
    summary: dict = {}
    for i in range(rounds):
        order = RECORDERS if i % 2 == 0 else RECORDERS[::-1]
        for rec in order:
            seconds, cpu_s, summary = timed_run_cpu(cfgs[rec], tmp / f"{experiment}_{i}_{rec}")
            times[rec].append(seconds)
            cpu[rec].append(cpu_s)
    none, rerun_ = np.asarray(times["none"]), np.asarray(times["rerun"])
    cpu_none, cpu_rerun = np.median(cpu["none"]), np.median(cpu["rerun"])
    rrd = tmp / f"{experiment}_0_rerun" / "run.rrd"
    return {
        "experiment": experiment,
        "status": summary.get("status"),
        "steps": summary.get("n_steps"),
        "rounds": rounds,
        "none_median_s": float(np.median(none)),
        "rerun_median_s": float(np.median(rerun_)),
        "overhead_pct": 100 * (float(np.median(rerun_)) / float(np.median(none)) - 1),
        "pairwise_overhead_pct": 100 * float(np.median(rerun_ / none) - 1),
        "cpu_overhead_pct": 100 * float(cpu_rerun / cpu_none - 1),
        "rrd_kib": rrd.stat().st_size / 1024,
        "first_rerun_run_s": warm["rerun"],
        "import_rerun_s": t_import,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiments", nargs="+", help="experiment names (conf/experiment/)")
    parser.add_argument("--rounds", type=int, default=7, help="alternating pairs of runs")
    parser.add_argument("--override", action="append", default=[],
                        help="Hydra override applied to every run (repeatable)")
    parser.add_argument("--md", type=Path, help="also write the stamped table here")
    argv = list(sys.argv if argv is None else argv)
    args = parser.parse_args(argv[1:])
    register_all()
    rows = []
    with tempfile.TemporaryDirectory(prefix="mpclab_rec_bench_") as tmp:
        for name in args.experiments:
            rows.append(bench(name, args.rounds, args.override, Path(tmp)))
            print(f"{name}: done", file=sys.stderr)
    table = pd.DataFrame(rows)
    write_stamped(args.md, table.to_markdown(index=False, floatfmt=".3f"), argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
