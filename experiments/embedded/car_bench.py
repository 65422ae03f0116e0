"""Study A from generated C: the car's converged SQP as CasADi-generated C against the study's
program (a CVXPY problem rebuilt every step) and the Python-driven compiled solver, one run.

    uv run python experiments/embedded/car_bench.py [--rounds 5]

Whole closed loops of ``car_to_origin`` alternate for ``--rounds`` rounds; per-step times
(wall clock and this thread's CPU time) are pooled (``compare`` of the car_cvxpy benchmark;
a generated solver reports no iteration count, so its QP columns are empty). Rows: the
study's program (one pass, rebuilt every step: ``experiments/car_cvxpy/bench.py``),
``car_casadi`` (sqpmethod + qrqp, the NLP's functions compiled: ``jit``), and the same with
``controller.codegen=true`` (the whole solver generated as C by CasADi, its status by the KKT
test), at ``-O1`` and ``-O2``.
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import pandas as pd

from mpclab.experiment import build_run, compose

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
    return car_cvxpy_bench.compare(runs, args.rounds)

if __name__ == "__main__":
    main()
