"""The dynamic window approach: its window, its admissibility rule and its choice, checked on
scenes whose answer is known, and its prediction against the plant's own step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpclab.controllers.base import SolveStatus, StepContext
from mpclab.controllers.dwa.controller import DwaController
from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo

ZUMO = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
X0 = np.array([0.0, 0.0, 0.0])  # at the origin, facing +x


def ctx(goal_xy, points=()) -> StepContext:
    goal = np.array([*goal_xy, 0.0])
    return StepContext(goal=goal, target=np.tile(goal, (6, 1)),
                       detections=np.asarray(points, dtype=float).reshape(-1, 2))


def test_in_free_space_it_drives_straight_at_a_goal_ahead() -> None:
    step = DwaController(ZUMO).step(0.0, X0, ctx((1.0, 0.0)))
    assert step.status is SolveStatus.converged and not step.fallback
    np.testing.assert_allclose(step.u, [10.0, 10.0])  # full speed, no turn


def test_its_prediction_is_the_plants_own_rollout_of_the_held_input() -> None:
    step = DwaController(ZUMO, horizon=5, substeps=4).step(0.0, X0, ctx((0.5, 0.5)))
    x = X0.copy()
    for k in range(5):
        for _ in range(4):  # the clearance is checked at every quarter sample
            x = ZUMO.step(x, step.u, 0.05)
        np.testing.assert_allclose(step.x_pred[k + 1], x, atol=1e-12)
    assert step.u_pred.shape == (5, 2) and np.allclose(step.u_pred, step.u)


def test_the_chosen_trajectory_keeps_the_margin_from_every_sensed_point() -> None:
    wall = np.c_[np.full(21, 0.3), np.linspace(-0.5, 0.5, 21)]  # across the way, 0.3 m ahead
    ctrl = DwaController(ZUMO, robot_radius=0.05, margin=0.015)
    step = ctrl.step(0.0, X0, ctx((1.0, 0.0), wall))
    assert step.status is SolveStatus.converged
    gap = np.min(np.linalg.norm(step.x_pred[:, None, :2] - wall[None], axis=2)) - 0.05
    assert gap > 0.015
    # full speed ahead would have reached the wall within the horizon: not chosen
    assert not np.allclose(step.u, [10.0, 10.0])


def test_with_every_candidate_too_close_the_step_is_infeasible_and_falls_back() -> None:
    ring = 0.06 * np.c_[np.cos(np.linspace(0, 2 * math.pi, 24, endpoint=False)),
                        np.sin(np.linspace(0, 2 * math.pi, 24, endpoint=False))]
    step = DwaController(ZUMO).step(0.0, X0, ctx((1.0, 0.0), ring))
    assert step.fallback and step.solver_status == "no_admissible_input"


def test_the_window_holds_the_inputs_the_plant_can_reach_in_a_sample() -> None:
    ctrl = DwaController(ZUMO, max_rate=10.0)  # 2 rad/s of wheel speed per 0.2 s sample
    ctrl.received(np.array([3.0, -3.0]))
    step = ctrl.step(0.0, X0, ctx((1.0, 0.0)))
    assert np.all(np.abs(step.u - [3.0, -3.0]) <= 2.0 + 1e-12)
    assert step.u[0] > 3.0 and step.u[1] > -3.0  # as far towards straight ahead as it may


@pytest.mark.parametrize("options, key", [
    ({"samples": 1}, "controller.samples"), ({"horizon": 0}, "controller.horizon"),
    ({"margin": -0.1}, "controller.margin"), ({"weights": {"goal": -1}}, "controller.weights.goal"),
    ({"weights": {"goals": 1}}, "controller.weights"),
])
def test_bad_options_are_refused_by_name(options, key) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        DwaController(ZUMO, **options)


def test_a_plant_without_finite_input_bounds_is_refused() -> None:
    with pytest.raises(ConfigError, match="finite input bounds"):
        DwaController(Zumo())


def test_it_runs_from_its_experiment(run_cfg) -> None:
    result, _ = run_cfg(["+experiment=zumo_dwa", "scenario=barn", "scenario.world=1",
                         "+ci=smoke"])
    s = result.summary
    assert s["controller"] == "dwa" and s["problem"] == "sampled"
    assert s["status"] == "timeout" and s["solves_converged"] == s["n_steps"]
