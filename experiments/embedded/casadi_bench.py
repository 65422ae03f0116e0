"""Studies A and B from generated C: the CasADi backend's whole solver as CasADi-generated C
(``controller.codegen=true``) against the same solver driven from Python, and for the car
against the study's program (a CVXPY problem rebuilt every step), in one run.

    uv run python experiments/embedded/casadi_bench.py [--rounds 5] [--md FILE]

Car: whole closed loops of ``car_to_origin`` alternate for ``--rounds`` rounds and per-step
times (wall clock and this thread's CPU time) are pooled (``compare`` of the car_cvxpy
benchmark; a generated SQP reports no iteration count, so its QP columns are empty). Rows:
the study's program (one pass, rebuilt every step: ``experiments/car_cvxpy/bench.py``),
``car_casadi`` (sqpmethod + qrqp, the NLP's functions compiled: ``jit``), and the same with
``controller.codegen=true`` (its status by the KKT test) at ``-O1`` and ``-O2``.

Zumo: whole ``zumo_bug2`` runs (fatrop, functions compiled) alternate with the same from
generated C; per-step times pooled.

Prints both tables, each with its stamp (command, commit, CPU, date); ``--md`` also writes them,
and ``results_casadi.csv`` beside this file keeps the generated-C rows (``key``) that
experiments/backends/guide.py quotes.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose

_spec = importlib.util.spec_from_file_location(
    "car_cvxpy_bench", Path(__file__).resolve().parents[1] / "car_cvxpy" / "bench.py")
car_cvxpy_bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(car_cvxpy_bench)
REF = car_cvxpy_bench.REF
HERE = Path(__file__).resolve().parent
CAR_JIT = "car_casadi: SQP + qrqp, NLP functions compiled (jit, -O1)"
CAR_C1 = "car_casadi codegen=true: whole solver as generated C (-O1)"
CAR_C2 = "car_casadi codegen=true: whole solver as generated C (-O2)"
ZUMO_JIT = "zumo_bug2: fatrop, NLP functions compiled (jit)"
ZUMO_C = "zumo_bug2 codegen=true: fatrop from generated C"
#: the rows experiments/backends/guide.py reads from results_casadi.csv
KEYS = {CAR_JIT: "car_jit", CAR_C1: "car_codegen_O1", CAR_C2: "car_codegen_O2",
        ZUMO_JIT: "zumo_jit", ZUMO_C: "zumo_codegen"}


def casadi_run(experiment: str, *overrides: str):
    return build_run(compose([f"+experiment={experiment}", "recorder=none", *overrides]))


def car(rounds: int) -> pd.DataFrame:
    runs = {
        REF: car_cvxpy_bench.rebuilt(),
        CAR_JIT: casadi_run("car_casadi"),
        CAR_C1: casadi_run("car_casadi", "controller.codegen=true"),
        CAR_C2: casadi_run(
            "car_casadi", "controller.codegen=true", "controller.build.jit_flags=[-O2]"),
    }
    return car_cvxpy_bench.compare(runs, rounds)


def zumo(rounds: int) -> pd.DataFrame:
    runs = {ZUMO_JIT: casadi_run("zumo_bug2"),
            ZUMO_C: casadi_run("zumo_bug2", "controller.codegen=true")}
    times: dict[str, list[np.ndarray]] = {name: [] for name in runs}
    summaries: dict[str, dict] = {}
    for _ in range(rounds):
        for name, run in runs.items():
            res = simulate(run)
            calls = res.steps[res.steps["status"] != "final"]
            times[name].append(calls["solve_time_s"].to_numpy())
            summaries[name] = summary = res.summary
            print(f"{name}: {summary['status']}, converged {summary['converged_fraction']}",
                  file=sys.stderr, flush=True)
    base = np.median(np.concatenate(times[next(iter(runs))]))
    table = pd.DataFrame([{
        "controller": name, "arrival_s": summaries[name]["arrival_time_s"],
        "steps": summaries[name]["n_steps"],
        "converged": summaries[name]["converged_fraction"],
        "median_ms": 1e3 * np.median(np.concatenate(t)),
        "p95_ms": 1e3 * np.percentile(np.concatenate(t), 95),
        "speed-up (median)": base / np.median(np.concatenate(t)),
    } for name, t in times.items()])
    return table


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--md", type=Path, help="also write the stamped tables here")
    args = ap.parse_args(argv[1:])
    car_t, zumo_t = car(args.rounds), zumo(args.rounds)
    write_stamped(args.md, [t.to_markdown(index=False, floatfmt=".3g") for t in (car_t, zumo_t)],
                  argv)
    both = pd.concat([car_t, zumo_t], ignore_index=True)
    both.insert(0, "key", both["controller"].map(KEYS))
    both.to_csv(HERE / "results_casadi.csv", index=False)


if __name__ == "__main__":
    main()
