"""Solve statuses: one vocabulary, read robustly, never a capped solve called converged."""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from conftest import grouped
from mpclab.controllers.base import ControlStep, SolveStatus, StepContext
from mpclab.controllers.casadi.mpc import CasadiMPC, read_status
from mpclab.controllers.casadi.solvers import CALL_FAILED
from mpclab.core.status import PROBLEM_KEY, Problem
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction
from mpclab.plants.zumo import Zumo
from mpclab.record import files as record


def _zumo(**kw) -> CasadiMPC:
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    return CasadiMPC(plant, Objective({"J1": GoalAttraction()}), **grouped(
        CasadiMPC, horizon=6, dt=0.2, initial_input={"u1": 2.0, "u2": 2.0}, **kw))


def _ctx() -> StepContext:
    goal = np.array([0.4, 0.4, 0.0])
    return StepContext(goal=goal, target=np.tile(goal, (7, 1)))


class _Raises:
    def stats(self):
        raise RuntimeError("basic_string: construction from null is not valid")


class _Stats:
    def __init__(self, **stats) -> None:
        self._stats = stats

    def stats(self):
        return self._stats


@pytest.mark.parametrize(("stats", "expected"), [
    ({"return_status": "Solve_Succeeded", "success": True, "iter_count": 9},
     SolveStatus.converged),
    ({"return_status": "Solved_To_Acceptable_Level", "success": True}, SolveStatus.truncated),
    ({"return_status": "Maximum_Iterations_Exceeded", "success": False,
      "unified_return_status": "SOLVER_RET_LIMITED"}, SolveStatus.truncated),
    ({"return_status": "Infeasible_Problem_Detected", "success": False,
      "unified_return_status": "SOLVER_RET_INFEASIBLE"}, SolveStatus.infeasible),
    ({"return_status": "0", "success": True, "iter_count": 7}, SolveStatus.converged),  # fatrop
    ({"return_status": "1", "success": False}, SolveStatus.truncated),  # fatrop's cap
    ({"return_status": "4", "success": False}, SolveStatus.failed),
    ({"return_status": "Search_Direction_Becomes_Too_Small", "success": False,
      "unified_return_status": "SOLVER_RET_UNKNOWN"}, SolveStatus.failed),
    ({"return_status": "Whatever", "success": False,
      "unified_return_status": "SOLVER_RET_SUCCESS"}, SolveStatus.failed),
])
def test_status_is_read_from_what_the_solver_says(stats, expected) -> None:
    status, raw, _ = read_status(_Stats(**stats))
    assert status is expected and raw == stats["return_status"]


def test_stats_that_raise_are_a_failed_solve_not_a_crash() -> None:
    assert read_status(_Raises()) == (SolveStatus.failed, "no_status", None)


@pytest.mark.parametrize("cap", [1, 2])
def test_an_ipopt_iteration_cap_is_truncated_and_applied(cap: int) -> None:
    res = _zumo(max_iter=cap).step(0.0, np.array([0.4, 0.8, 0.0]), _ctx())
    assert res.status is SolveStatus.truncated and not res.fallback
    assert res.solver_status == "Maximum_Iterations_Exceeded" and res.iterations == cap


def test_ipopt_to_tolerance_is_converged() -> None:
    res = _zumo().step(0.0, np.array([0.4, 0.8, 0.0]), _ctx())
    assert res.status is SolveStatus.converged and res.solver_status == "Solve_Succeeded"
    assert res.iterations is not None and res.iterations > 1


@pytest.mark.parametrize("where", ["u", "x_pred"])
def test_a_nan_result_labelled_success_is_a_failure_and_falls_back(where, monkeypatch) -> None:
    """A NaN input, or a NaN in the predicted states, from a solve that says it converged."""
    mpc = _zumo()
    x = np.array([0.4, 0.8, 0.0])
    first = mpc.step(0.0, x, _ctx())

    def nan_success(t, x, ctx):
        T, nu = mpc.horizon, mpc.plant.nu
        res = ControlStep(u=np.zeros(nu), x_pred=np.zeros((T + 1, 3)),
                          u_pred=np.zeros((T, nu)), status=SolveStatus.converged,
                          solver_status="Solve_Succeeded")
        getattr(res, where).flat[-1] = np.nan
        return res

    monkeypatch.setattr(mpc, "_solve", nan_success)
    res = mpc.step(0.2, x, _ctx())
    assert res.status is SolveStatus.failed and res.fallback
    assert res.solver_status == "non_finite(Solve_Succeeded)"
    np.testing.assert_allclose(res.u, first.u_pred[1])


@pytest.mark.parametrize("word", ["optimal", None, 3])
def test_a_status_outside_the_vocabulary_is_a_counted_failure(word, monkeypatch) -> None:
    """A backend that returns its own word (not a SolveStatus) has failed: the call falls
    back and is counted with the failed ones, never with none of them."""
    mpc = _zumo()
    x = np.array([0.4, 0.8, 0.0])
    first = mpc.step(0.0, x, _ctx())

    def own_word(t, x, ctx):
        T, nu = mpc.horizon, mpc.plant.nu
        return ControlStep(u=np.ones(nu), x_pred=np.tile(x, (T + 1, 1)),
                           u_pred=np.ones((T, nu)), status=word, iterations=2)

    monkeypatch.setattr(mpc, "_solve", own_word)
    res = mpc.step(0.2, x, _ctx())
    assert res.status is SolveStatus.failed and res.fallback
    assert res.solver_status == f"unknown_status({word!r})" and res.iterations == 2
    np.testing.assert_allclose(res.u, first.u_pred[1])
    monkeypatch.setattr(mpc, "_solve", lambda t, x, ctx: replace(
        own_word(t, x, ctx), status="converged"))  # a plain string of the vocabulary is it
    assert mpc.step(0.4, x, _ctx()).status is SolveStatus.converged


