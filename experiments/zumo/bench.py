"""Study B benchmark: every Zumo experiment on the study's layouts, untuned layouts, random walls.

    uv run python experiments/zumo/bench.py [--out outputs/zumo_bench] [--md FILE]

Writes one run record per row under ``--out``, copies each summary.json to
``experiments/zumo/results/`` and each run's ``path.png`` (predicted horizons, obstacles,
m-line, BUG2 modes) to ``experiments/zumo/figures/``, and prints the outcomes table (Markdown,
stamped with command, commit, CPU and date; ``--md`` also writes it) that
experiments/zumo/README.md shows. Rows: the three experiments of the study (J1..J4, J1..J5,
BUG2) on its three layouts; the study's BUG2 formulation (``zumo_bug2_study``); BUG2 on the
truncated 3-step SQP backend (``sqp_capped3``: ``controller=casadi_sqp_capped``); the study's
J4 constants (``study_J4``) where they decide the outcome; both BUG2 formulations on the
untuned layouts (tests/test_zumo_layouts.py); BUG2 and the right-hand rule on random walls.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from mpclab.config.registry import register_all
from mpclab.record.provenance import write_stamped
from mpclab.runner.single_run import compose, run_experiment

HERE = Path(__file__).resolve().parent

LAYOUTS = ("zumo_long_wall", "zumo_l_wall", "zumo_cup", "zumo_narrow_gap", "zumo_wide_gap",
           "zumo_goal_near_wall")
SQP_CAPPED3 = ["controller=casadi_sqp_capped", "controller.solve.sqp_iterations=3"]
#: the study's J4 (ours: C3 = 1500, L3 = 0.05)
STUDY_J4 = ["objective.terms.J4.C3=8000", "objective.terms.J4.L3=0.1527"]

#: (experiment, scenario, seed, label, extra overrides)
RUNS = [
    (exp, scen, 0, "", [])
    for exp in ("zumo_potential", "zumo_right_hand", "zumo_bug2")
    for scen in ("zumo_one_obstacle", "zumo_wall", "zumo_dead_end")
] + [
    ("zumo_bug2_study", "zumo_dead_end", 0, "", []),
    ("zumo_bug2", "zumo_dead_end", 0, "sqp_capped3", SQP_CAPPED3),
] + [
    (exp, scen, 0, "study_J4", STUDY_J4)
    for exp, scen in (("zumo_potential", "zumo_one_obstacle"), ("zumo_potential", "zumo_wall"),
                      ("zumo_right_hand", "zumo_wall"), ("zumo_right_hand", "zumo_dead_end"),
                      ("zumo_bug2_study", "zumo_dead_end"))
] + [(exp, scen, 0, "", []) for exp in ("zumo_bug2", "zumo_bug2_study")
     for scen in LAYOUTS] + [
    ("zumo_bug2", "zumo_random", s, "", []) for s in (0, 1, 2, 3, 4, 5)
] + [("zumo_right_hand", "zumo_random", s, "", []) for s in (0, 1, 2)]

COLUMNS = ("status", "arrival_time_s", "converged_fraction", "u1_sign_changes_per_s",
           "max_heading_change_rad", "min_clearance_m", "compute_median_ms",
           "compute_cpu_median_ms", "rtf", "solver_failures", "n_steps")


def compose_run(exp: str, scen: str, seed: int, extra: list[str]) -> object:
    return compose([f"+experiment={exp}", "recorder=none", "progress=false",
                    f"seed={seed}", f"scenario={scen}", *extra])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="outputs/zumo_bench")
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    args = ap.parse_args()
    register_all()
    out = Path(args.out)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "figures").mkdir(exist_ok=True)
    rows = []
    for exp, scen, seed, label, extra in RUNS:
        cfg = compose_run(exp, scen, seed, extra)
        tag = f"{exp}__{scen}__{seed}" + (f"__{label}" if label else "")
        res = run_experiment(cfg, out / tag)
        shutil.copy(out / tag / "summary.json", HERE / "results" / f"{tag}.json")
        shutil.copy(out / tag / "path.png", HERE / "figures" / f"{tag}.png")
        name = exp + (f" ({label})" if label else "")
        rows.append((name, res.summary["scenario"], seed, res.summary))
        print(tag, json.dumps({k: res.summary.get(k) for k in COLUMNS}), file=sys.stderr)
    lines = ["| experiment | scenario | seed | " + " | ".join(COLUMNS) + " |",
             "|" + "---|" * (3 + len(COLUMNS))]
    for name, scen, seed, s in rows:
        cells = [_fmt(s.get(k)) for k in COLUMNS]
        lines.append(f"| {name} | {scen} | {seed} | " + " | ".join(cells) + " |")
    write_stamped(args.md, "\n".join(lines), sys.argv)


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    return "-" if v is None else str(v)


if __name__ == "__main__":
    main()
