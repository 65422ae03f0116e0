"""The CVXPY backend: built once, DPP, the right QP, and failures survived."""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest

from conftest import grouped
from mpclab.controllers.base import StepContext
from mpclab.controllers.cvxpy.mpc import CvxpyMPC
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective, Term
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.kinematic_car import KinematicCar

X0 = np.array([-10.0, 10.0, 0.0, 0.0, 0.0])


def make(**options):
    car = KinematicCar(
        input_bounds={"a": [-10, 10], "phi_dot": [-3, 3]},
        state_bounds={"phi": [-np.pi / 4, np.pi / 4]},
    )
    obj = Objective(
        {"tracking": QuadraticTracking({"px": 100, "py": 100}, {"a": 0.01, "phi_dot": 0.01})}
    )
    return car, CvxpyMPC(car, obj, **grouped(CvxpyMPC, terminal_constraint={"v": 0.0}, **options))


def ctx(T: int = 10) -> StepContext:
    return StepContext(goal=np.zeros(5), target=np.zeros((T + 1, 5)))


def reference_qp(car: KinematicCar, x0: np.ndarray, Xbar, Ubar, T: int = 10, dt: float = 0.1):
    """Study A's QP written out with constants and solved by OSQP (not the backend's solver)."""
    X, U = cp.Variable((5, T + 1)), cp.Variable((2, T))
    cost, cons = 0, [X[:, 0] == x0, X[3, T] == 0]
    for k in range(T):
        A, B, c = car.linearize(Xbar[k], Ubar[k], dt)
        cost += 100 * cp.sum_squares(X[0:2, k + 1]) + 0.01 * cp.sum_squares(U[:, k])
        cons += [
            X[:, k + 1] == A @ X[:, k] + B @ U[:, k] + c,
            cp.abs(U[0, k]) <= 10, cp.abs(U[1, k]) <= 3, cp.abs(X[4, k + 1]) <= np.pi / 4,
        ]
    prob = cp.Problem(cp.Minimize(cost), cons)
    prob.solve(solver="OSQP", eps_abs=1e-10, eps_rel=1e-10, max_iter=200000, polishing=True)
    return U.value.T, prob.value


def test_problem_is_dpp_and_built_once() -> None:
    _, ctrl = make()
    assert ctrl.problem.is_dpp()
    problem = ctrl.problem
    ctrl.reset(X0)
    for k in range(3):
        ctrl.step(0.1 * k, X0, ctx())
    assert ctrl.problem is problem  # only parameter values change between steps


def test_first_step_matches_reference_qp() -> None:
    car, ctrl = make(sl="one_pass")
    ctrl.reset(X0)
    res = ctrl.step(0.0, X0, ctx())
    assert res.ok and not res.fallback
    Ubar = np.zeros((10, 2))
    Xbar = car.rollout(X0, Ubar, 0.1)[:-1]
    U_ref, cost_ref = reference_qp(car, X0, Xbar, Ubar)
    np.testing.assert_allclose(res.u_pred, U_ref, atol=1e-4)
    assert res.cost == pytest.approx(cost_ref, rel=1e-6)


def test_second_step_linearizes_about_the_shifted_plan() -> None:
    car, ctrl = make(sl="one_pass")
    ctrl.reset(X0)
    first = ctrl.step(0.0, X0, ctx())
    x1 = car.step(X0, first.u, 0.1)
    second = ctrl.step(0.1, x1, ctx())
    Ubar = np.concatenate([first.u_pred[1:], first.u_pred[-1:]])
    Xbar = np.concatenate([first.x_pred[1:], first.x_pred[-1:]])[:-1]
    Xbar[0] = x1
    U_ref, cost_ref = reference_qp(car, x1, Xbar, Ubar)
    # the last steering rates barely move the cost (~1e4): compare the applied input tightly,
    # the rest of the plan to the accuracy the solvers' tolerances allow
    np.testing.assert_allclose(second.u, U_ref[0], atol=1e-4)
    np.testing.assert_allclose(second.u_pred, U_ref, atol=1e-2)
    assert second.cost == pytest.approx(cost_ref, rel=1e-6)


@pytest.mark.parametrize("sl", ["one_pass", "converge"])
def test_osqp_and_clarabel_agree(sl: str) -> None:
    _, c1 = make(solver="CLARABEL", sl=sl)
    _, c2 = make(solver="OSQP", sl=sl, options={"eps_abs": 1e-9, "eps_rel": 1e-9})
    r1, r2 = c1.step(0.0, X0, ctx()), c2.step(0.0, X0, ctx())
    np.testing.assert_allclose(r1.u, r2.u, atol=1e-4)


