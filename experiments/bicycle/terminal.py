"""The LQR terminal cost, checked in the closed loop: no failed step, the value decreasing.

    uv run python experiments/bicycle/terminal.py --runs 40 --md experiments/bicycle/terminal.md

Each run starts the dynamic bicycle at a random offset from a straight path (the lateral
reference, the speed, yaw rate and slip angle: drawn from the run's seed) and regulates it to
the path at 2 m/s, the linearization point of ``+experiment=bicycle_lqr``'s terminal cost,
with the terminal cost and without it (``~objective.terms.terminal``), on the same starts.
Per variant the table counts the steps whose solve did not converge, and checks the MPC's
value ``V_k`` (the optimal cost, the step log's ``cost``) along the closed loop: the
stability argument with a terminal cost gives ``V_{k+1} <= V_k - l_k`` (``l_k``: the stage
cost the first step spent, the state's at ``k+1`` and the input at ``k``) for the nominal
model where the shifted plan stays feasible. The table gives how many steps kept that
decrease and how many kept ``V_{k+1} <= V_k`` at least (both within ``1e-6 max(V_k, 1)``,
the solver's tolerance), how many of the steps where the value rose had an input at its
bound (where the LQR's tail would break the bounds: the argument then needs a terminal set),
and the largest excess ``(V_{k+1} - V_k + l_k) / V_k`` where the decrease failed. The
Markdown is stamped.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mpclab.config.instantiate import build
from mpclab.record.provenance import stamp
from mpclab.runner.single_run import compose, run_experiment

BASE = ("+experiment=bicycle_lqr", "recorder=none", "progress=false",
        "figures.enabled=false", "scenario.t_max=4.0", "scenario.speed={t:[0.0],value:[2.0]}")
VARIANTS = (("terminal LQR", ()), ("no terminal cost", ("~objective.terms.terminal",)))
TOL = 1e-6


def start(seed: int) -> list[str]:
    """The run's offset from the path, from its seed: the lateral reference [m] (the path
    itself starts at the start pose), and the start's speed [m/s], yaw rate [rad/s] and slip
    angle [rad]."""
    rng = np.random.default_rng(seed)
    lateral, v = rng.uniform(-1.0, 1.0), rng.uniform(1.0, 3.0)
    yaw_rate, slip = rng.uniform(-0.5, 0.5), rng.uniform(-0.1, 0.1)
    return [f"scenario.lateral={{t:[0.0],value:[{lateral:.4f}]}}", f"scenario.start.V={v:.4f}",
            f"scenario.start.r={yaw_rate:.4f}", f"scenario.start.beta={slip:.4f}"]


def check(overrides: Sequence[str], out: Path) -> dict[str, float]:
    """One run: its steps, the failed solves and the value's decrease."""
    cfg = compose([*BASE, *overrides])
    res = run_experiment(cfg, out)
    steps = res.steps[res.steps["status"].astype(str) != "final"]  # the controller's steps
    plant = build(cfg.plant, "plant")
    scen = build(cfg.scenario, "scenario", plant=plant)
    q = np.array([float(cfg.objective.terms.tracking.state_weights.get(s, 0.0))
                  for s in plant.states])
    r = np.array([float(cfg.objective.terms.tracking.input_weights.get(u, 0.0))
                  for u in plant.inputs])
    X = steps[list(plant.states)].to_numpy(float)
    U = steps[list(plant.inputs)].to_numpy(float)
    V = steps["cost"].to_numpy(float)
    dt = float(cfg.controller.dt)
    ref = np.array([scen.target(t, 0, dt)[0] for t in steps["t"].to_numpy(float)])
    e = X[1:] - ref[1:]
    spent = (e**2) @ q + (U[:-1] ** 2) @ r
    excess = V[1:] - V[:-1] + spent
    kept = excess <= TOL * np.maximum(V[:-1], 1.0)
    worst = excess / np.maximum(V[:-1], 1e-12)
    rose = V[1:] > V[:-1] + TOL * np.maximum(V[:-1], 1.0)  # the decrease's tolerance
    at_bound = np.any((U[:-1] <= plant.u_lb + 1e-6) | (U[:-1] >= plant.u_ub - 1e-6), axis=1)
    return {"steps": len(V) - 1, "kept": int(kept.sum()),
            "decreased": int(np.sum(~rose)), "rose_at_bound": int(np.sum(rose & at_bound)),
            "worst": float(worst[~kept].max()) if (~kept).any() else 0.0,
            "failed": int(np.sum(steps["status"].astype(str) != "converged")),
            "arrived": res.summary["status"] == "arrived",
            "final_py": float(abs(X[-1, plant.state_index("py")]
                                  - ref[-1, plant.state_index("py")]))}


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--out", default="outputs/terminal")
    ap.add_argument("--md", type=Path)
    args = ap.parse_args(argv[1:])
    lines = ["| variant | runs | steps | solves not converged | steps keeping V(k+1) <= V(k) - "
             "l(k) | steps with V(k+1) <= V(k) | of the others, at an input bound | "
             "largest excess, relative to V(k) | largest final lateral error [m] |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, extra in VARIANTS:
        rows = [check([*start(seed), *extra], Path(args.out) / name.replace(" ", "_")
                      / f"seed_{seed}") for seed in range(args.runs)]
        steps = sum(r["steps"] for r in rows)
        lines.append(
            f"| {name} | {len(rows)} | {steps} | {sum(r['failed'] for r in rows)} | "
            f"{sum(r['kept'] for r in rows)} ({sum(r['kept'] for r in rows) / steps:.3f}) | "
            f"{sum(r['decreased'] for r in rows)} "
            f"({sum(r['decreased'] for r in rows) / steps:.3f}) | "
            f"{sum(r['rose_at_bound'] for r in rows)} | "
            f"{max(r['worst'] for r in rows):.3g} | {max(r['final_py'] for r in rows):.3g} |")
    text = "\n".join([f"{args.runs} random starts regulated to the straight path at 2 m/s "
                      "(experiments/bicycle/terminal.py)", "", *lines, "", stamp(argv), ""])
    print(text)
    if args.md:
        args.md.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
