"""The CasADi backend's time cap: a solve stopped at ``controller.solve.time_cap_ms`` is truncated.

IPOPT takes the cap as its ``max_wall_time``, sqpmethod (``sqp``, ``sqp_capped``) through an
iteration callback; either returns its last iterate, applied and counted ``truncated`` in the
run's summary, never ``converged``. Statuses and counts only: no timing is asserted.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import grouped
from mpclab.controllers.base import StepContext
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction
from mpclab.plants.zumo import Zumo

#: one microsecond: every solve stops at its first iteration check
TINY = "controller.solve.time_cap_ms=0.001"


@pytest.mark.parametrize(("overrides", "stop"), [
    (["controller=casadi"], "Maximum_WallTime_Exceeded"),
    (["controller.build.jit=false"], "User_Requested_Stop:time_cap"),
    (["controller=casadi_sqp_capped", "controller.solve.sqp_iterations=5"],
     "User_Requested_Stop:time_cap"),
], ids=["ipopt", "sqp", "sqp_capped"])
def test_a_tiny_cap_truncates_every_solve_and_the_run_completes(run_cfg, overrides,
                                                                 stop) -> None:
    res, _ = run_cfg(["+experiment=car_casadi", *overrides, TINY, "scenario.t_max=1.0"])
    s, steps = res.summary, res.steps
    calls = steps[steps["status"] != "final"]
    assert s["status"] in ("arrived", "timeout", "stalled") and s["error"] is None
    assert s["time_cap_ms"] == pytest.approx(0.001)
    assert len(calls) == s["n_steps"] > 0
    # all stopped by the cap: truncated (applied, not fallbacks), counted as such
    assert set(calls["status"]) == {"truncated"} and not calls["fallback"].any()
    assert s["solves_truncated"] == s["n_steps"] and s["solves_converged"] == 0
    assert all(str(r).startswith(stop) for r in calls["solver_status"])


def _zumo(**kw) -> CasadiMPC:
    return CasadiMPC(Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]}),
                     Objective({"J1": GoalAttraction()}), **grouped(CasadiMPC, horizon=8, dt=0.2,
                     initial_input={"u1": 2.0, "u2": 2.0}, **kw))


@pytest.mark.parametrize("solver", ["ipopt", "sqp"])
def test_a_generous_cap_changes_nothing(solver) -> None:
    goal = np.array([0.4, 0.4, 0.0])
    ctx = StepContext(goal=goal, target=np.tile(goal, (9, 1)))
    x = np.array([0.4, 0.8, -1.2])
    free = _zumo(solver=solver).step(0.0, x, ctx)
    capped = _zumo(solver=solver, time_cap_ms=60_000).step(0.0, x, ctx)
    assert free.status == capped.status == "converged"
    np.testing.assert_allclose(capped.u_pred, free.u_pred, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("kw", "why"), [
    ({"solver": "fatrop"}, "fatrop has no time limit"),
    ({"solver": "sqp_rti"}, "one QP per sample"),
    ({"solver": "sqp", "codegen": True}, "generated C"),
])
def test_solvers_without_a_cap_refuse_it_naming_those_with_one(kw, why) -> None:
    with pytest.raises(ConfigError, match=r"controller\.solve\.time_cap_ms=5 needs "
                       r"controller\.solver "
                       r"one of ipopt, sqp, sqp_capped") as err:
        _zumo(time_cap_ms=5, **kw)
    assert why in str(err.value)


@pytest.mark.parametrize("value", [0, -1.0, "fast", float("nan")])
def test_a_bad_cap_is_one_config_error(value) -> None:
    with pytest.raises(ConfigError, match=r"controller\.solve\.time_cap_ms"):
        _zumo(solver="ipopt", time_cap_ms=value)
