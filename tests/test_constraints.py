"""Constraints as objects: the obstacle distance in its three modes, on every CasADi solver
(the CVXPY backend's linearized form: tests/test_cvxpy_obstacles.py)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import grouped
from mpclab.constraints.base import Constraint
from mpclab.constraints.obstacle import ObstacleDistance, SensedRegion
from mpclab.controllers.base import StepContext
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.controllers.scheduled.models import tracking_weights
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.zumo import Zumo

GOAL = np.array([0.4, 0.4, 0.0])
X0 = np.array([0.4, 0.8, -np.pi / 2])
POINT = np.array([0.41, 0.7])          # on the straight way to the goal


def _con(mode: str, **kw) -> ObstacleDistance:
    return ObstacleDistance(mode=mode, distance=0.06, **kw)


def _mpc(cons: dict, **kw) -> CasadiMPC:
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    terms = {"J1": GoalAttraction(), "J2": QuadraticTracking(input_weights={"u1": 0.01,
                                                                              "u2": 0.01})}
    return CasadiMPC(plant, Objective(terms, cons), **grouped(CasadiMPC, horizon=8, dt=0.2,
                     initial_input={"u1": 2.0, "u2": 2.0}, tol=1e-8, max_iter=300, **kw))


def _ctx(points) -> StepContext:
    return StepContext(goal=GOAL, target=np.tile(GOAL, (9, 1)),
                       detections=np.asarray(points, dtype=float).reshape(-1, 2))


def _dist(step, point=POINT) -> np.ndarray:
    return np.hypot(*(step.x_pred[1:, :2] - point).T)


def test_a_stated_distance_is_kept_and_recorded() -> None:
    c = ObstacleDistance(distance=0.065)
    assert c.distance == pytest.approx(0.065)
    mpc = _mpc({"obstacles": c}, solver="ipopt")
    info = mpc.metrics(None)["constraints"]["obstacles"]
    assert info["mode"] == "soft" and info["distance_m"] == pytest.approx(0.065)
    assert info["margin"] == "stated"


def test_an_underived_margin_is_named() -> None:
    with pytest.raises(ConfigError, match="distance=<metres>"):
        _ = ObstacleDistance().distance


@pytest.mark.parametrize("solver", ["ipopt", "fatrop", "sqp"])
def test_soft_equals_hard_where_hard_is_feasible(solver) -> None:
    free = _mpc({}, solver=solver).step(0.0, X0, _ctx([POINT]))
    hard = _mpc({"o": _con("hard")}, solver=solver).step(0.0, X0, _ctx([POINT]))
    soft = _mpc({"o": _con("soft")}, solver=solver).step(0.0, X0, _ctx([POINT]))
    assert free.ok and hard.ok and soft.ok
    assert _dist(free).min() < 0.05                      # the constraint is active
    assert _dist(hard).min() >= 0.06 - 1e-6
    assert _dist(soft).min() >= 0.06 - 1e-5              # the slack stays 0
    assert soft.u_pred == pytest.approx(hard.u_pred, abs=1e-3)
    assert soft.cost == pytest.approx(hard.cost, rel=1e-5)


def test_soft_stays_solvable_where_hard_cannot_hold() -> None:
    # a ring of points 0.05 m around the robot: no position keeps the soft mode's full 0.06 m
    # from all of them; it solves, and the slack says by how much it gave way
    a = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    pts = X0[:2] + 0.05 * np.c_[np.cos(a), np.sin(a)]
    mpc = _mpc({"o": _con("soft")}, solver="fatrop")
    step = mpc.step(0.0, X0, _ctx(pts))
    assert step.ok
    assert mpc.metrics(None)["slack_max_m"] > 1e-3


def test_a_small_penalty_gives_way_and_a_large_one_does_not() -> None:
    small = _mpc({"o": _con("soft", penalty=1.0)}, solver="ipopt").step(0.0, X0, _ctx([POINT]))
    assert small.ok and _dist(small).min() < 0.05


@pytest.mark.parametrize("solver", ["ipopt", "fatrop"])
def test_cbf_decays_the_barrier_at_most_gamma_per_step(solver) -> None:
    gamma = 0.3
    step = _mpc({"o": _con("cbf", gamma=gamma)}, solver=solver).step(0.0, X0, _ctx([POINT]))
    assert step.ok
    h = np.concatenate([[np.hypot(*(X0[:2] - POINT))], _dist(step)]) ** 2 - 0.06**2
    assert np.all(h[1:] >= (1 - gamma) * h[:-1] - 1e-6)
    assert h.min() >= -1e-6


def test_hard_keeps_a_point_already_inside_from_coming_nearer() -> None:
    near = X0[:2] + np.array([0.0, -0.04])              # 0.04 m ahead, inside 0.06
    step = _mpc({"o": _con("hard")}, solver="fatrop").step(0.0, X0, _ctx([near]))
    assert step.ok and _dist(step, near).min() >= 0.04 - 1e-6


def test_sensed_region_keeps_the_plan_within_range() -> None:
    free = _mpc({}, solver="ipopt").step(0.0, X0, _ctx([]))
    held = _mpc({"r": SensedRegion(max_range=0.2)}, solver="ipopt").step(0.0, X0, _ctx([]))
    reach = lambda s: np.hypot(*(s.x_pred[1:, :2] - X0[:2]).T).max()  # noqa: E731
    assert reach(free) > 0.25 and reach(held) <= 0.2 + 1e-6


def test_codegen_solves_the_soft_constraint_as_fatrop_does() -> None:
    a = _mpc({"o": _con("soft")}, solver="fatrop").step(0.0, X0, _ctx([POINT]))
    b = _mpc({"o": _con("soft")}, solver="fatrop", codegen=True).step(0.0, X0, _ctx([POINT]))
    assert a.ok and b.ok and b.u_pred == pytest.approx(a.u_pred, abs=1e-4)


def test_a_backend_that_cannot_express_it_refuses_naming_it() -> None:
    con = _con("cbf")
    con.name = "obstacles"
    with pytest.raises(ConfigError, match="'obstacles' .*mode cbf.*cvxpy.*accept it: casadi$"):
        con.require("cvxpy")
    with pytest.raises(ConfigError, match="not a constraint"):
        Objective({"J1": GoalAttraction()}, {"o": GoalAttraction()})
    assert Constraint.backends() == []
    assert ObstacleDistance.backends() == SensedRegion.backends() == ["casadi", "cvxpy"]
    # the scheduled backend's QP has no rows for constraints: it refuses them, not drops them
    track = QuadraticTracking(state_weights={"x": 1.0}, input_weights={"u1": 1.0, "u2": 1.0})
    with pytest.raises(ConfigError, match="'o' .*scheduled backend.*accept it: casadi, cvxpy"):
        tracking_weights(Objective({"t": track}, {"o": _con("soft")}), Zumo())


def test_bad_options_name_the_key_and_choices() -> None:
    with pytest.raises(ConfigError, match="hard, soft, cbf"):
        ObstacleDistance(mode="stiff")
    with pytest.raises(ConfigError, match="gamma"):
        ObstacleDistance(mode="cbf", gamma=1.5)
    with pytest.raises(ConfigError, match="penalty"):
        ObstacleDistance(penalty=0)


@pytest.mark.parametrize("solver", ["ipopt", "fatrop", "sqp"])
def test_penalty_use_is_the_hard_multiplier_over_the_penalty(solver) -> None:
    """Where the hard problem is feasible, the soft one's stage multipliers (read on the
    detected points' rows) are the hard one's: their ratio to the penalty is recorded, and a
    penalty within 10x of them is warned of."""
    hard = _mpc({"o": _con("hard")}, solver=solver)
    hard.step(0.0, X0, _ctx([POINT]))
    needed = float(np.max(hard._lam_g))  # the point's row at its active stage
    for penalty, warned in ((1e6, False), (2e5, True)):
        soft = _mpc({"o": _con("soft", penalty=penalty)}, solver=solver)
        soft.step(0.0, X0, _ctx([POINT]))
        m = soft.metrics(None)
        assert m["slack_steps"] == 0
        assert m["penalty_use_max"] == pytest.approx(needed / penalty, rel=1e-3)
        assert (m["penalty_warning"] is not None) is warned
