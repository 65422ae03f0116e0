"""Study B benchmark: every Zumo experiment on every Zumo scenario, plus car_casadi.

    uv run python experiments/zumo/bench.py [--out outputs/zumo_bench]

Writes one run record per pair under ``--out``, copies each summary.json to
``experiments/zumo/results/``, draws the study's figures (path, predicted horizons,
obstacles, m-line, BUG2 modes) into ``experiments/zumo/figures/`` and prints the outcomes
table (markdown) that experiments/zumo/README.md shows. Besides every experiment on every
scenario: BUG2 on the untuned layouts (tests/test_zumo_layouts.py) and on random walls, and
two variants of the main command, labelled: the truncated 3-step SQP backend it used to run
on (``rti3``), and that with the objective and supervisor it had then (``rti3_old``: no dU,
no goal-in-sight rule).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from mpclab.experiment import build_run, compose, run_experiment  # noqa: E402
from mpclab.registry import register_all  # noqa: E402

HERE = Path(__file__).resolve().parent

LAYOUTS = ("zumo_long_wall", "zumo_l_wall", "zumo_cup", "zumo_narrow_gap", "zumo_wide_gap",
           "zumo_goal_near_wall")
RTI3 = ["controller=casadi_rti", "controller.sqp_iterations=3"]
OLD = ["objective.terms.dU.weights.u1=0", "objective.terms.dU.weights.u2=0",
       "supervisor.goal_sight_range=0"]

#: (experiment, scenario, seed, label, extra overrides)
RUNS = [
    (exp, scen, 0, "", [])
    for exp in ("zumo_potential", "zumo_right_hand", "zumo_bug2")
    for scen in ("zumo_one_obstacle", "zumo_wall", "zumo_dead_end")
] + [
    ("zumo_bug2", "zumo_dead_end", 0, "rti3", RTI3),
    ("zumo_bug2", "zumo_dead_end", 0, "rti3_old", RTI3 + OLD),
] + [("zumo_bug2", scen, 0, "", []) for scen in LAYOUTS] + [
    ("zumo_bug2", "zumo_random", s, "", []) for s in (0, 1, 2, 3, 4, 5)
] + [("zumo_right_hand", "zumo_random", s, "", []) for s in (0, 1, 2)] + [
    ("car_casadi", None, 0, "", [])
]

COLUMNS = ("status", "arrival_time_s", "converged_fraction", "u1_sign_changes_per_s",
           "max_heading_change_rad", "min_clearance_m", "compute_median_ms", "rtf",
           "solver_failures", "n_steps")


def compose_run(exp: str, scen: str | None, seed: int, extra: list[str]) -> object:
    over = [f"+experiment={exp}", "recorder=none", "progress=false", "figures.enabled=false",
            f"seed={seed}", *extra]
    if scen is not None:
        over.append(f"scenario={scen}")
    return compose(over)


def draw(result: object, run: object, path: Path, label: str = "") -> None:
    """Path (red: go to goal / no supervisor, blue: wall-follow), horizons, world, m-line."""
    steps, hz, scen = result.steps, result.horizons, run.scenario
    fig, ax = plt.subplots(figsize=(5.2, 5.2))
    for _, h in hz.groupby("step", sort=True):
        ax.plot(h["x"], h["y"], "-", color="tab:blue", lw=0.5, alpha=0.35)
    scen.draw(ax)
    mline = getattr(run.supervisor, "mline", None)
    if mline is not None:
        (xs, ys), (xg, yg) = mline
        ax.plot([xs, xg], [ys, yg], "--", color="tab:green", lw=1, label="m-line")
    modes = steps["mode"].fillna("")
    for mode, color in (("wall_follow", "tab:purple"), ("go_to_goal", "tab:red"), ("", "tab:red")):
        sel = steps[modes == mode]
        if len(sel):
            ax.plot(sel["x"], sel["y"], ".", color=color, ms=3, label=mode or "path")
    ax.plot(scen.x0[0], scen.x0[1], "o", color="tab:red", ms=8, label="start")
    ax.plot(scen.goal[0], scen.goal[1], "o", color="tab:blue", ms=8, label="goal")
    s = result.summary
    when = f"arrived {s['arrival_time_s']:.1f} s" if s["arrived"] else s["status"]
    ax.set_title(f"{s['experiment']}{label} / {scen.name} (seed {s['seed']}): {when}",
                 fontsize=9)
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="outputs/zumo_bench")
    args = ap.parse_args()
    register_all()
    out = Path(args.out)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "figures").mkdir(exist_ok=True)
    rows = []
    for exp, scen, seed, label, extra in RUNS:
        cfg = compose_run(exp, scen, seed, extra)
        tag = f"{exp}__{scen or 'car_to_origin'}__{seed}" + (f"__{label}" if label else "")
        res = run_experiment(cfg, out / tag)
        shutil.copy(out / tag / "summary.json", HERE / "results" / f"{tag}.json")
        if scen is not None:
            run = build_run(cfg)  # the same objects (and random layout) as the run
            run.supervisor.reset(run.scenario.x0, run.scenario.goal)
            draw(res, run, HERE / "figures" / f"{tag}.png", f" ({label})" if label else "")
        name = exp + (f" ({label})" if label else "")
        rows.append((name, res.summary["scenario"], seed, res.summary))
        print(tag, json.dumps({k: res.summary.get(k) for k in COLUMNS}), file=sys.stderr)
    print("| experiment | scenario | seed | " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * (3 + len(COLUMNS)))
    for name, scen, seed, s in rows:
        cells = [_fmt(s.get(k)) for k in COLUMNS]
        print(f"| {name} | {scen} | {seed} | " + " | ".join(cells) + " |")


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    return "-" if v is None else str(v)


if __name__ == "__main__":
    main()
