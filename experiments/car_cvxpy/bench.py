"""Study A benchmark: converged and one-pass successive linearization, built once, against
rebuilding the QP every step.

Runs ``car_cvxpy`` as configured (the linearization iterated to convergence with a trust
region and the exact Hessian, Clarabel on the compiled data), the same with the Gauss-Newton
QP, through ``Problem.solve``, in the one-pass mode (``sl=one_pass``: one QP per step,
truncated), and, in the same process, a reference that builds a new CVXPY problem at every
step the way the study did (constants instead of parameters, one ``Problem`` per stage summed)
with the one-pass linearization; and ``car_casadi``, the same OCP solved as a nonlinear program
to convergence (CasADi's SQP with qrqp, compiled). Whole closed-loop runs alternate for
``--rounds`` rounds and the per-step times of each are pooled.

    uv run python experiments/car_cvxpy/bench.py [--rounds 5] [--md FILE]

Prints the table with its stamp (command, commit, CPU, date); ``--md`` also writes it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cvxpy as cp
import numpy as np
import pandas as pd

from mpclab.controllers.base import ControlStep, SolveStatus, StepContext
from mpclab.controllers.cvxpy.mpc import CvxpyMPC
from mpclab.objectives.base import TermContext
from mpclab.record.provenance import write_stamped
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import build_run, compose


class RebuildEveryStep(CvxpyMPC):
    """The study's way: a fresh problem (constants, not parameters) at every step."""

    def _solve(self, t: float, x: np.ndarray, ctx: StepContext) -> ControlStep:
        Xbar, Ubar = self._linearization_points(x)  # the one-pass linearization
        A, B, c = self.plant.linearize_trajectory(Xbar[:-1], Ubar, self.dt)
        nx, nu, T, p = self.plant.nx, self.plant.nu, self.horizon, self.plant
        X, U = cp.Variable((nx, T + 1)), cp.Variable((nu, T))
        target = TermContext(x0=x, target=ctx.target.T, u_prev=np.zeros(nu))
        stages = []
        for k in range(T):
            cons = [X[:, k + 1] == A[k] @ X[:, k] + B[k] @ U[:, k] + c[k]]
            cons += [cp.norm(U[j, k], "inf") <= p.u_ub[j] for j in range(nu)]
            bounded = [i for i in range(nx) if np.isfinite(p.x_ub[i])]
            cons += [cp.norm(X[i, k + 1], "inf") <= p.x_ub[i] for i in bounded]
            stages.append(cp.Problem(cp.Minimize(0), cons))
        total = sum(stages)
        cost = sum(term.cvxpy_cost(X, U, target) for term in self.objective)
        cons = total.constraints + [X[:, 0] == x, X[p.state_index("v"), T] == 0.0]
        prob = cp.Problem(cp.Minimize(cost), cons)
        prob.solve(solver=self.solver)
        if prob.status != cp.OPTIMAL:
            return self._failed(SolveStatus.failed, x, str(prob.status))
        return ControlStep(  # one linearize-and-solve pass, as the study: truncated
            u=U.value[:, 0].copy(), x_pred=X.value.T.copy(), u_pred=U.value.T.copy(),
            status=SolveStatus.truncated, cost=float(prob.value), solver_status=prob.status,
            iterations=1,
        )


def build(overrides: list[str]):
    return build_run(compose(["+experiment=car_cvxpy", "recorder=none", *overrides]))


def rebuilt() -> object:
    """The study's program: one pass, a fresh CVXPY problem every step."""
    run = build(["controller.sl=one_pass"])
    c = run.controller
    run.controller = RebuildEveryStep(
        c.plant, c.objective, horizon=c.horizon, dt=c.dt, solver=c.solver, sl="one_pass",
        initial_input={"a": float(c._u_guess[0])}, terminal_constraint={"v": 0.0},
    )
    return run


REF = "one pass, rebuilt every step (study's program)"


def cpu_timed(run, log: list[float]) -> None:
    """Record the CPU time of each controller call (this thread's: less inflated than the
    wall clock on a shared machine, where a step may wait for a core)."""
    step = run.controller.step

    def timed(*args, **kwargs):
        t0 = time.thread_time()
        res = step(*args, **kwargs)
        log.append(time.thread_time() - t0)
        return res

    run.controller.step = timed


def main(argv: list[str] | None = None) -> pd.DataFrame:
    argv = list(sys.argv if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--md", type=Path, help="also write the stamped table here")
    args = ap.parse_args(argv[1:])
    runs = {
        "converged SL, exact Hessian (default)": build([]),
        "converged SL, exact Hessian, via Problem.solve": build(["controller.solve.via=problem"]),
        "converged SL, Gauss-Newton QP (cap 20)": build(["controller.solve.hessian=gauss_newton"]),
        "one pass (sl=one_pass)": build(["controller.sl=one_pass"]),
        REF: rebuilt(),
        # the same OCP as a nonlinear program: CasADi's SQP (qrqp) to convergence, compiled
        # (iterations are SQP iterations, one QP each)
        "converged NLP, CasADi SQP + qrqp, compiled (car_casadi)": build_run(
            compose(["+experiment=car_casadi", "recorder=none"])),
    }
    table = compare(runs, args.rounds)
    write_stamped(args.md, table.to_markdown(index=False, floatfmt=".3g"), argv)
    return table


def compare(runs: dict, rounds: int) -> pd.DataFrame:
    """Alternate whole runs of ``runs`` for ``rounds`` rounds, pool their per-step times and
    return the table (speed-ups against the study's program, ``runs[REF]``)."""
    steps: dict[str, list[pd.DataFrame]] = {name: [] for name in runs}
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    for name, run in runs.items():
        cpu_timed(run, cpu[name])
    summaries: dict[str, dict] = {}
    for r in range(rounds):
        for name, run in runs.items():
            res = simulate(run)
            steps[name].append(res.steps[res.steps["status"] != "final"])
            summaries[name] = res.summary
        print(f"round {r + 1}/{rounds} done", file=sys.stderr)
    rows = []
    ref_median = np.median(pd.concat(steps[REF])["solve_time_s"])
    for name, chunks in steps.items():
        calls = pd.concat(chunks)
        t = calls["solve_time_s"].to_numpy()
        s = summaries[name]
        rows.append({
            "controller": name,
            "arrival_s": s["arrival_time_s"],
            "steps": s["n_steps"],
            "converged": s["converged_fraction"],
            "QPs/step (median, max)": f"{np.median(calls['iterations']):g}, "
                                      f"{calls['iterations'].max():g}",
            "median_ms": 1e3 * np.median(t),
            "p95_ms": 1e3 * np.percentile(t, 95),
            "cpu_median_ms": 1e3 * np.median(cpu[name]),
            "ms/QP": (1e3 * t.sum() / calls["iterations"].sum()  # none: count unknown
                      if calls["iterations"].notna().all() else float("nan")),
            "compute/sim": float(np.sum(t)) / rounds / s["sim_time_s"],
            "speed-up (median)": ref_median / np.median(t),
            "speed-up (cpu median)": np.median(cpu[REF]) / np.median(cpu[name]),
        })
    return pd.DataFrame(rows)


if __name__ == "__main__":
    main()
