"""Study A benchmark: the built-once DPP backend against rebuilding the QP every step.

Runs ``car_cvxpy`` (the backend as configured: Clarabel on the compiled data, the same
backend through ``Problem.solve``, and with OSQP) and, in the same process, a reference that
builds a new CVXPY problem at every step the way the study did (constants instead of
parameters, one ``Problem`` per stage summed), with the same corrected linearization about the
shifted previous plan. Whole closed-loop runs alternate (fast, reference, fast, ...) for
``--rounds`` rounds and the per-step times of each are pooled.

    uv run python experiments/car_cvxpy/bench.py [--rounds 5]
"""

from __future__ import annotations

import argparse
import sys

import cvxpy as cp
import numpy as np
import pandas as pd

from mpclab.controllers.base import ControlStep, SolveStatus, StepContext
from mpclab.controllers.cvxpy import CvxpyMPC
from mpclab.experiment import build_run, compose
from mpclab.objectives.base import TermContext
from mpclab.sim import simulate


class RebuildEveryStep(CvxpyMPC):
    """The study's way: a fresh problem (constants, not parameters) at every step."""

    def _solve(self, t: float, x: np.ndarray, ctx: StepContext) -> ControlStep:
        Xbar, Ubar = self._linearization_points(x)
        A, B, c = self.plant.linearize_trajectory(Xbar, Ubar, self.dt)
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
        )


def make_runs(overrides: list[str]):
    cfg = compose(["+experiment=car_cvxpy", "recorder=none", *overrides])
    fast = build_run(cfg)
    ref = build_run(cfg)
    c = ref.controller
    ref.controller = RebuildEveryStep(
        c.plant, c.objective, horizon=c.horizon, dt=c.dt, solver=c.solver,
        terminal_constraint={"v": 0.0},
    )
    return fast, ref


def main(argv: list[str] | None = None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    variants = {
        "built once (DPP), Clarabel": make_runs([]),
        "built once (DPP), Clarabel via Problem.solve": make_runs(
            ["controller.solve_via=problem"]
        ),
        "built once (DPP), OSQP": make_runs(["controller.solver=OSQP"]),
    }
    ref_name = "rebuilt every step (study), Clarabel"
    times: dict[str, list[np.ndarray]] = {name: [] for name in [*variants, ref_name]}
    summaries: dict[str, dict] = {}
    for r in range(args.rounds):
        for name, (fast, ref) in variants.items():
            res = simulate(fast)
            times[name].append(res.steps["solve_time_s"].dropna().to_numpy())
            summaries[name] = res.summary
            if name == "built once (DPP), Clarabel":  # interleave: the reference right after
                res = simulate(ref)
                times[ref_name].append(res.steps["solve_time_s"].dropna().to_numpy())
                summaries[ref_name] = res.summary
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr)
    rows = []
    ref_median = np.median(np.concatenate(times[ref_name]))
    for name, chunks in times.items():
        t = np.concatenate(chunks)
        s = summaries[name]
        sim = s["sim_time_s"]
        rows.append({
            "controller": name,
            "status": s["status"],
            "arrival_s": s["arrival_time_s"],
            "steps": s["n_steps"],
            "median_ms": 1e3 * np.median(t),
            "p95_ms": 1e3 * np.percentile(t, 95),
            "compute/sim": float(np.sum(t)) / args.rounds / sim,
            "speed-up (median)": ref_median / np.median(t),
        })
    table = pd.DataFrame(rows)
    print(table.to_markdown(index=False, floatfmt=".3g"))
    return table


if __name__ == "__main__":
    main()