def test_summary_counts_every_status(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_casadi", "controller=casadi", "controller.solve.max_iter=3"])
    s = res.summary
    counts = {st: s[f"solves_{st}"] for st in SolveStatus}
    assert sum(counts.values()) == s["n_steps"]
    assert counts[SolveStatus.truncated] > 0  # three IPOPT iterations do not converge
    assert s["converged_fraction"] == pytest.approx(counts[SolveStatus.converged] / s["n_steps"])
    steps = record.controller_steps(res.steps)
    capped = steps["solver_status"] == "Maximum_Iterations_Exceeded"
    assert (steps.loc[capped, "status"] == "truncated").all()
    assert (steps.loc[capped, "iterations"] == 3).all()


@pytest.mark.parametrize(("overrides", "cap"), [
    (["+experiment=car_casadi", "controller.solve.max_iter=1"], 1),          # SQP + qrqp
    (["+experiment=car_casadi", "controller.solve.max_iter=3"], 3),
    (["+experiment=zumo_bug2", "controller.solve.max_iter=3"], 3),           # fatrop
    (["+experiment=zumo_bug2", "controller=casadi_sqp_capped",
      "controller.solve.sqp_iterations=1"], 1),
    (["+experiment=zumo_bug2", "controller=casadi_sqp_capped",
      "controller.solve.sqp_iterations=5"], 5),
], ids=["car_sqp_1", "car_sqp_3", "zumo_fatrop_3", "zumo_rti_1", "zumo_rti_5"])
def test_any_iteration_cap_is_truncated_never_an_exception(run_cfg, overrides, cap) -> None:
    res, _ = run_cfg([*overrides, "scenario.t_max=2.0"])
    s = res.summary
    assert s["status"] != "error", s["error"]
    assert s["solves_exception"] == 0
    steps = record.controller_steps(res.steps)
    unconverged = steps[steps["status"] != "converged"]
    assert len(unconverged) > 0 and s["solves_truncated"] == len(unconverged)
    assert (unconverged["status"] == "truncated").all()
    # the cap is what stopped them (fatrop counts one more; sqpmethod's own count can stop
    # short of its cap while it reports Maximum_Iterations_Exceeded)
    assert (unconverged["iterations"] >= cap).any()
    assert (steps["iterations"] <= cap + 1).all()


@pytest.mark.parametrize(("overrides", "problem"), [
    (["+experiment=bicycle_scheduled"], Problem.scheduled_linear),
    (["+experiment=bicycle_interpolated"], Problem.scheduled_linear),
    (["+experiment=bicycle_adaptive"], Problem.linearized),
    (["+experiment=car_cvxpy"], Problem.nonlinear),
    (["+experiment=car_cvxpy", "controller.sl=one_pass"], Problem.linearized),
    (["+experiment=car_casadi"], Problem.nonlinear),
    (["+experiment=zumo_nn"], Problem.policy),
], ids=["switched", "interpolated", "adaptive", "cvxpy_converge", "cvxpy_one_pass", "casadi",
        "nn"])
def test_the_record_says_what_problem_converged_means(run_cfg, overrides, problem) -> None:
    """A linear-model backend's exact QP is `converged`, and the record tells it apart from
    an NLP solved to its tolerance by the `problem` it names."""
    res, out = run_cfg([*overrides, "scenario.t_max=0.4"])
    s = record.read_summary(out)
    assert s["status"] != "error", s["error"]
    assert s[PROBLEM_KEY] == problem.value
    assert Problem(s[PROBLEM_KEY]) is problem


def test_a_call_that_ends_in_an_error_is_failed_whatever_status_it_left() -> None:
    """sqpmethod returns an error without writing a status when its Hessian has a NaN: the
    return string is the previous call's (here an iteration cap), the call is failed."""
    x = ca.SX.sym("x", 2)
    f = (x[0] - 1) ** 2 + x[1] ** 2 + ca.fabs(x[1]) ** 1.5  # Hessian NaN at x[1] = 0
    quiet = {"print_time": False, "print_header": False, "print_iteration": False,
             "print_status": False}
    solver = ca.nlpsol("s", "sqpmethod", {"x": x, "f": f}, {
        "max_iter": 1, "qpsol": "qrqp", **quiet,
        "qpsol_options": {"print_iter": False, "print_header": False, "error_on_fail": False}})
    buffer, trigger = solver.buffer()
    x0, x_out = np.array([0.5, 1.0]), np.zeros(2)
    buffer.set_arg(0, memoryview(x0))
    buffer.set_res(0, memoryview(x_out))
    trigger()
    assert read_status(buffer)[:2] == (SolveStatus.truncated, "Maximum_Iterations_Exceeded")
    x0[:] = [0.5, 0.0]
    trigger()
    assert buffer.stats()["return_status"] == "Maximum_Iterations_Exceeded"  # left over
    status, raw, _ = read_status(buffer)
    assert status is SolveStatus.failed and raw.startswith(CALL_FAILED)
