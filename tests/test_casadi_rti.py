"""The CasADi backend's real-time iteration: its QP is the NLP's linearization, its phases.

Stated tolerances: the RTI's step and one full sqpmethod step from the same point and
multipliers (the same eigen-clip convexification, the line search off) solve the same QP,
to the QP solvers' accuracy: 1e-7 on the variables and the multipliers (measured: 2e-9 and
2e-8); the initial-state embedding under multiple shooting is exact up to round-off (1e-9).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pandas as pd
import pytest

from conftest import grouped
from mpclab.constraints.obstacle import ObstacleDistance
from mpclab.controllers.base import StepContext
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.controllers.casadi.solvers import CasadiQpSolver, CasadiSolver, nlpsol_options
from mpclab.core.errors import ConfigError
from mpclab.core.native_output import c_stdout_silenced
from mpclab.core.status import SolveStatus
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction, ObstacleRepulsion
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.zumo import Zumo
from mpclab.record import files as record

GOAL = np.array([0.4, 0.4, 0.0])
X = np.array([0.4, 0.8, -1.2])
POINT = np.array([[0.45, 0.65]])


def _zumo(shooting: str = "single", qp_solver: str = "qpoases", solver: str = "sqp_rti",
          **kw) -> CasadiMPC:
    terms = {"J1": GoalAttraction(),
             "J2": QuadraticTracking(input_weights={"u1": 0.01, "u2": 0.01}),
             "J4": ObstacleRepulsion(C3=1500, L3=0.05)}
    hard = ObstacleDistance(mode="hard", distance=0.06)
    return CasadiMPC(Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]}),
                     Objective(terms, {"obstacles": hard}), **grouped(CasadiMPC, horizon=8, dt=0.2,
                     initial_input={"u1": 2.0, "u2": 2.0}, solver=solver, shooting=shooting,
                     qp_solver=qp_solver, **kw))


def _ctx() -> StepContext:
    return StepContext(goal=GOAL, target=np.tile(GOAL, (9, 1)), detections=POINT)


@pytest.mark.parametrize(("shooting", "qp_solver"),
                         [("single", "qpoases"), ("multiple", "qpoases"), ("multiple", "qrqp")])
def test_rti_step_is_one_sqpmethod_iteration(shooting, qp_solver) -> None:
    """The QP the preparation builds is the one sqpmethod solves at its first iteration:
    from the same point and multipliers (random, so that the constraints' curvature counts
    and the Hessian needs convexifying), the same step and new multipliers. (qrqp stops at
    its iteration cap on the dense single-shooting QP, in sqpmethod as here: two capped QP
    iterates are not compared.)"""
    mpc = _zumo(shooting, qp_solver, hessian="exact")
    ocp, rti = mpc.ocp, mpc._full.rti
    w0, _ = mpc._initial_guess(X, _ctx())
    p = mpc._params(X, _ctx())
    lam = np.random.default_rng(0).normal(size=ocp.lbg.size) * 0.1
    prep = rti.prepare(w0, p, lam)
    sol = rti.feedback(prep, p)
    rti.complete(prep, sol)  # the multipliers of a condensed QP's step
    name, opts = nlpsol_options(CasadiSolver.sqp_capped, CasadiQpSolver(qp_solver),
                                max_iter=100, tol=1e-6, sqp_iterations=1, warm_start=True,
                                equality=ocp.equality)
    with c_stdout_silenced():  # qpOASES' banner
        sqp = ca.nlpsol("one_step", name, ocp.nlp, opts | {"max_iter_ls": 0})  # full step
    ref = sqp(x0=w0, p=p, lbx=ocp.lbw, ubx=ocp.ubw, lbg=ocp.lbg, ubg=ocp.ubg, lam_g0=lam)
    assert sqp.stats()["iter_count"] == 1
    step = ref["x"].full().ravel() - w0
    assert np.abs(step).max() > 1.0  # a real step, not a stay
    np.testing.assert_allclose(sol.w - w0, step, rtol=0, atol=1e-7)
    np.testing.assert_allclose(sol.lam_g, ref["lam_g"].full().ravel(), rtol=0, atol=1e-7)
    assert sol.status is SolveStatus.truncated


@pytest.mark.parametrize("shooting", ["single", "multiple"])
def test_every_parameter_of_the_sample_enters_at_feedback(shooting) -> None:
    """Prepared for a predicted sample (another state, the point elsewhere, another input in
    flight), fed back the measured one: the QP is the NLP linearized with the measured
    sample's parameters, all of them (constraints, their Jacobian, the gradient), and only
    the Hessian is the preparation's."""
    mpc = _zumo(shooting)
    rti = mpc._full.rti
    w0, _ = mpc._initial_guess(X, _ctx())
    predicted = StepContext(goal=GOAL, target=np.tile(GOAL, (9, 1)),
                            detections=POINT + np.array([[0.05, -0.04]]))
    p_pred = mpc._params(X + np.array([0.01, -0.02, 0.05]), predicted)
    p = mpc._params(X, _ctx())
    assert np.abs(p_pred - p).max() > 0.01
    fed = rti.feedback(rti.prepare(w0, p_pred), p)
    direct = rti.feedback(rti.prepare(w0, p), p)
    np.testing.assert_array_equal(fed.p, p)
    lin = rti._lin(w0, p)
    for got, want in ((fed.g, lin[0]), (fed.c, lin[1]), (fed.a, lin[2].nonzeros())):
        np.testing.assert_allclose(got, np.ravel(want), rtol=0, atol=1e-12)
    np.testing.assert_allclose(fed.g, direct.g, rtol=0, atol=1e-12)


