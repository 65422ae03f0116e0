"""Safety benchmark: named variants of one experiment on the same seeds, side by side.

    uv run python experiments/safety/bench.py --scenario zumo_random --seeds 0:1000 \\
        --variant study --variant constrained controller.collision_distance=0.065

Every variant runs on every seed of every scenario (paired: the same layouts for all),
interleaved seed by seed so that a busy machine slows every variant alike. Per variant the
table gives the success (arrival) rate and the collision rate, each with its exact 95 %
interval (Clopper-Pearson), time-outs, stalls, the least clearance of any run (continuous
time) and the CPU time per controller call (median and p95, pooled over every call; CPU
time, not wall time, so other processes on the machine do not inflate it), and the CPU time
up to the input (the real-time iteration's feedback; the whole call for any other
controller). A second table gives the obstacle margin kept and, where the robot localizes
by odometry or an EKF, the estimate's error and the filter's consistency. Seeds that
collided or timed out are listed; with several scenarios, a second table gives each
scenario's outcome per variant.
The Markdown (``--md``) is stamped with the command, the git commit, the CPU model, the
cores and the date.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpclab.record import files as record
from mpclab.record.provenance import stamp
from mpclab.record.stats import clopper_pearson
from mpclab.runner.loop import CPU_COLUMN
from mpclab.runner.single_run import compose, run_experiment

#: the real-time iteration's CPU time from the call to its input (its step log's column)
FEEDBACK_CPU = "feedback_cpu_s"
HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
#: the variants run when none is given: the experiment as it ships, and the same with the
#: NMPC's hard distance constraint on (centre to detected point, 6.5 cm: robot radius 5 cm
#: plus a margin for the ray's error and what sampling hides)
#: the shipped BUG2 (obstacles as a soft distance constraint) and the study's formulation
#: (obstacles as the potential J4 only), as ``zumo_bug2_study`` composes it
DEFAULT_VARIANTS = (("constrained", ()),
                    ("study", ("objective=zumo_bug2_study", "supervisor=bug2_study")))
BASE = ("recorder=none", "progress=false", "figures.enabled=false")


@dataclass
class Outcome:
    """What the table needs of one run."""

    variant: str
    scenario: str
    seed: int
    status: str
    arrival_time_s: float | None
    min_clearance_m: float | None
    cpu_ms: np.ndarray  # CPU time of every controller call [ms]
    to_input_ms: np.ndarray  # CPU time of every call up to its input [ms]: the real-time
    #                          iteration's feedback; the whole call for any other controller
    converged: int
    calls: int
    margin_m: float | None = None  # the distance the run's obstacle constraint kept
    estimate_error_m: float | None = None  # the estimate's largest position error
    nees: float | None = None  # the EKF's mean normalized estimation error squared
    inside_95: float | None = None  # ... and the fraction of periods inside its 95 % ellipse


def run_one(job: tuple[str, str, int, list[str], str]) -> Outcome:
    """Compose and run one (variant, scenario, seed); its record goes below ``out``."""
    variant, scenario, seed, overrides, out = job
    cfg = compose([*BASE, f"scenario={scenario}", f"seed={seed}", *overrides])
    res = run_experiment(cfg, Path(out) / variant / scenario / f"seed_{seed}")
    calls = record.controller_steps(res.steps)
    cpu = calls[CPU_COLUMN].to_numpy(dtype=float) * 1e3
    to_input = (calls[FEEDBACK_CPU].to_numpy(dtype=float) * 1e3 if FEEDBACK_CPU in calls
                else cpu)
    s = res.summary
    return Outcome(variant, scenario, seed, s["status"], s["arrival_time_s"],
                   s["min_clearance_m"], cpu, to_input,
                   int(s.get("solves_converged", 0)), int(s["n_steps"]),
                   (s.get("margin") or {}).get("kept_m"), s.get("localization_error_max_m"),
                   s.get("localization_nees_mean"), s.get("localization_inside_95"))


def seeds_of(text: str) -> list[int]:
    """``"0:100"`` (from 0 up to 99) or ``"3,94,284"``."""
    if ":" in text:
        lo, hi = text.split(":", 1)
        return list(range(int(lo), int(hi)))
    return [int(v) for v in text.split(",") if v.strip()]


def table(outcomes: Sequence[Outcome], variants: Sequence[str]) -> str:
    """The Markdown table, one row per variant, and the seeds that failed."""
    head = ("| variant | runs | arrived | success [95 % CI] | collisions | collision rate "
            "[95 % CI] | time-outs | stalled | other | least clearance mm | CPU/step median "
            "ms | CPU/step p95 ms | to input median ms | to input p95 ms | converged |")
    lines = [head, "|" + "---|" * 15]
    notes = []
    for name in variants:
        rows = [o for o in outcomes if o.variant == name]
        n = len(rows)
        count = {st: sum(o.status == st for o in rows) for st in
                 ("arrived", "collision", "timeout", "stalled")}
        other = n - sum(count.values())
        s_lo, s_hi = clopper_pearson(count["arrived"], n)
        c_lo, c_hi = clopper_pearson(count["collision"], n)
        clear = [o.min_clearance_m for o in rows if o.min_clearance_m is not None]
        cpu = np.concatenate([o.cpu_ms for o in rows]) if rows else np.zeros(0)
        to_input = np.concatenate([o.to_input_ms for o in rows]) if rows else np.zeros(0)
        conv = sum(o.converged for o in rows) / max(1, sum(o.calls for o in rows))
        lines.append(
            f"| {name} | {n} | {count['arrived']} | {count['arrived'] / n:.3f} "
            f"[{s_lo:.3f}, {s_hi:.3f}] | {count['collision']} | {count['collision'] / n:.4f} "
            f"[{c_lo:.4f}, {c_hi:.4f}] | {count['timeout']} | {count['stalled']} | {other} | "
            f"{1e3 * min(clear):.1f} | {np.median(cpu):.2f} | {np.percentile(cpu, 95):.2f} | "
            f"{np.median(to_input):.2f} | {np.percentile(to_input, 95):.2f} | "
            f"{conv:.3f} |" if n else f"| {name} | 0 |" + " |" * 13)
        for st in ("collision", "timeout", "stalled", "error", "solver_failed"):
            seeds = sorted((o.scenario, o.seed) for o in rows if o.status == st)
            if seeds:
                where = ", ".join(f"{sc} {seed}" for sc, seed in seeds)
                notes.append(f"- {name}, {st}: {where}")
    return "\n".join(lines + ([""] + notes if notes else []))


def world_table(outcomes: Sequence[Outcome], variants: Sequence[str]) -> str | None:
    """The margin kept and the localization, one row per variant (medians over the runs);
    None where no run has either."""
    fields = ("margin_m", "estimate_error_m", "nees", "inside_95")
    if not any(getattr(o, f) is not None for o in outcomes for f in fields):
        return None

    def median(rows: Sequence[Outcome], f: str, scale: float, fmt: str) -> str:
        v = [getattr(o, f) for o in rows if getattr(o, f) is not None]
        return format(scale * float(np.median(v)), fmt) if v else "-"

    lines = ["| variant | distance kept mm (median) | estimate's largest error, median mm | "
             "EKF mean NEES, median (2: consistent) | EKF inside its 95 % ellipse, median |",
             "|---|---|---|---|---|"]
    for name in variants:
        rows = [o for o in outcomes if o.variant == name]
        lines.append(f"| {name} | {median(rows, 'margin_m', 1e3, '.1f')} | "
                     f"{median(rows, 'estimate_error_m', 1e3, '.1f')} | "
                     f"{median(rows, 'nees', 1, '.2f')} | {median(rows, 'inside_95', 1, '.3f')} |")
    return "\n".join(lines)


def by_scenario(outcomes: Sequence[Outcome], variants: Sequence[str]) -> str:
    """One row per scenario, one column per variant: its run's status (arrival time, least
    clearance) for one seed, counts for several."""
    scenarios = list(dict.fromkeys(o.scenario for o in outcomes))
    lines = ["| scenario | " + " | ".join(variants) + " |", "|" + "---|" * (1 + len(variants))]
    for scen in scenarios:
        cells = []
        for name in variants:
            rows = [o for o in outcomes if o.scenario == scen and o.variant == name]
            if len(rows) == 1:
                o = rows[0]
                when = f" {o.arrival_time_s:.1f} s" if o.arrival_time_s is not None else ""
                clear = ("" if o.min_clearance_m is None
                         else f", {1e3 * o.min_clearance_m:.1f} mm")
                cells.append(f"{o.status}{when}{clear}")
            else:
                n = len(rows)
                counts = {st: sum(o.status == st for o in rows)
                          for st in ("arrived", "collision", "timeout", "stalled")}
                cells.append(", ".join(f"{c}/{n} {st}" for st, c in counts.items() if c))
        lines.append(f"| {scen} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--experiment", default="zumo_bug2")
    ap.add_argument("--scenario", default="zumo_random",
                    help="a scenario, or several separated by commas (each on every seed)")
    ap.add_argument("--seeds", default="0:10", help="'0:1000' (0..999) or '3,94,284'")
    ap.add_argument("--variant", nargs="+", action="append", metavar=("NAME", "OVERRIDE"),
                    help="a name and its overrides (repeat for each variant; default: "
                         + "; ".join(f"{n} {' '.join(o)}".strip() for n, o in DEFAULT_VARIANTS)
                         + ")")
    ap.add_argument("--set", nargs="*", default=[], metavar="OVERRIDE",
                    help="overrides for every variant, e.g. sim=realistic")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--out", default="outputs/safety_bench", help="run records")
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    args = ap.parse_args(argv[1:])
    variants = [(v[0], tuple(v[1:])) for v in args.variant] if args.variant else list(
        DEFAULT_VARIANTS)
    names = [n for n, _ in variants]
    if len(set(names)) != len(names):
        ap.error(f"variant names must differ, got {names}")
    common = [f"+experiment={args.experiment}", *args.set]
    scenarios = [s.strip() for s in args.scenario.split(",") if s.strip()]
    jobs = [(name, scen, seed, [*common, *over], args.out) for scen in scenarios
            for seed in seeds_of(args.seeds) for name, over in variants]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            outcomes = list(pool.map(run_one, jobs))
    else:
        outcomes = [run_one(j) for j in jobs]
    seeds = seeds_of(args.seeds)
    over = "; ".join(f"**{n}**: `{' '.join(o) or '(as shipped)'}`" for n, o in variants)
    text = "\n".join([
        f"{args.experiment} on {args.scenario}, {len(seeds)} seeds "
        f"({args.seeds}){', ' + ' '.join(args.set) if args.set else ''}; {over}", "",
        table(outcomes, names), "",
        *([world, ""] if (world := world_table(outcomes, names)) else []),
        *([by_scenario(outcomes, names), ""] if len(scenarios) > 1 else []),
        stamp(argv), ""])
    print(text)
    if args.md:
        args.md.parent.mkdir(parents=True, exist_ok=True)
        args.md.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