@pytest.mark.parametrize("sl", ["one_pass", "converge"])
def test_direct_path_equals_problem_solve(sl: str) -> None:
    """The compiled-data path and ``Problem.solve`` give the same plan and cost."""
    _, direct = make(sl=sl)
    _, problem = make(via="problem", sl=sl)
    assert direct.direct is not None and problem.direct is None
    car = direct.plant
    x = X0
    for k in range(5):  # a few closed-loop steps, so the LTV model varies
        r1, r2 = direct.step(0.1 * k, x, ctx()), problem.step(0.1 * k, x, ctx())
        assert r1.ok and r2.ok
        np.testing.assert_allclose(r1.u_pred, r2.u_pred, atol=1e-7)
        np.testing.assert_allclose(r1.x_pred, r2.x_pred, atol=1e-7)
        assert r1.cost == pytest.approx(r2.cost, rel=1e-9)
        x = car.step(x, r1.u, 0.1)


def test_direct_path_data_equal_cvxpy_at_random_parameters() -> None:
    _, ctrl = make()
    data, _, _ = ctrl.problem.get_problem_data(cp.CLARABEL)
    rng = np.random.default_rng(3)
    for p in ctrl.problem.parameters():
        p.value = rng.normal(size=p.shape)
    P, q, d, A, b = ctrl.direct.data()
    P_ref, q_ref, d_ref, A_ref, b_ref = data[cp.settings.PARAM_PROB].apply_parameters(
        quad_obj=True
    )
    np.testing.assert_allclose(P.toarray(), np.triu(P_ref.toarray()), atol=1e-12)
    np.testing.assert_allclose(A.toarray(), -A_ref.toarray(), atol=1e-12)
    np.testing.assert_allclose(q, q_ref, atol=1e-12)
    np.testing.assert_allclose(b, b_ref, atol=1e-12)
    assert d == pytest.approx(d_ref)


def test_direct_path_needs_clarabel_and_known_settings() -> None:
    with pytest.raises(ConfigError, match="via=direct needs solver CLARABEL, not OSQP"):
        make(solver="OSQP", via="direct")
    with pytest.raises(ConfigError, match=r"unknown Clarabel setting 'max_iters'.*max_iter"):
        make(options={"max_iters": 10})
    _, ctrl = make(solver="OSQP")  # auto: OSQP goes through Problem.solve
    assert ctrl.direct is None


