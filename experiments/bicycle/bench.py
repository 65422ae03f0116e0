"""Study C benchmark: every scenario x mode x sample time, figures, and the CVXPY comparison.

    uv run python experiments/bicycle/bench.py            # all runs, figures, timing
    uv run python experiments/bicycle/bench.py --steps 300 --skip-runs   # timing only

Writes ``results.md`` (stamped: command, commit, CPU, date) and ``results.csv`` beside this
file and ``figures/*.png``; the run records go to
``outputs/bicycle_bench/<scenario>_<mode>_<dt>/``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
from mpclab.config.instantiate import build  # noqa: E402
from mpclab.controllers.base import StepContext  # noqa: E402
from mpclab.record.provenance import stamped  # noqa: E402
from mpclab.runner.single_run import build_run, run_experiment  # noqa: E402
from mpclab.runner.single_run import compose as compose_cfg  # noqa: E402

SCENARIOS = ("control_y_V", "regular_circle_turn", "turn")
MODES = {"switched": "bicycle_scheduled", "interpolated": "bicycle_interpolated",
         "adaptive": "bicycle_adaptive"}
DTS = (0.02, 0.05)
QUIET = ("recorder=none", "progress=false", "figures.enabled=false")
COLUMNS = ["scenario", "mode", "dt", "status", "n_steps", "rms_px", "rms_py", "rms_V",
           "rms_theta", "overshoot_py", "input_jump_max_rel", "switch_jump_max_rel",
           "switch_jump_max_delta", "switch_jump_max_a", "n_switches", "input_bound_excess",
           "compute_median_ms", "compute_p95_ms", "V_min", "V_max", "rk4_z_max"]


def overrides(scenario: str, mode: str, dt: float, *extra: str) -> list[str]:
    return [f"+experiment={MODES[mode]}", f"scenario={scenario}", f"controller.dt={dt}",
            *QUIET, *extra]


def run_all(out_root: Path) -> pd.DataFrame:
    rows = []
    for scenario in SCENARIOS:
        for mode in MODES:
            for dt in DTS:
                out = out_root / f"{scenario}_{mode}_{dt}"
                run_experiment(compose_cfg(overrides(scenario, mode, dt)), out)
                s = json.loads((out / "summary.json").read_text())
                s |= speeds(out, dt)
                rows.append({"scenario": scenario, "mode": mode, "dt": dt,
                             **{k: s.get(k) for k in COLUMNS[3:]}})
                print(f"{scenario:20s} {mode:12s} {dt:.2f}  {s['status']}  "
                      f"median {s['compute_median_ms']:.3f} ms", flush=True)
    return pd.DataFrame(rows, columns=COLUMNS)


def speeds(out: Path, dt: float) -> dict[str, float]:
    """The speeds a run reached and the largest ``|lambda h|`` of the lateral modes there
    (RK4 is stable up to 2.785; ``h = dt / substeps``)."""
    V = pd.read_parquet(out / "steps.parquet")["V"].to_numpy(dtype=float)
    plant = build(compose_cfg(["plant=dynamic_bicycle"]).plant, "plant")
    z = max(plant.rk4_z(v, dt) for v in np.linspace(V.min(), V.max(), 50))
    return {"V_min": float(V.min()), "V_max": float(V.max()), "rk4_z_max": z}


def model_accuracy() -> pd.DataFrame:
    """The controllers' discrete models against the exact zero-order-hold discretization
    (``expm`` of the continuous linearization, MATLAB's c2d) at the 8 operating points:
    the largest error in ``[A B]`` relative to its largest entry, for 1, 2 and 4 substeps."""
    from scipy.linalg import expm

    rows = []
    for dt in DTS:
        for sub in (1, 2, 4):
            plant = build(compose_cfg(["plant=dynamic_bicycle", f"plant.substeps={sub}"]).plant,
                          "plant")
            x, u = ca.SX.sym("x", 6), ca.SX.sym("u", 2)
            f = plant.rhs(x, u)
            jac = ca.Function("rhs_jac", [x, u], [ca.jacobian(f, x), ca.jacobian(f, u)])
            err = 0.0
            for theta in (0.0, np.pi / 2, np.pi, -np.pi / 2):
                for V in (1.0, 2.0):
                    xbar, ubar = np.array([0, 0, theta, 0, 0, V]), np.zeros(2)
                    Ac, Bc = (np.asarray(m) for m in jac(xbar, ubar))
                    M = np.zeros((8, 8))
                    M[:6, :6], M[:6, 6:] = Ac, Bc
                    E = expm(M * dt)[:6]
                    A, B = plant.jacobians(xbar, ubar, dt)
                    AB = np.hstack([A, B])
                    err = max(err, float(np.abs(AB - E).max() / np.abs(E).max()))
            rows.append({"dt": dt, "substeps": sub, "max_rel_err_AB_vs_zoh": err})
    return pd.DataFrame(rows)


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
        "CLARABEL_direct": ["controller.solver=CLARABEL", "controller.solve.via=direct"],
        "CLARABEL_problem": ["controller.solver=CLARABEL", "controller.solve.via=problem"],
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


def substeps_cost(scenario: str, n_steps: int) -> dict[str, float]:
    """Per-step time of the adaptive mode (it relinearizes the plant's step every call) with
    1 and 2 RK4 substeps, called alternately on the same states (those of the 2-substep run)."""
    ctrls = {sub: build_run(compose_cfg(overrides(scenario, "adaptive", 0.02,
                                                  f"plant.substeps={sub}"))) for sub in (1, 2)}
    scen, plant = ctrls[2].scenario, ctrls[2].plant
    times: dict[int, list[float]] = {1: [], 2: []}
    x = scen.x0.copy()
    for run in ctrls.values():
        run.controller.reset(x)
    H, dt = ctrls[2].controller.horizon, ctrls[2].controller.dt
    for k in range(n_steps):
        ctx = StepContext(goal=scen.goal, target=scen.target(k * dt, H, dt))
        res = {}
        for sub in ((1, 2) if k % 2 == 0 else (2, 1)):
            t0 = time.perf_counter()
            res[sub] = ctrls[sub].controller.step(k * dt, x, ctx)
            times[sub].append(time.perf_counter() - t0)
        x = plant.step(x, res[2].u, dt)
    med = {sub: float(np.median(ts)) * 1e3 for sub, ts in times.items()}
    return {"scenario": scenario, "steps": n_steps, "adaptive_1_substep_median_ms": med[1],
            "adaptive_2_substeps_median_ms": med[2], "ratio": med[2] / med[1]}


#: the columns of the tracking and switch table
TRACKING = ["scenario", "mode", "rms_py", "rms_V", "input_jump_max_rel", "switch_jump_max_rel",
            "switch_jump_max_delta", "n_switches"]


def overshoot_by_dt(table: pd.DataFrame) -> pd.DataFrame:
    """control_y_V's overshoot in y per mode, a column per sample time."""
    lane = table[table["scenario"] == "control_y_V"]
    wide = lane.pivot(index="mode", columns="dt", values="overshoot_py")
    wide = wide.reindex([m for m in lane["mode"].unique()])
    return pd.DataFrame({"mode": wide.index,
                         **{f"overshoot_py {1e3 * dt:g} ms [m]": wide[dt].to_numpy()
                            for dt in sorted(wide.columns)}})


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
    parts = ["# Study C benchmark results", ""]
    if not args.skip_runs:
        table = run_all(out_root)
        table.to_csv(HERE / "results.csv", index=False)
        sys.path.insert(0, str(HERE))
        from figures import draw_all  # the figures module beside this script

        draw_all(out_root, HERE / "figures")
        parts += ["## Every scenario, mode and sample time (from each run's summary.json)", "",
                  fmt(table), "", "## Tracking and switches, 20 ms", "",
                  fmt(table[table["dt"] == 0.02][TRACKING]), "",
                  "## 50 ms against 20 ms on control_y_V (overshoot in y)", "",
                  fmt(overshoot_by_dt(table)), ""]
        acc = model_accuracy()
        print(acc.to_string(index=False), flush=True)
        parts += ["## Discrete models against the exact zero-order hold (8 operating points)",
                  "", fmt(acc), ""]
    timing = pd.DataFrame([interleaved(s, args.steps) for s in SCENARIOS])
    print(timing.T.to_string(), flush=True)
    parts += ["## Per-step time, interleaved in one process (switched mode, 20 ms, horizon 32, "
              "control horizon 1)", "", fmt(timing), ""]
    cost = pd.DataFrame([substeps_cost(s, min(args.steps, 300)) for s in SCENARIOS])
    print(cost.to_string(index=False), flush=True)
    parts += ["## Adaptive mode with 1 and 2 RK4 substeps, interleaved in one process (20 ms)",
              "", fmt(cost), ""]
    (HERE / "results.md").write_text(stamped("\n".join(parts)))


if __name__ == "__main__":
    main()
