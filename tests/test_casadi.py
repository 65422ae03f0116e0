"""The CasADi backend: Study A's car on it, objective switching by parameters, failures."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import grouped
from mpclab.constraints.obstacle import ObstacleDistance
from mpclab.controllers.base import StepContext
from mpclab.controllers.casadi.compile import LONG_BUILD_S, announce_long_build
from mpclab.controllers.casadi.mpc import CasadiMPC
from mpclab.core.errors import ConfigError
from mpclab.objectives.base import Objective
from mpclab.objectives.potential import GoalAttraction, ObstacleRepulsion
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.zumo import Zumo


def test_car_casadi_arrives_with_terminal_constraint(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_casadi"])
    s = res.summary
    assert s["status"] == "arrived" and s["arrival_time_s"] <= 3.0
    assert s["solver_failures"] == 0
    hz = res.horizons
    # v_T = 0 on every predicted horizon (the terminal constraint)
    assert np.abs(hz[hz["k"] == hz["k"].max()]["v"]).max() < 1e-6


def test_car_cvxpy_experiment_runs_on_casadi(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=car_cvxpy", "controller=casadi_rti"])
    assert res.summary["controller"] == "casadi" and res.summary["arrived"]


def _zumo(terms, **kw) -> CasadiMPC:
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    return CasadiMPC(plant, Objective(terms), **grouped(CasadiMPC, horizon=8, dt=0.2,
                     initial_input={"u1": 2.0, "u2": 2.0}, **kw))


def _ctx(active=None, det=None) -> StepContext:
    det = np.zeros((0, 2)) if det is None else det
    goal = np.array([0.4, 0.4, 0.0])
    return StepContext(goal=goal, target=np.tile(goal, (9, 1)), detections=det, active=active)


def test_switching_terms_equals_a_solver_built_without_them() -> None:
    terms = lambda: {  # noqa: E731
        "J1": GoalAttraction(),
        "J2": QuadraticTracking(input_weights={"u1": 0.01, "u2": 0.01}),
        "J4": ObstacleRepulsion(C3=1500, L3=0.05),
    }
    x = np.array([0.4, 0.8, -1.2])
    det = np.array([[0.45, 0.65]])
    both = _zumo(terms())
    only = _zumo({k: v for k, v in terms().items() if k != "J4"})
    a = both.step(0.0, x, _ctx(frozenset({"J1", "J2"}), det))
    b = only.step(0.0, x, _ctx(None, det))
    assert a.ok and b.ok
    assert a.u_pred == pytest.approx(b.u_pred, abs=1e-4)
    c = both.step(0.0, x, _ctx(None, det))   # J4 back on: the plan changes
    assert np.abs(c.x_pred - a.x_pred).max() > 1e-3


def test_unknown_active_term_is_a_recorded_failure() -> None:
    mpc = _zumo({"J1": GoalAttraction()})
    res = mpc.step(0.0, np.array([0.4, 0.8, 0.0]), _ctx(frozenset({"J9"})))
    assert res.fallback and res.status == "exception"


def test_iteration_limit_falls_back_and_records_status() -> None:
    mpc = _zumo({"J1": GoalAttraction()}, max_iter=1)
    res = mpc.step(0.0, np.array([0.4, 0.8, 0.0]), _ctx())
    # an iteration cap with a usable iterate: applied, and said to be truncated
    assert res.ok and not res.fallback and res.status == "truncated"
    assert res.solver_status == "Maximum_Iterations_Exceeded" and res.iterations == 1


def test_rti_and_osqp_take_one_qp_per_step() -> None:
    for qp in ("qpoases", "osqp"):
        mpc = _zumo({"J1": GoalAttraction()}, solver="sqp_rti", qp_solver=qp)
        res = mpc.step(0.0, np.array([0.4, 0.8, 0.0]), _ctx())
        assert res.ok and res.iterations == 1


def test_bad_options_name_the_choices() -> None:
    with pytest.raises(ConfigError, match="ipopt, fatrop, sqp, sqp_rti"):
        _zumo({"J1": GoalAttraction()}, solver="snopt")
    with pytest.raises(ConfigError, match="terminal_constraint"):
        _zumo({"J1": GoalAttraction()}, terminal_constraint={"vx": 0.0})


def _j1_j2_j4():
    return {
        "J1": GoalAttraction(),
        "J2": QuadraticTracking(input_weights={"u1": 0.01, "u2": 0.01}),
        "J4": ObstacleRepulsion(C3=1500, L3=0.05),
    }


def test_single_shooting_solves_the_same_nlp() -> None:
    # the same optimum whether the states are variables (multiple) or the inputs' rollout
    x, det = np.array([0.4, 0.8, -1.2]), np.array([[0.45, 0.65]])
    a = _zumo(_j1_j2_j4()).step(0.0, x, _ctx(None, det))
    b = _zumo(_j1_j2_j4(), shooting="single").step(0.0, x, _ctx(None, det))
    assert a.ok and b.ok
    assert b.u_pred == pytest.approx(a.u_pred, abs=1e-3)
    assert b.x_pred == pytest.approx(a.x_pred, abs=1e-5)
    # the plan's states are the plant's rollout of its inputs
    assert b.x_pred == pytest.approx(Zumo().rollout(x, b.u_pred, 0.2), abs=1e-9)


def test_sqp_iterations_converge_to_ipopt() -> None:
    x = np.array([0.4, 0.8, -1.2])
    ref = _zumo(_j1_j2_j4()).step(0.0, x, _ctx())
    for shooting in ("single", "multiple"):
        sqp = _zumo(_j1_j2_j4(), solver="sqp_capped", sqp_iterations=60, shooting=shooting)
        res = sqp.step(0.0, x, _ctx())
        assert res.ok and 1 < res.iterations <= 60
        assert res.u_pred == pytest.approx(ref.u_pred, abs=1e-2), shooting
    three = _zumo(_j1_j2_j4(), solver="sqp_capped", sqp_iterations=3, shooting="single")
    res = three.step(0.0, x, _ctx())
    assert res.ok and res.iterations == 3
    assert np.all(np.abs(res.u_pred) <= 10 + 1e-9)


@pytest.mark.parametrize("solver", ["ipopt", "sqp_capped"])
def test_collision_constraint_keeps_predicted_positions_off_detected_points(solver) -> None:
    # a detected point on the straight way to the goal; J1 alone would drive through it
    x, point = np.array([0.4, 0.8, -np.pi / 2]), np.array([0.4, 0.7])
    kw = {"solver": solver, "shooting": "single", "sqp_iterations": 20}
    free = _zumo({"J1": GoalAttraction()}, **kw).step(0.0, x, _ctx(None, point[None]))
    con = ObstacleDistance(mode="hard", distance=0.06)
    hard = CasadiMPC(Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]}),
                     Objective({"J1": GoalAttraction()}, {"obstacles": con}),
                     **grouped(CasadiMPC, horizon=8, dt=0.2,
                               initial_input={"u1": 2.0, "u2": 2.0}, **kw)).step(
        0.0, x, _ctx(None, point[None])
    )
    assert free.ok and hard.ok
    dist = lambda plan: np.hypot(*(plan.x_pred[1:, :2] - point).T)  # noqa: E731
    assert dist(free).min() < 0.06
    assert dist(hard).min() >= 0.06 - 1e-6


def test_within_bounds_flags_a_failed_qp_iterate() -> None:
    mpc = _zumo({"J1": GoalAttraction()}, solver="sqp_rti", shooting="single")
    w = np.zeros(mpc.ocp.lbw.size)
    assert mpc.starts.within_bounds(w)
    w[3] = 10.5   # an input beyond |u| <= 10, as a silently failed QP leaves it
    assert not mpc.starts.within_bounds(w)


def test_new_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="multiple, single"):
        _zumo({"J1": GoalAttraction()}, shooting="triple")
    with pytest.raises(ConfigError, match="sqp_iterations"):
        _zumo({"J1": GoalAttraction()}, sqp_iterations=0)
    with pytest.raises(ConfigError, match="hard, soft, cbf"):
        ObstacleDistance(mode="stiff")


class _Started(Exception):
    """Raised where the long build would start."""


def test_a_horizon_that_builds_for_minutes_says_so_before_it_starts(monkeypatch, capsys
                                                                    ) -> None:
    def start(self, names, terminal, extra):
        raise _Started(capsys.readouterr().err)  # what was said when the build began

    monkeypatch.setattr(CasadiMPC, "_make_nlp", start)
    plant = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
    with pytest.raises(_Started) as said:
        CasadiMPC(plant, Objective(_j1_j2_j4()), horizon=5000, dt=0.2, build={"jit": True})
    text = str(said.value)
    assert "mpclab: controller.horizon=5000: an NLP of about" in text
    assert "writing and compiling its C" in text and "unless it was compiled before" in text
    with pytest.raises(_Started) as said:  # a usual horizon: nothing to say
        CasadiMPC(plant, Objective(_j1_j2_j4()), horizon=30, dt=0.2, build={"jit": True})
    assert str(said.value) == ""


def test_the_build_estimate_grows_with_the_horizon() -> None:
    """Operations grow linearly with the horizon; the compile faster than the C."""
    size = {1: 400, 2: 700}.__getitem__  # an NLP of 300 operations a step
    quick = announce_long_build(size, 30, True)
    long = announce_long_build(size, 3000, True)
    assert 0 < quick < LONG_BUILD_S < long
    assert long / quick > 100  # a hundred times the horizon, more than that the time
    assert announce_long_build(size, 3000, False) < long
    assert announce_long_build(size, 10, True) == 0  # a short horizon: not even estimated