def test_direct_path_that_cannot_be_built_falls_back_or_refuses(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from mpclab.controllers.cvxpy import direct as cvxpy_direct

    def unusable(self, *args, **kwargs):
        raise ValueError("the compiled data disagree with CVXPY's: {'A': 1.0}")

    monkeypatch.setattr(cvxpy_direct.DirectClarabel, "__init__", unusable)
    with pytest.warns(UserWarning, match="solving through Problem.solve: the compiled data"):
        _, ctrl = make()  # auto: warn and take Problem.solve
    assert ctrl.direct is None and ctrl.step(0.0, X0, ctx()).ok
    with pytest.raises(ConfigError, match="via=direct is not possible: the compiled"):
        make(via="direct")


@pytest.mark.parametrize("via", ["direct", "problem"])
def test_infeasible_qp_falls_back_with_its_status(via: str) -> None:
    """A real infeasible QP: at 100 m/s, |a| <= 10 cannot stop the car within 1 s."""
    _, ctrl = make(via=via)
    fast = X0.copy()
    fast[3] = 100.0
    res = ctrl.step(0.0, fast, ctx())
    assert res.status == "infeasible" and res.fallback and not res.ok
    np.testing.assert_array_equal(res.u, np.zeros(2))  # no previous plan: zero input
    first = ctrl.step(0.1, X0, ctx())
    assert first.ok
    again = ctrl.step(0.2, fast, ctx())
    assert again.status == "infeasible" and again.fallback
    np.testing.assert_array_equal(again.u, first.u_pred[1])  # the previous plan, shifted


def test_solver_exception_falls_back_to_shifted_plan(monkeypatch: pytest.MonkeyPatch) -> None:
    _, ctrl = make(via="problem")
    first = ctrl.step(0.0, X0, ctx())

    def broken(*args, **kwargs):
        raise cp.error.SolverError("injected failure")

    monkeypatch.setattr(ctrl.problem, "solve", broken)
    res = ctrl.step(0.1, X0, ctx())
    assert res.status == "failed" and res.solver_status == "solver_error"
    assert res.fallback and not res.ok
    assert res.info["error"] == "injected failure"
    np.testing.assert_array_equal(res.u, first.u_pred[1])
    np.testing.assert_array_equal(res.u_pred[:-1], first.u_pred[1:])
    again = ctrl.step(0.2, X0, ctx())  # a second failure shifts the fallback plan again
    np.testing.assert_array_equal(again.u, first.u_pred[2])


def test_direct_solver_crash_is_survived(monkeypatch: pytest.MonkeyPatch) -> None:
    _, ctrl = make()
    first = ctrl.step(0.0, X0, ctx())

    def crash():
        raise RuntimeError("injected crash")

    monkeypatch.setattr(ctrl.direct, "solve", crash)
    res = ctrl.step(0.1, X0, ctx())
    assert res.status == "exception" and res.solver_status == "RuntimeError" and res.fallback
    np.testing.assert_array_equal(res.u, first.u_pred[1])


def test_failure_with_no_plan_gives_zero_input(monkeypatch: pytest.MonkeyPatch) -> None:
    _, ctrl = make(via="problem")

    def infeasible(*args, **kwargs):
        ctrl.problem._status = cp.INFEASIBLE  # what a solver reports for an infeasible QP
        return np.inf

    monkeypatch.setattr(ctrl.problem, "solve", infeasible)
    res = ctrl.step(0.0, X0, ctx())
    assert res.status == "infeasible" and res.fallback
    np.testing.assert_array_equal(res.u, np.zeros(2))


def test_nonconvex_term_is_refused_by_name() -> None:
    class OnlyCasadi(Term):
        def casadi_cost(self, X, U, p):
            return 0

    car = KinematicCar()
    with pytest.raises(ConfigError, match=r"term 'bump' \(OnlyCasadi\).*cvxpy.*accept it: casadi"):
        CvxpyMPC(car, Objective({"bump": OnlyCasadi()}))


def test_unknown_terminal_label_is_named() -> None:
    car = KinematicCar()
    obj = Objective({"t": QuadraticTracking({"px": 1.0})})
    with pytest.raises(ConfigError, match="terminal_constraint: unknown state label 'vel'"):
        CvxpyMPC(car, obj, terminal_constraint={"vel": 0.0})


def test_converge_needs_every_term_in_casadi_too() -> None:
    class OnlyCvxpy(Term):
        def cvxpy_cost(self, X, U, ctx):
            return cp.sum_squares(U)

    car = KinematicCar()
    with pytest.raises(ConfigError, match=r"term 'effort' \(OnlyCvxpy\).*casadi backend"):
        CvxpyMPC(car, Objective({"effort": OnlyCvxpy()}))
    CvxpyMPC(car, Objective({"effort": OnlyCvxpy()}), sl="one_pass")  # no true cost needed


@pytest.mark.parametrize(("options", "message"), [
    ({"sl": "converged"}, r"controller.sl: unknown choice 'converged'; valid: converge, one_pass"),
    ({"hessian": "bfgs"}, r"controller.solve.hessian: unknown choice 'bfgs'; valid: exact"),
    ({"max_iterations": 0}, r"controller.solve.max_iterations must be >= 1, got 0"),
    ({"tol": 0.0}, r"controller.solve.tol must be > 0, got 0.0"),
    ({"trust_radius": -1}, r"controller.solve.trust_radius must be in \(0, 1000\], got -1"),
    ({"initial_input": {"accel": 1.0}}, r"initial_input: unknown input label 'accel'"),
])
def test_bad_options_are_named(options: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        make(**options)


def test_converged_plan_is_the_rollout_and_a_cap_truncates() -> None:
    car, ctrl = make(initial_input={"a": 1.0})
    res = ctrl.step(0.0, X0, ctx())
    assert res.status == "converged" and res.iterations > 2 and res.info["qp_iterations"] > 0
    np.testing.assert_allclose(res.x_pred, car.rollout(X0, res.u_pred, 0.1), atol=1e-9)
    for cap in (1, 2):
        _, capped = make(initial_input={"a": 1.0}, max_iterations=cap)
        short = capped.step(0.0, X0, ctx())
        assert short.status == "truncated" and short.iterations == cap and not short.fallback
        assert short.cost > res.cost
