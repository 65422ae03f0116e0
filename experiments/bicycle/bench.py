"""Study C benchmark: every scenario x mode x sample time, figures, and the CVXPY comparison.

    uv run python experiments/bicycle/bench.py            # all runs, figures, timing
    uv run python experiments/bicycle/bench.py --steps 300 --skip-runs   # timing only

Writes ``results.md`` and ``results.csv`` beside this file and ``figures/*.png``; the run
records go to ``outputs/bicycle_bench/<scenario>_<mode>_<dt>/``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
from mpclab.controllers.base import StepContext  # noqa: E402
from mpclab.experiment import build_run, run_experiment  # noqa: E402
from mpclab.experiment import compose as compose_cfg  # noqa: E402

SCENARIOS = ("control_y_V", "regular_circle_turn", "turn")
MODES = {"switched": "bicycle_scheduled", "interpolated": "bicycle_interpolated",
         "adaptive": "bicycle_adaptive"}
DTS = (0.02, 0.05)
COLUMNS = ["scenario", "mode", "dt", "status", "n_steps", "rms_px", "rms_py", "rms_V",
           "rms_theta", "overshoot_py", "input_jump_max_rel", "switch_jump_max_rel",
           "switch_jump_max_delta", "switch_jump_max_a", "n_switches", "input_bound_excess",
           "compute_median_ms", "compute_p95_ms"]


def overrides(scenario: str, mode: str, dt: float, *extra: str) -> list[str]:
    return [f"+experiment={MODES[mode]}", f"scenario={scenario}", f"controller.dt={dt}",
            "recorder=none", "progress=false", "figures.enabled=false", *extra]


def run_all(out_root: Path) -> pd.DataFrame:
    rows = []
    for scenario in SCENARIOS:
        for mode in MODES:
            for dt in DTS:
                out = out_root / f"{scenario}_{mode}_{dt}"
                run_experiment(compose_cfg(overrides(scenario, mode, dt)), out)
                s = json.loads((out / "summary.json").read_text())
                rows.append({"scenario": scenario, "mode": mode, "dt": dt,
                             **{k: s.get(k) for k in COLUMNS[3:]}})
                print(f"{scenario:20s} {mode:12s} {dt:.2f}  {s['status']}  "
                      f"median {s['compute_median_ms']:.3f} ms", flush=True)
    return pd.DataFrame(rows, columns=COLUMNS)


def interleaved(scenario: str, n_steps: int) -> dict[str, float]:
    """Per-step time of the switched backend (closed form) against the same condensed QP
    through CVXPY: Clarabel on the compiled data (``solve_via=direct``, the default), Clarabel
    through ``Problem.solve`` and OSQP (through ``Problem.solve``), all called on the same
    state, alternating the order."""
    cfg = compose_cfg(overrides(scenario, "switched", 0.02))
    run = build_run(cfg)
    plant, scen, fast = run.plant, run.scenario, run.controller
    # the same controller but the QP solved through CVXPY (its own copy of the plant)
    variants = {
        "CLARABEL_direct": ["controller.solver=CLARABEL", "controller.solve_via=direct"],
        "CLARABEL_problem": ["controller.solver=CLARABEL", "controller.solve_via=problem"],
        "OSQP": ["controller.solver=OSQP"],
    }
    others = {name: build_run(compose_cfg(overrides(scenario, "switched", 0.02, *extra)))
              .controller for name, extra in variants.items()}
    ctrls = {"closed_form": fast, **others}
    times: dict[str, list[float]] = {name: [] for name in ctrls}
    diff = {name: 0.0 for name in others}
    x = scen.x0.copy()
    for c in ctrls.values():
        c.reset(x)
    H, dt = fast.horizon, fast.dt
    order = list(ctrls)
    for k in range(n_steps):
        t = k * dt
        ctx = StepContext(goal=scen.goal, target=scen.target(t, H, dt))
        res = {}
        for name in order if k % 2 == 0 else order[::-1]:
            t0 = time.perf_counter()
            res[name] = ctrls[name].step(t, x, ctx)
            times[name].append(time.perf_counter() - t0)
        for name in others:
            diff[name] = max(diff[name], float(np.abs(res[name].u - res["closed_form"].u).max()))
        x = plant.step(x, res["closed_form"].u, dt)
    out = {"scenario": scenario, "steps": n_steps}
    for name, ts in times.items():
        ms = np.asarray(ts) * 1e3
        out[f"{name}_median_ms"] = float(np.median(ms))
        out[f"{name}_p95_ms"] = float(np.percentile(ms, 95))
    for name in others:
        out[f"{name}_ratio"] = out[f"{name}_median_ms"] / out["closed_form_median_ms"]
        out[f"{name}_max_du"] = diff[name]
    return out


def fmt(df: pd.DataFrame) -> str:
    def cell(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return "" if v is None else str(v)
    head = "| " + " | ".join(df.columns) + " |"
    sep = "|" + "---|" * len(df.columns)
    body = ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join([head, sep, *body])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=600, help="steps of each interleaved timing")
    ap.add_argument("--skip-runs", action="store_true", help="only the interleaved timing")
    args = ap.parse_args()
    out_root = ROOT / "outputs" / "bicycle_bench"
    parts = ["# Study C benchmark results", "",
             f"Command: `uv run python experiments/bicycle/bench.py --steps {args.steps}`", ""]
    if not args.skip_runs:
        table = run_all(out_root)
        table.to_csv(HERE / "results.csv", index=False)
        sys.path.insert(0, str(HERE))
        from figures import draw_all  # the figures module beside this script

        draw_all(out_root, HERE / "figures")
        parts += ["## Every scenario, mode and sample time (from each run's summary.json)", "",
                  fmt(table), ""]
    timing = pd.DataFrame([interleaved(s, args.steps) for s in SCENARIOS])
    print(timing.T.to_string(), flush=True)
    parts += ["## Per-step time, interleaved in one process (switched mode, 20 ms, horizon 32, "
              "control horizon 1)", "", fmt(timing), ""]
    (HERE / "results.md").write_text("\n".join(parts))


if __name__ == "__main__":
    main()
