"""The study's program in experiments/car_cvxpy/bench.py (a CVXPY problem rebuilt every step)
solves the same one-pass QP as the built-once controller with ``sl=one_pass``."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from mpclab.controllers.base import SolveStatus, StepContext

_PATH = Path(__file__).resolve().parents[1] / "experiments/car_cvxpy/bench.py"
_spec = importlib.util.spec_from_file_location("car_cvxpy_bench", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_the_rebuilt_program_takes_the_one_pass_step() -> None:
    plans = {}
    runs = {"rebuilt": bench.rebuilt(), "one_pass": bench.build(["controller.sl=one_pass"])}
    for name, run in runs.items():
        c, scen = run.controller, run.scenario
        x = scen.x0.copy()
        c.reset(x)
        ctx = StepContext(goal=scen.goal, target=scen.target(0.0, c.horizon, c.dt))
        plans[name] = c.step(0.0, x, ctx)
    span = run.plant.u_ub - run.plant.u_lb
    for plan in plans.values():
        assert plan.status is SolveStatus.truncated  # one pass, not iterated
    du = np.abs(plans["rebuilt"].u_pred - plans["one_pass"].u_pred) / span
    assert du.max() < 1e-3
