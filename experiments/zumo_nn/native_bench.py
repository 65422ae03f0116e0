"""Per-step time of the MPC expert and of its NN imitation, in the loop and compiled.

From the same held-out starts (seeds 100000, 100001, ...; the data used 0-999), runs the
expert (``+experiment=zumo_nn_data``) and the net (``+experiment=zumo_nn``) alternately and
pools each one's in-loop step times (what ``steps.parquet`` records: the Python call of
``Controller.step``), and the time of the expert's call into its compiled solver alone.
Then it exports the net with :mod:`mpclab.approx.export_c`, compiles it with the system C
compiler (``-O2``, and ``-O3 -march=native``), and times the C function in a C loop on the
feature vectors of every state the expert visited, checking its outputs against NumPy's.
A controller that returns a constant input, run from the same starts, gives the loop's floor:
what any step costs in the Python loop (the base class's failure handling, the result).
The table gives medians, p95 and the expert's median (whole step, and solver call only)
over each.

    uv run python experiments/zumo_nn/native_bench.py [--starts 20] [--reps 200] [--md FILE]

The table is printed with its stamp (command, commit, CPU, date); ``--md`` also writes it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mpclab.approx.evaluate import visited_features
from mpclab.approx.export_c import c_compiler, time_compiled
from mpclab.controllers.base import ControlStep, SolveStatus
from mpclab.policy.mlp import MLP
from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose

HERE = Path(__file__).resolve().parent
FIRST_HELD_OUT_SEED = 100_000

FLAGS = {"C, cc -O2": ["-O2"], "C, cc -O3 -march=native": ["-O3", "-march=native"]}


class _TimedCalls:
    """The CasADi controller's solver call (``CasadiMPC.call_solver``), timed."""

    def __init__(self, call) -> None:
        self.call, self.times = call, []

    def __call__(self) -> None:
        t0 = time.perf_counter()
        self.call()
        self.times.append(time.perf_counter() - t0)


class _Constant:
    """A controller's ``_solve`` that computes nothing: the same input every step."""

    def __init__(self, ctrl) -> None:
        self.ctrl = ctrl
        self.u = ctrl.plant.clip_input(np.full(ctrl.plant.nu, 2.0))

    def __call__(self, t, x, ctx) -> ControlStep:
        return ControlStep(u=self.u.copy(), x_pred=x[None, :], u_pred=self.ctrl._no_plan,
                           status=SolveStatus.converged)


def closed_loop(starts: int, weights: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """In-loop step times [s] of expert and net, and the expert's visited feature rows."""
    times: dict[str, list[np.ndarray]] = {"MPC expert (in the loop)": [],
                                          "MPC expert, solver call only": [],
                                          "NN, NumPy (in the loop)": [],
                                          "constant input (in the loop)": []}
    mlp = MLP.load(weights)
    rows = []
    for i in range(starts):
        seed = FIRST_HELD_OUT_SEED + i
        common = ["recorder=none", "figures.enabled=false", "progress=false", f"seed={seed}"]
        expert = build_run(compose(["+experiment=zumo_nn_data", *common]))
        solver_calls = _TimedCalls(expert.controller.call_solver)
        expert.controller.call_solver = solver_calls
        res = simulate(expert)
        times["MPC expert, solver call only"].append(np.array(solver_calls.times))
        times["MPC expert (in the loop)"].append(res.steps["solve_time_s"].dropna().to_numpy())
        steps = res.steps.dropna(subset=["solve_time_s"])
        rows.append(visited_features(mlp, expert, steps[list(expert.plant.states)]))
        net = build_run(compose(["+experiment=zumo_nn", f"controller.weights={weights}",
                                 *common]))
        res = simulate(net)
        times["NN, NumPy (in the loop)"].append(res.steps["solve_time_s"].dropna().to_numpy())
        net.controller._solve = _Constant(net.controller)  # the loop's floor for any controller
        res = simulate(net)
        times["constant input (in the loop)"].append(
            res.steps["solve_time_s"].dropna().to_numpy()
        )
        print(f"start {i + 1}/{starts}", file=sys.stderr)
    return {k: np.concatenate(v) for k, v in times.items()}, np.concatenate(rows)


def compiled(mlp: MLP, rows: np.ndarray, reps: int) -> dict[str, np.ndarray]:
    """Per-call times [s] of the exported C net, per set of compiler flags."""
    return {name: time_compiled(mlp, rows, reps, flags) for name, flags in FLAGS.items()}


def main(argv: list[str] | None = None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=20, help="held-out starts (default 20)")
    ap.add_argument("--reps", type=int, default=200, help="C calls per visited state")
    ap.add_argument("--weights", type=Path, default=HERE / "weights.npz")
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    argv = list(sys.argv if argv is None else argv)
    args = ap.parse_args(argv[1:])
    if c_compiler() is None:
        ap.error("no C compiler (cc or gcc) on PATH")
    times, rows = closed_loop(args.starts, args.weights.resolve())
    times.update(compiled(MLP.load(args.weights), rows, args.reps))
    mpc = np.median(times["MPC expert (in the loop)"])
    mpc_solver = np.median(times["MPC expert, solver call only"])
    table = pd.DataFrame([
        {"step": name, "samples": len(t), "median_us": 1e6 * np.median(t),
         "p95_us": 1e6 * np.percentile(t, 95), "MPC step / this": mpc / np.median(t),
         "MPC solver call / this": mpc_solver / np.median(t)}
        for name, t in times.items()
    ])
    write_stamped(args.md, f"{args.starts} held-out starts, {len(rows)} states the expert "
                  f"visited\n\n{table.to_markdown(index=False, floatfmt='.4g')}", argv)
    return table


if __name__ == "__main__":
    main()
