"""Where a sweep's time goes, on 1 and 2 workers, and what that projects for more cores.

    uv run python experiments/sweeps/bench_scale.py [--jobs 48] [--rounds 1] [--wait-quiet]
        [-- OVERRIDE ...]

Runs ``python -m mpclab -m +experiment=zumo_bug2 scenario=zumo_random 'seed=range(0,N)'
recorder=none figures.enabled=false hydra.launcher.n_jobs=W`` (other overrides replace the
experiment's) for W = 1, 2 (then 2, 1 in a second round), each into a fresh sweep folder,
and reads what the sweep wrote about itself:

* the whole command's wall time (Python start to exit), from here;
* ``.mpclab/sweep.json``: when the sweep started, when its last job ended, how long the
  tables and figure took;
* ``.mpclab/tasks.jsonl`` (mpclab's pool launcher): per job, its time in the worker, the
  minor page faults of that time (a forked worker copies each inherited page it writes) and,
  of that time, its closed loop (``simulate``);
* every row in ``summary.parquet``.

From these: the serial part (before the first job starts, and after the last one ends), how
much longer the jobs themselves took two at a time (the host of a virtual machine may give
two busy cores less than twice one), the per-job time outside the closed loop on a warm
worker (every job but each worker's first), the speed-up of 2 workers, an Amdahl fit
``T(W) = S + P / W`` and its projection to 16 and 64 cores, and the bound
``sum(closed loop) / W * 1.3``. ``--wait-quiet`` first waits (up to 10 minutes) until the
1-minute system load is below 1.

Before the sweeps, mpclab's own modules are compiled to bytecode (``compileall``), as Python
does on its first import anywhere bytecode is written: a machine that sets
``PYTHONDONTWRITEBYTECODE=1`` (this project's 2-core machine does) would otherwise compile
them from source in every command (0.2 s each). ``--source`` measures that case instead
(the bytecode is removed first).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from mpclab.record.provenance import stamp

ROOT = Path(__file__).resolve().parents[2]
SWEEP = ["+experiment=zumo_bug2", "scenario=zumo_random", "recorder=none",
         "figures.enabled=false"]


def wait_quiet(limit_s: float = 600.0) -> float:
    """Wait until the 1-minute system load is below 1 (or ``limit_s``); return it."""
    t0 = time.time()
    while os.getloadavg()[0] >= 1.0 and time.time() - t0 < limit_s:
        time.sleep(30)
    return os.getloadavg()[0]


def bytecode(compiled: bool) -> None:
    """Compile mpclab's modules (and its Hydra plugins) to bytecode, or remove theirs."""
    packages = [ROOT / "mpclab", ROOT / "hydra_plugins"]
    if compiled:
        subprocess.run([sys.executable, "-m", "compileall", "-q", *map(str, packages)],
                       check=True)
        return
    for package in packages:
        for cache in package.rglob("__pycache__"):
            shutil.rmtree(cache)


