"""A Run simulated twice with the same objects gives the same step log: nothing a solver keeps
between runs (warm starts, multipliers, a persistent solver's scaling) leaks from one run into
the next. Benchmarks, DAgger and the evaluation reuse runs this way."""

from __future__ import annotations

import pandas as pd
import pytest

from mpclab.record import files as record
from mpclab.runner.loop import simulate
from mpclab.runner.single_run import CONF_DIR, build_run, compose

CVXPY_VARIANTS = {
    "car_cvxpy-clarabel-direct": ["+experiment=car_cvxpy"],
    "car_cvxpy-clarabel-problem": ["+experiment=car_cvxpy", "controller.solve.via=problem"],
    "car_cvxpy-osqp": ["+experiment=car_cvxpy", "controller.solver=OSQP"],  # warm-started
    "bicycle-clarabel-direct": ["+experiment=bicycle_scheduled", "controller.solver=CLARABEL"],
    "bicycle-osqp": ["+experiment=bicycle_scheduled", "controller.solver=OSQP",
                     "scenario.t_max=4.0"],
}
OTHERS = {
    p.stem: [f"+experiment={p.stem}"]
    for p in sorted((CONF_DIR / "experiment").glob("*.yaml"))
    if p.stem != "car_cvxpy"
}


@pytest.mark.parametrize("overrides", [*CVXPY_VARIANTS.values(), *OTHERS.values()],
                         ids=[*CVXPY_VARIANTS, *OTHERS])
def test_a_reused_run_repeats_itself(overrides: list[str]) -> None:
    run = build_run(compose([*overrides, "recorder=none", "figures.enabled=false"]))
    timing = list(record.TIMING_COLUMNS)
    first = simulate(run).steps.drop(columns=timing, errors="ignore")
    second = simulate(run).steps.drop(columns=timing, errors="ignore")
    pd.testing.assert_frame_equal(first, second)
