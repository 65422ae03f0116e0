"""The obstacle distance on the CVXPY backend: linearized, safe at the predicted states,
compiled once, and at IPOPT's plan where successive linearization converges."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from conftest import compose_cfg, grouped
from mpclab.constraints.obstacle import ObstacleDistance, SensedRegion
from mpclab.controllers.base import StepContext
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.controllers.cvxpy.mpc import CvxpyMPC
from mpclab.controllers.cvxpy.successive_linearization import model_through
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective, TermContext
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.objectives.rate import InputRate
from mpclab.plants.zumo import Zumo
from mpclab.runner.single_run import run_experiment

GOAL = np.array([0.4, 0.4, 0.0])
X0 = np.array([0.4, 0.8, -np.pi / 2])
T, DT, R = 10, 0.2, 0.06
WALL = np.c_[np.linspace(0.25, 0.55, 7), np.full(7, 0.65)]   # across the straight way
DISC = np.array([[0.41, 0.65]])                               # a point just off it


def _objective(mode: str | None, **kw) -> Objective:
    terms = {"track": QuadraticTracking(state_weights={"x": 100.0, "y": 100.0},
                                        input_weights={"u1": 0.01, "u2": 0.01}),
             "dU": InputRate(weights={"u1": 0.1, "u2": 0.1})}
    cons = {} if mode is None else {"o": ObstacleDistance(
        mode=mode, distance=R, **kw)}
    return Objective(terms, cons)


def _plant() -> Zumo:
    return Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})


def _cvxpy(mode: str | None, **kw) -> CvxpyMPC:
    return CvxpyMPC(_plant(), _objective(mode), **grouped(
                    CvxpyMPC, horizon=T, dt=DT, max_iterations=100,
                    initial_input={"u1": 2.0, "u2": 2.0}, **kw))


def _ctx(points) -> StepContext:
    return StepContext(goal=GOAL, target=np.tile(GOAL, (T + 1, 1)),
                       detections=np.asarray(points, dtype=float).reshape(-1, 2))


def _dist(step, points) -> np.ndarray:
    """The least distance of each predicted position ``(T,)`` to ``points``."""
    p = step.x_pred[1:, :2]
    return np.hypot(p[:, None, 0] - points[None, :, 0], p[:, None, 1] - points[None, :, 1]
                    ).min(axis=1)


def _terms_cost(step) -> float:
    """The terms' cost of a plan (without a slack's penalty), from the terms' CasADi form."""
    obj = _objective(None)
    obj.bind(_plant(), "casadi")
    ctx = TermContext(x0=ca.DM(X0), target=ca.DM(np.tile(GOAL, (T + 1, 1)).T),
                      u_prev=ca.DM.zeros(2))
    X, U = ca.DM(step.x_pred.T), ca.DM(step.u_pred.T)
    return sum(float(t.casadi_cost(X, U, ctx)) for t in obj.terms.values())


@pytest.mark.parametrize("options", [{}, {"hessian": "gauss_newton"}, {"sl": "one_pass"}],
                         ids=["exact", "gauss_newton", "one_pass"])
@pytest.mark.parametrize("mode", ["hard", "soft"])
def test_plan_keeps_the_distance_where_the_unconstrained_one_does_not(mode, options) -> None:
    free = _cvxpy(None, **options).step(0.0, X0, _ctx(WALL))
    held = _cvxpy(mode, **options).step(0.0, X0, _ctx(WALL))
    assert free.ok and held.ok
    assert _dist(free, WALL).min() < R - 0.03
    # converged: the plan is a rollout, within the iteration's feasibility tolerance (1e-5);
    # one pass: the QP's own states, which keep the halfspaces outside every disc
    assert _dist(held, WALL).min() >= R - 1e-5


@pytest.mark.parametrize("mode", ["hard", "soft"])
def test_converged_plan_agrees_with_ipopt(mode) -> None:
    # the same constrained OCP as an NLP: where successive linearization converges, its plan
    # is IPOPT's to within 1e-2 rad/s and 1e-3 m (measured: 6e-4 rad/s, 5e-5 m). Head-on
    # at the wall the two stop at different stationary points (the SL before the wall, at
    # the saddle of turning either way; IPOPT turned), so this poses the disc off the way
    sl = _cvxpy(mode).step(0.0, X0, _ctx(DISC))
    nlp = CasadiMPC(_plant(), _objective(mode), **grouped(
                    CasadiMPC, horizon=T, dt=DT, solver="ipopt",
                    initial_input={"u1": 2.0, "u2": 2.0}, tol=1e-9, max_iter=500,
                    )).step(0.0, X0, _ctx(DISC))
    assert sl.status == "converged" and nlp.status == "converged"
    assert sl.u_pred == pytest.approx(nlp.u_pred, abs=1e-2)
    assert sl.x_pred == pytest.approx(nlp.x_pred, abs=1e-3)
    assert _terms_cost(sl) == pytest.approx(_terms_cost(nlp), rel=1e-4)
    assert _dist(sl, DISC).min() >= R - 1e-5