def run(jobs: int, workers: int, extra: list[str], out: Path) -> dict:
    """One sweep; its timings as the sweep itself recorded them."""
    cmd = [sys.executable, "-m", "mpclab", "-m", *SWEEP, f"seed=range(0,{jobs})",
           f"hydra.launcher.n_jobs={workers}", f"hydra.sweep.dir={out}", *extra]
    load = os.getloadavg()[0]
    t0 = time.time()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    t_end = time.time()
    if proc.returncode != 0:
        raise RuntimeError((proc.stdout + proc.stderr)[-3000:])
    meta = json.loads((out / ".mpclab" / "sweep.json").read_text())
    tasks = pd.read_json(out / ".mpclab" / "tasks.jsonl", lines=True).sort_values("start")
    rows = pd.read_parquet(out / "summary.parquet")
    first = tasks.groupby("pid")["start"].transform("min") == tasks["start"]
    warm = tasks[~first]
    outside = warm["task_s"] - warm["simulate_s"]
    return {
        "workers": workers, "jobs": jobs, "rows": len(rows),
        "errors": int((rows["status"] == "error").sum()),
        "wall_s": t_end - t0,
        "before_first_job_s": tasks["start"].min() - t0,
        "after_last_job_s": t_end - (tasks["start"] + tasks["task_s"]).max(),
        "report_s": meta.get("report_s", float("nan")),
        "closed_loop_sum_s": float(tasks["simulate_s"].sum()),
        "task_sum_s": float(tasks["task_s"].sum()),
        "first_job_outside_s": float((tasks[first]["task_s"] - tasks[first]["simulate_s"])
                                     .mean()),
        "warm_outside_median_s": float(outside.median()),
        "warm_outside_mean_s": float(outside.mean()),
        "first_job_faults": float(tasks[first]["minor_faults"].mean()),
        "warm_faults_median": float(warm["minor_faults"].median()),
        "load_before": load, "load_after": os.getloadavg()[0],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=48)
    parser.add_argument("--rounds", type=int, default=1, help="1: W = 1, 2; 2: 1, 2, 2, 1")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                        help="worker counts (the fit and projection need 1 and 2)")
    parser.add_argument("--wait-quiet", action="store_true")
    parser.add_argument("--source", action="store_true",
                        help="mpclab's modules compiled from source in every command")
    parser.add_argument("overrides", nargs="*", help="extra overrides for every sweep")
    args = parser.parse_args()
    print(f"PYTHONDONTWRITEBYTECODE={os.environ.get('PYTHONDONTWRITEBYTECODE', '')!r}; "
          + ("mpclab compiled from source in every command" if args.source
             else "mpclab's bytecode compiled first"), flush=True)
    bytecode(compiled=not args.source)
    if args.wait_quiet:
        print(f"system load (1 min) before: {wait_quiet():.2f}", flush=True)
    results = []
    with tempfile.TemporaryDirectory(prefix="mpclab_bench_") as tmp:
        for r in range(args.rounds):
            for w in (args.workers if r % 2 == 0 else args.workers[::-1]):
                res = run(args.jobs, w, args.overrides, Path(tmp) / f"r{r}_w{w}")
                results.append(res)
                print(json.dumps({k: round(v, 3) if isinstance(v, float) else v
                                  for k, v in res.items()}), flush=True)
    df = pd.DataFrame(results)
    print(stamp())
    for _, r in df.iterrows():
        loops = r["closed_loop_sum_s"] / r["workers"]
        print(f"  W={r['workers']}: {r['rows']}/{r['jobs']} rows, wall {r['wall_s']:.1f} s, "
              f"closed loops / W = {loops:.1f} s: wall = {r['wall_s'] / loops:.2f} x that")
    print(f"load (1 min): before {df['load_before'].min():.2f}-{df['load_before'].max():.2f}, "
          f"after {df['load_after'].min():.2f}-{df['load_after'].max():.2f}; "
          f"cores {os.cpu_count()}")
    print(f"per job outside the closed loop on a warm worker: median "
          f"{statistics.median(df['warm_outside_median_s']):.3f} s, mean "
          f"{statistics.median(df['warm_outside_mean_s']):.3f} s; a worker's first job "
          f"{df['first_job_outside_s'].median():.2f} s")
    for w, g in df.groupby("workers"):
        print(f"minor page faults, {w} worker(s): a worker's first job "
              f"{g['first_job_faults'].median():.0f}, a warm job "
              f"{g['warm_faults_median'].median():.0f} (medians)")
    one = df[df["workers"] == 1]
    if len(one):  # from the parts one worker measured: what does not shrink with workers
        fixed = float((one["before_first_job_s"] + one["after_last_job_s"]
                       + one["first_job_outside_s"]).median())
        work = float((one["task_sum_s"] - one["first_job_outside_s"]).median())
        t1 = float(one["wall_s"].median())
        print(f"from the parts (1 worker): fixed {fixed:.2f} s (before the first job, after the "
              f"last, a worker's first set-up), jobs {work:.2f} s; projected speed-up: "
              + ", ".join(f"{c} cores {t1 / (fixed + work / c):.1f}" for c in (2, 16, 64)))
    per_job = df.groupby("workers")["task_sum_s"].median()
    if {1, 2} <= set(per_job.index):  # the cores' share: 1.0 when two jobs run as one alone
        print(f"the jobs' own time (their sum in the workers), 2 workers against 1: "
              f"{per_job[2] / per_job[1]:.3f} (1.0: two jobs at once run as fast as one alone)")
    med = df.groupby("workers")["wall_s"].median()
    if not {1, 2} <= set(med.index):
        return
    t1, t2 = med[1], med[2]
    serial = 2 * t2 - t1                    # Amdahl: T(W) = S + P / W
    parallel = 2 * (t1 - t2)
    print(f"\n{args.jobs} jobs: wall {t1:.2f} s on 1 worker, {t2:.2f} s on 2: "
          f"speed-up {t1 / t2:.2f}")
    print(f"Amdahl fit: serial {serial:.2f} s, parallel {parallel:.2f} s "
          f"({parallel / args.jobs:.3f} s per job)")
    for cores in (16, 64):
        print(f"  projected speed-up on {cores} cores: {t1 / (serial + parallel / cores):.1f}")
    print("measured serial (1 worker): before the first job "
          f"{one['before_first_job_s'].median():.2f} s, after the last "
          f"{one['after_last_job_s'].median():.2f} s (tables and figure "
          f"{one['report_s'].median():.2f} s)")


if __name__ == "__main__":
    main()
