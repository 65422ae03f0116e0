"""Study A from generated C: the car's converged SQP as CasADi-generated C against the study's
program (a CVXPY problem rebuilt every step) and the Python-driven compiled solver, one run.

    uv run python experiments/embedded/car_bench.py [--rounds 5]

Whole closed loops of ``car_to_origin`` alternate for ``--rounds`` rounds; per-step times
(wall clock and this thread's CPU time) are pooled. Rows: the study's program (one pass,
rebuilt every step: ``experiments/car_cvxpy/bench.py``), ``car_casadi`` (sqpmethod + qrqp, the
NLP's functions compiled: ``jit``), and the same with ``controller.codegen=true`` (the whole
solver generated as C by CasADi, its status by the KKT test), at ``-O1`` and ``-O2``.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.experiment import build_run, compose
from mpclab.sim import simulate

_spec = importlib.util.spec_from_file_location(
    "car_cvxpy_bench", Path(__file__).resolve().parents[1] / "car_cvxpy" / "bench.py")
car_cvxpy_bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(car_cvxpy_bench)
REF = car_cvxpy_bench.REF


def casadi_run(*overrides: str):
    return build_run(compose(["+experiment=car_casadi", "recorder=none", *overrides]))


def main(argv: list[str] | None = None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    runs = {
        REF: car_cvxpy_bench.rebuilt(),
        "car_casadi: SQP + qrqp, NLP functions compiled (jit, -O1)": casadi_run(),
        "car_casadi codegen=true: whole solver as generated C (-O1)": casadi_run(
            "controller.codegen=true"),
        "car_casadi codegen=true: whole solver as generated C (-O2)": casadi_run(
            "controller.codegen=true", "controller.jit_flags=[-O2]"),
    }
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    for name, run in runs.items():
        car_cvxpy_bench.cpu_timed(run, cpu[name])
    steps: dict[str, list[pd.DataFrame]] = {name: [] for name in runs}
    summaries: dict[str, dict] = {}
    load = os.getloadavg()[0]
    for r in range(args.rounds):
        for name, run in runs.items():
            res = simulate(run)
            steps[name].append(res.steps[res.steps["status"] != "final"])
            summaries[name] = res.summary
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr)
    ref_wall = np.median(pd.concat(steps[REF])["solve_time_s"])
    rows = []
    for name, chunks in steps.items():
        calls, s = pd.concat(chunks), summaries[name]
        t = calls["solve_time_s"].to_numpy()
        rows.append({
            "controller": name, "arrival_s": s["arrival_time_s"], "steps": s["n_steps"],
            "converged": s["converged_fraction"], "median_ms": 1e3 * np.median(t),
            "p95_ms": 1e3 * np.percentile(t, 95), "cpu_median_ms": 1e3 * np.median(cpu[name]),
            "speed-up (median)": ref_wall / np.median(t),
            "speed-up (cpu median)": np.median(cpu[REF]) / np.median(cpu[name]),
        })
    table = pd.DataFrame(rows)
    print(table.to_markdown(index=False, floatfmt=".3g"))
    print(f"load average (1 min): {load:.2f} before, {os.getloadavg()[0]:.2f} after "
          f"({os.cpu_count()} cores)")
    return table


if __name__ == "__main__":
    main()