def test_rti_at_the_nlps_solution_is_converged_and_elsewhere_truncated() -> None:
    """``converged`` only when the linearization point is a KKT point: at IPOPT's solution
    (with its multipliers); one step from the cold guess is ``truncated``."""
    ref = _zumo(solver="ipopt", tol=1e-10)
    ctx = _ctx()
    ref.step(0.0, X, ctx)
    io = ref._full.io
    mpc = _zumo(tol=1e-6)
    rti = mpc._full.rti
    p = mpc._params(X, ctx)
    at_opt = rti.prepare(io["x"].copy(), p, io["lam_g"].copy(), io["lam_x"].copy())
    sol = rti.feedback(at_opt, p)
    rti.complete(at_opt, sol)
    rti.refine(at_opt, sol)
    assert sol.status is SolveStatus.converged and max(rti.kkt(at_opt, sol)) <= 1e-6
    cold = rti.prepare(mpc._initial_guess(X, ctx)[0], p)
    sol = rti.feedback(cold, p)
    rti.complete(cold, sol)
    rti.refine(cold, sol)
    assert sol.status is SolveStatus.truncated and max(rti.kkt(cold, sol)) > 1e-3


def test_rti_closed_loop_records_its_phases(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_casadi", "controller=casadi_rti"])
    s, steps = res.summary, res.steps
    calls = steps[steps["status"] != "final"]
    assert s["arrived"] and s["solver"] == "sqp_rti"
    for col in ("prep_s", "feedback_s", "feedback_cpu_s", "late_prep", "prep_overrun"):
        assert col in steps
    assert np.all(calls["prep_s"].to_numpy(dtype=float) > 0)
    assert np.all(calls["feedback_s"].to_numpy(dtype=float) > 0)
    # one QP per sample: truncated unless a KKT point, all counted
    assert set(calls["iterations"]) == {1}
    assert s["solves_truncated"] == int((calls["status"] == "truncated").sum()) > 0
    assert s["solves_truncated"] + s["solves_converged"] == s["n_steps"]
    # only the first call prepares after its measurement
    assert s["late_preps"] == 1 and bool(calls["late_prep"].iloc[0])
    assert s["feedback_median_ms"] > 0 and s["prep_median_ms"] > 0
    assert s["prep_overruns"] == int(calls["prep_overrun"].sum())


def test_two_rti_runs_give_identical_step_logs(run_cfg) -> None:
    a, _ = run_cfg(["+experiment=car_casadi", "controller=casadi_rti"], name="a")
    b, _ = run_cfg(["+experiment=car_casadi", "controller=casadi_rti"], name="b")
    timing = list(record.TIMING_COLUMNS)
    pd.testing.assert_frame_equal(a.steps.drop(columns=timing), b.steps.drop(columns=timing))


def test_measured_latency_is_the_feedback_time(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_casadi", "controller=casadi_rti",
                      "sim.latency=measured", "scenario.t_max=0.5"])
    calls = res.steps[res.steps["status"] != "final"]
    np.testing.assert_allclose(calls["latency_s"], calls["feedback_s"], rtol=1e-12)
    assert np.all(calls["feedback_s"] < calls["solve_time_s"])


def test_the_capped_sqp_keeps_its_iterations_and_the_rti_refuses_them() -> None:
    capped = _zumo(solver="sqp_capped", sqp_iterations=3)
    res = capped.step(0.0, X, _ctx())
    assert res.ok and res.iterations == 3 and "prep_s" not in res.info
    with pytest.raises(ConfigError,
                       match=r"controller\.solve\.sqp_iterations=3 .*casadi_sqp_capped"):
        _zumo(sqp_iterations=3)
    with pytest.raises(ConfigError, match=r"controller\.build\.jit=true .*sqp_rti"):
        _zumo(jit=True)


def test_an_unsafe_iterate_takes_more_qps_then_fails_to_the_fallback(run_cfg, monkeypatch):
    """An iterate whose first predicted state is deeper inside an obstacle's margin than the
    robot is now takes up to SAFETY_ITERATIONS more QPs at that sample; with a tolerance no
    iterate can meet (below zero), every sample takes them all, fails and falls back."""
    from mpclab.controllers.casadi import mpc, rti

    monkeypatch.setattr(mpc, "SAFETY_TOLERANCE", -1.0)
    res, _ = run_cfg(["+experiment=zumo_bug2", "controller=casadi_rti", "scenario.t_max=0.6"])
    calls = res.steps[res.steps["status"] != "final"]
    assert len(calls) >= 3
    assert (calls["safety_qps"] == rti.SAFETY_ITERATIONS).all()
    assert (calls["iterations"] == rti.SAFETY_ITERATIONS + 1).all()
    assert (calls["status"] == "failed").all() and calls["fallback"].all()
    assert calls["solver_status"].str.startswith("unsafe after").all()
    # the Zumo holds at rest: the fallback stops it where it is
    assert (calls[["u1", "u2"]].to_numpy() == 0.0).all()
    assert np.allclose(res.steps[["x", "y"]].to_numpy(), res.steps[["x", "y"]].iloc[0])
    assert res.summary["safety_qps"] == rti.SAFETY_ITERATIONS * len(calls)


def test_a_safe_run_takes_no_extra_qp(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_casadi", "controller=casadi_rti"])
    assert res.summary["arrived"] and res.summary["safety_qps"] == 0


def test_the_rti_hessian_is_refused_for_a_solver_that_builds_its_own() -> None:
    with pytest.raises(ConfigError, match="controller.solve.hessian=exact applies to "
                                          "controller.solver=sqp_rti"):
        _zumo(solver="ipopt", hessian="exact")
