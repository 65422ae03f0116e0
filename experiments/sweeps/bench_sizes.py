"""The speed-up of 2 workers over 1 against the size of the sweep, measured, with a fitted line.

    uv run python experiments/sweeps/bench_sizes.py [--sizes 24 48 96 192] [--rounds 2]
        [--wait-quiet] [--out experiments/sweeps/figures/speedup_vs_jobs.png]

For each size N, runs the sweep of ``bench_scale.py`` (``zumo_bug2`` on ``zumo_random``,
``seed=range(0,N)``) with ``hydra.launcher.n_jobs`` 1, 2, 2, 1, ... (``--rounds`` pairs,
interleaved so that a drift of the machine falls on both), each whole command timed from
here. Per worker count W, a line ``T_W(N) = S_W + N * j_W``: ``S_W`` the serial part as each
sweep measured it (before its first job starts and after its last one ends; the median over
every run on W workers), ``j_W`` the least-squares slope through the origin of the rest of the
wall time against N (for two workers it also carries each worker's first set-up). The figure
shows each pair's ratio (the runs of one size, next to each other), each size's ratio of
medians, and ``T_1(N) / T_2(N)``, beside a target of 1.8; the table is printed as Markdown.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from bench_scale import bytecode, run, wait_quiet

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).resolve().parent
TARGET = 1.8  # the speed-up of 2 workers asked of a 48-job sweep


def measure(sizes: list[int], rounds: int) -> pd.DataFrame:
    """One row per sweep run: size, workers, the command's wall time and its parts."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="mpclab_sizes_") as tmp:
        for r in range(rounds):
            for n in sizes:
                for w in ((1, 2) if r % 2 == 0 else (2, 1)):
                    res = {**run(n, w, [], Path(tmp) / f"n{n}_w{w}_r{r}"), "round": r}
                    if res["rows"] != n:
                        raise RuntimeError(f"{n} jobs on {w} workers: {res['rows']} rows")
                    rows.append(res)
                    print(f"  {n:4d} jobs on {w} worker{'s' if w > 1 else ' '}: "
                          f"{res['wall_s']:6.2f} s (load before {res['load_before']:.2f})",
                          flush=True)
    return pd.DataFrame(rows)


def fit(df: pd.DataFrame) -> dict[int, tuple[float, float]]:
    """Per worker count: ``(S, j)``, the measured serial part and the per-job slope."""
    serial = df["before_first_job_s"] + df["after_last_job_s"]
    out = {}
    for w in (1, 2):
        mine = df["workers"] == w
        n, rest = df.loc[mine, "jobs"].to_numpy(float), (df["wall_s"] - serial)[mine].to_numpy()
        out[w] = (float(serial[mine].median()), float(n @ rest / (n @ n)))
    return out


def pair_ratios(df: pd.DataFrame) -> pd.DataFrame:
    """Per size and round: 1-worker wall / 2-worker wall of the two runs made together."""
    walls = df.pivot_table(index=["jobs", "round"], columns="workers", values="wall_s")
    return (walls[1] / walls[2]).rename("ratio").reset_index()


def table(df: pd.DataFrame, lines: dict[int, tuple[float, float]]) -> str:
    med = df.groupby(["jobs", "workers"])["wall_s"].median().unstack()
    pairs = pair_ratios(df).groupby("jobs")["ratio"]
    out = ["| jobs | 1 worker, median [s] | 2 workers, median [s] | speed-up (medians) | "
           "speed-up of each pair | T1/T2 of the lines |", "|---:|---:|---:|---:|---|---:|"]
    for n, (t1, t2) in med[[1, 2]].iterrows():
        model = (lines[1][0] + n * lines[1][1]) / (lines[2][0] + n * lines[2][1])
        each = ", ".join(f"{x:.2f}" for x in pairs.get_group(n))
        out.append(f"| {n} | {t1:.2f} | {t2:.2f} | {t1 / t2:.2f} | {each} | {model:.2f} |")
    return "\n".join(out)


def plot(df: pd.DataFrame, lines: dict[int, tuple[float, float]], out: Path) -> None:
    med = df.groupby(["jobs", "workers"])["wall_s"].median().unstack()
    ns = np.linspace(min(med.index) * 0.8, max(med.index) * 1.6, 200)
    model = (lines[1][0] + ns * lines[1][1]) / (lines[2][0] + ns * lines[2][1])
    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    ax.plot(ns, model, color="C0", label=(
        f"T1 / T2, T1 = {lines[1][0]:.2f} + {lines[1][1]:.3f} N, "
        f"T2 = {lines[2][0]:.2f} + {lines[2][1]:.3f} N [s]"))
    pairs = pair_ratios(df)
    ax.plot(pairs["jobs"], pairs["ratio"], ".", color="0.6", label="ratio of one pair of runs")
    ax.plot(med.index, med[1] / med[2], "o", color="C1", label="ratio of medians")
    ax.axhline(TARGET, color="0.4", ls="--", lw=1, label=f"target: {TARGET}")
    ax.axhline(2.0, color="0.7", ls=":", lw=1)
    ax.set_xscale("log", base=2)
    ax.set_xticks(list(med.index), [str(n) for n in med.index])
    ax.set_xlabel("jobs in the sweep (N)")
    ax.set_ylabel("wall time 1 worker / 2 workers")
    ax.set_title("zumo_bug2 on zumo_random, whole command, 2 cores")
    ax.legend(loc="lower right", fontsize=8)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[24, 48, 96, 192])
    parser.add_argument("--rounds", type=int, default=2, help="pairs of runs per size")
    parser.add_argument("--wait-quiet", action="store_true")
    parser.add_argument("--out", type=Path, default=HERE / "figures" / "speedup_vs_jobs.png")
    args = parser.parse_args()
    if len(args.sizes) < 2:
        parser.error("--sizes: at least two sizes (the lines need them)")
    bytecode(compiled=True)
    if args.wait_quiet:
        print(f"system load (1 min) before: {wait_quiet():.2f}", flush=True)
    df = measure(sorted(set(args.sizes)), args.rounds)
    lines = fit(df)
    print("\n" + table(df, lines))
    for w, (s, j) in lines.items():
        print(f"T{w}(N) = {s:.2f} s (measured serial part) + {j:.4f} s x N")
    s1, j1 = lines[1]
    s2, j2 = lines[2]
    if j1 > TARGET * j2:  # where the lines' ratio reaches the target
        print(f"the lines reach {TARGET} from N = {(TARGET * s2 - s1) / (j1 - TARGET * j2):.0f}")
    print(f"load (1 min) before each run: {statistics.median(df['load_before']):.2f} median, "
          f"{df['load_before'].max():.2f} max")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    plot(df, lines, args.out)
    print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