def test_soft_solves_from_inside_the_margin_and_reports_the_slack() -> None:
    # a ring of points 0.05 m around the robot: no reachable position keeps 0.06 m from all
    a = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    ring = X0[:2] + 0.05 * np.c_[np.cos(a), np.sin(a)]
    mpc = _cvxpy("soft")
    step = mpc.step(0.0, X0, _ctx(ring))
    assert step.ok and not step.fallback
    given_up = R - _dist(step, ring)
    m = mpc.metrics(None)
    assert m["slack_steps"] == 1 and m["slack_max_m"] > 1e-3
    assert m["slack_max_m"] == pytest.approx(given_up.max(), abs=1e-9)
    assert m["constraints"]["o"]["mode"] == "soft"


def test_hard_keeps_a_point_already_inside_from_coming_nearer() -> None:
    near = X0[:2] + np.array([0.0, -0.04])              # 0.04 m ahead, inside 0.06
    step = _cvxpy("hard").step(0.0, X0, _ctx([near]))
    assert step.ok and _dist(step, near[None]).min() >= 0.04 - 1e-5


def test_detections_are_parameters_of_a_problem_compiled_once() -> None:
    mpc = _cvxpy("soft")
    assert mpc.problem.is_dpp()
    names = {p.name() for p in mpc.problem.parameters()}
    assert {"o_normal_x", "o_normal_y", "o_offset"} <= names
    direct = mpc.direct
    assert direct is not None
    for points in (WALL, DISC, np.zeros((0, 2)), WALL[:3]):
        assert mpc.step(0.0, X0, _ctx(points)).ok
    assert mpc.direct is direct    # the compiled data of construction served every step


def test_the_model_moved_through_its_own_rollout_is_the_model() -> None:
    # the second-order correction's model meets a given rollout; the model linearized about
    # a rollout already meets it (c_k = F(x_k, u_k) - A_k x_k - B_k u_k)
    mpc = _cvxpy("soft")
    U = np.tile([3.0, 5.0], (T, 1))
    pt = mpc.iteration.with_model(mpc.iteration.point(X0, U, np.tile(GOAL, (T + 1, 1)).T,
                                                      np.zeros(2)),
                                  X0, np.tile(GOAL, (T + 1, 1)).T, np.zeros(2))
    assert model_through(pt.model, pt.X, U) == pytest.approx(pt.model, abs=1e-12)


def test_more_detections_than_room_keep_the_nearest() -> None:
    mpc = _cvxpy("hard", max_detections=3)
    step = mpc.step(0.0, X0, _ctx(WALL))
    near3 = WALL[np.argsort(np.hypot(*(WALL - X0[:2]).T))[:3]]
    assert step.ok and _dist(step, near3).min() >= R - 1e-5


def test_sensed_region_keeps_the_plan_within_range() -> None:
    obj = Objective(_objective(None).terms, {"r": SensedRegion(max_range=0.2)})
    step = CvxpyMPC(_plant(), obj, **grouped(
                    CvxpyMPC, horizon=T, dt=DT, initial_input={"u1": 2.0, "u2": 2.0},
                    max_iterations=100)).step(0.0, X0, _ctx([]))
    assert step.ok and np.hypot(*(step.x_pred[1:, :2] - X0[:2]).T).max() <= 0.2 + 1e-5


def test_cbf_is_refused_naming_the_backends_that_take_it() -> None:
    with pytest.raises(ConfigError, match=r"'o' \(ObstacleDistance, mode cbf\) cannot be "
                                          r"expressed by the cvxpy backend; backends that "
                                          r"accept it: casadi$"):
        _cvxpy("cbf")
    assert ObstacleDistance(mode="soft").accepted_by() == ["casadi", "cvxpy"]


def test_the_shipped_experiment_passes_the_wall_and_arrives(tmp_path) -> None:
    cfg = compose_cfg(["+experiment=zumo_cvxpy_wall", "recorder=none",
                       "figures.enabled=false", "progress=false"])
    s = run_experiment(cfg, tmp_path).summary
    assert s["controller"] == "cvxpy" and s["status"] == "arrived"
    assert s["min_clearance_m"] > 0.0 and s["slack_max_m"] < 1e-4
