"""The car's converged SQP as CasADi-generated C (SIL): the same closed loop as the library
solver it was generated from, and a status that only a KKT-satisfying point gets.

Stated tolerance: 1e-6 on the inputs (m/s^2, rad/s) at every step of a whole run; both are
sqpmethod + qrqp, one compiled from CasADi's C++ and one from its generated C.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from mpclab.codegen import build as codegen_build
from mpclab.controllers.base import SolveStatus, StepContext
from mpclab.errors import ConfigError
from mpclab.experiment import build_run, compose

pytestmark = pytest.mark.skipif(codegen_build.find_compiler() is None, reason="no C compiler")

CAR = ["+experiment=car_casadi", "recorder=none", "progress=false", "figures.enabled=false"]


@pytest.mark.slow
def test_generated_solver_runs_the_car_as_the_library_solver(run_cfg) -> None:
    _, lib_dir = run_cfg(CAR, name="library")
    _, gen_dir = run_cfg([*CAR, "controller.codegen=true"], name="generated")
    s_lib, s_gen = (json.loads((d / "summary.json").read_text()) for d in (lib_dir, gen_dir))
    assert (s_lib["codegen"], s_gen["codegen"]) == (False, True)
    assert s_gen["status"] == "arrived" and s_gen["converged_fraction"] == 1.0
    assert s_gen["arrival_time_s"] == pytest.approx(s_lib["arrival_time_s"])
    a, b = (pd.read_parquet(d / "steps.parquet").query("status != 'final'")
            for d in (lib_dir, gen_dir))
    assert len(a) == len(b) and (b["solver_status"] == "kkt_met").all()
    np.testing.assert_allclose(b[["a", "phi_dot"]], a[["a", "phi_dot"]], rtol=0, atol=1e-6)


def test_a_capped_generated_solve_is_never_converged() -> None:
    """One SQP iteration from the start does not meet the KKT test: failed, and the base
    class falls back; with the iterations it needs, the same state converges."""
    capped = build_run(compose([*CAR, "controller.codegen=true", "controller.max_iter=1"]))
    full = build_run(compose([*CAR, "controller.codegen=true"]))
    scen = capped.scenario
    for run, expected in ((capped, SolveStatus.failed), (full, SolveStatus.converged)):
        c = run.controller
        ctx = StepContext(goal=scen.goal, target=scen.target(0.0, c.horizon, c.dt))
        res = c.step(0.0, scen.x0, ctx)
        assert res.status is expected
        assert res.fallback == (expected is SolveStatus.failed)
    assert res.solver_status == "kkt_met"


def test_codegen_needs_the_sqp_solver() -> None:
    with pytest.raises(ConfigError, match="solver=sqp"):
        build_run(compose(["+experiment=zumo_bug2", "recorder=none",
                           "controller.codegen=true"]))
