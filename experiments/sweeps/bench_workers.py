"""1 vs 2 joblib workers on the same 16-job sweep, measured back to back and interleaved.

    uv run python experiments/sweeps/bench_workers.py [--rounds 2] [OVERRIDE ...]

Runs ``python -m mpclab -m +experiment=car_cvxpy +sweep=workers hydra.launcher.n_jobs=N``
in the order 1, 2, 2, 1, ... (ABBA, so a drift in machine load falls on both), timing each
whole command (start-up included) and the sweep itself (multirun start to end, from its log).
Prints a Markdown table, the ratio of medians, and the system load before and after.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SWEEP = ["+experiment=car_cvxpy", "+sweep=workers"]


def run(n_jobs: int, extra: list[str]) -> tuple[float, float]:
    """Wall time of the whole command and of the sweep (from its 'sweep finished' line)."""
    cmd = [sys.executable, "-m", "mpclab", "-m", *SWEEP, f"hydra.launcher.n_jobs={n_jobs}", *extra]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    out = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise RuntimeError(out[-3000:])
    m = re.search(r"sweep finished: (\d+) runs in (\d+):(\d\d):(\d\d), (.*)", out)
    if not m or m.group(1) != "16":
        raise RuntimeError(f"expected 16 runs:\n{out[-3000:]}")
    h, mi, s = (int(g) for g in m.group(2, 3, 4))
    print(f"  n_jobs={n_jobs}: {wall:6.1f} s command, {h * 3600 + mi * 60 + s} s sweep "
          f"({m.group(5)})", flush=True)
    return wall, float(h * 3600 + mi * 60 + s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=2, help="ABBA rounds (2 runs each)")
    parser.add_argument("overrides", nargs="*", help="extra overrides for every sweep")
    args = parser.parse_args()
    load_before = os.getloadavg()
    times: dict[int, list[tuple[float, float]]] = {1: [], 2: []}
    for r in range(args.rounds):
        for n in ((1, 2) if r % 2 == 0 else (2, 1)):
            times[n].append(run(n, args.overrides))
    load_after = os.getloadavg()
    print("\n| workers | command wall [s] (each) | median | sweep [s] (each) | median |")
    print("|---:|---|---:|---|---:|")
    med = {}
    for n, ts in times.items():
        walls, sweeps = [w for w, _ in ts], [s for _, s in ts]
        med[n] = (statistics.median(walls), statistics.median(sweeps))
        print(f"| {n} | {', '.join(f'{w:.1f}' for w in walls)} | {med[n][0]:.1f} | "
              f"{', '.join(f'{s:.0f}' for s in sweeps)} | {med[n][1]:.0f} |")
    print(f"\nspeed-up 2 vs 1 workers: {med[1][0] / med[2][0]:.2f}x (command), "
          f"{med[1][1] / med[2][1]:.2f}x (sweep)")
    print(f"system load (1, 5, 15 min) before: {', '.join(f'{x:.2f}' for x in load_before)}; "
          f"after: {', '.join(f'{x:.2f}' for x in load_after)}; cores: {os.cpu_count()}")


if __name__ == "__main__":
    main()
