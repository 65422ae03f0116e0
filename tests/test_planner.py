"""The sensed-map planner (``supervisor=planner``) and BUG2's shorter side, against analytic
geometry, and the navigation experiment that uses the planner in closed loop."""

from __future__ import annotations

import numpy as np
import pytest

from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo
from mpclab.supervisors.boundary import Side, shorter_side
from mpclab.supervisors.planner import MapPlanner, PlannerMode, cell_costs, smooth
from mpclab.world.barn import STALL_WINDOW_S, BarnScenario

ZUMO = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})


def _wall(x0: float, x1: float, y: float, spacing: float = 0.01) -> np.ndarray:
    xs = np.arange(x0, x1 + 1e-9, spacing)
    return np.c_[xs, np.full_like(xs, y)]


def _state(x: float, y: float, theta: float = np.pi / 2) -> np.ndarray:
    s = np.zeros(ZUMO.nx)
    for label, v in (("x", x), ("y", y), ("theta", theta)):
        s[ZUMO.state_index(label)] = v
    return s


def _length(line: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(line, axis=0), axis=1)))


@pytest.mark.parametrize("mirror", [1.0, -1.0])
def test_the_shorter_side_goes_round_the_nearer_tangent(mirror) -> None:
    """A wall across the way from x = -1.0 to x = 0.2: its right end is nearer, so the robot
    goes round it there, with the wall on its left; mirrored, the other way."""
    wall = _wall(-1.0, 0.2, 0.5) * [mirror, 1.0]
    side = shorter_side(np.zeros(2), wall, np.array([0.0, 2.0]))
    assert side is (Side.left if mirror > 0 else Side.right)


def test_a_wall_reaching_round_behind_the_robot_is_the_long_side() -> None:
    """The wall turns down past the robot on its left: its tangent there lies behind, far
    from the goal, so the way round is on the right (the wall on the robot's left)."""
    wall = np.vstack([_wall(-0.4, 0.6, 0.5), np.c_[np.full(80, -0.4), np.linspace(0.5, -0.3, 80)]])
    assert shorter_side(np.zeros(2), wall, np.array([0.0, 2.0])) is Side.left


def test_cells_cost_more_near_a_seen_point_and_are_blocked_within_the_inflation() -> None:
    seen = np.zeros((1, 41), dtype=bool)
    seen[0, 0] = True
    cost = cell_costs(seen, 0.01, inflation=0.07, comfort=0.12, weight=4.0)[0]
    assert cost[20] == pytest.approx(1.0)               # 0.20 m: free
    assert cost[12] == pytest.approx(1.0)               # at the comfort distance
    assert cost[10] == pytest.approx(1.0 + 4.0 * 0.4)   # 0.10 m: 2/5 of the way in
    assert cost[6] > 1e3 and cost[0] > cost[6]          # blocked, most at the point


def _planner(**kw) -> MapPlanner:
    return MapPlanner(ZUMO, **kw)


def test_with_nothing_seen_the_path_is_the_straight_line() -> None:
    sup = _planner()
    sup.reset(_state(0.0, 0.0), _state(0.3, 1.0))
    mode, active = sup.update(0.0, _state(0.0, 0.0), np.zeros((0, 2)))
    assert mode == PlannerMode.follow_path and active == frozenset({"Jp", "J2", "dU"})
    path = sup.path()
    assert _length(path) == pytest.approx(np.hypot(0.3, 1.0), rel=0.03)
    ref = sup.target(0.0, 10, 0.2)
    step = np.linalg.norm(np.diff(ref[:, :2], axis=0), axis=1)
    np.testing.assert_allclose(step, 0.15 * 0.2, rtol=0.05)  # sampled at path_speed
    # the grid's sixteen directions are at most 26.6 degrees apart: half of it off
    heading = np.arctan2(1.0, 0.3)
    np.testing.assert_allclose(ref[1:, ZUMO.state_index("theta")], heading, atol=0.24)


def test_the_path_goes_round_the_end_of_a_wall_by_the_shortest_way() -> None:
    """A wall from x = -0.3 to 0.6 at y = 0.5 between robot (0, 0) and goal (0, 1): the
    shortest way keeps the inflation from the wall's end (-0.3, 0.5), two tangents and an
    arc; the grid path is within its discretisation of it, and keeps off the wall."""
    r = 0.07
    sup = _planner(inflation=r, comfort=r, cell=0.01)
    start, goal = _state(0.0, 0.0), _state(0.0, 1.0)
    sup.reset(start, goal)
    wall = _wall(-0.3, 0.6, 0.5)
    sup.update(0.0, start, wall)
    path = sup.path()
    c = np.array([-0.3, 0.5])
    a = float(np.linalg.norm(c))
    tangent = np.sqrt(a * a - r * r)
    between = 2 * np.arctan2(0.5, 0.3)  # the angle at the wall's end between robot and goal
    arc = r * (2 * np.pi - between - 2 * np.arccos(r / a))
    shortest = 2 * tangent + arc
    assert shortest <= _length(path) <= 1.04 * shortest  # 16-neighbour grid: at most 2.7 %
    assert path[:, 0].min() < -0.3 - 0.5 * r            # round the left end
    gap = np.min(np.linalg.norm(path[1:-1, None, :] - wall[None], axis=2))
    assert gap >= r - 0.01                              # one cell of the grid
    smoothed = smooth(path)
    assert _length(smoothed) <= _length(path)


def test_a_gap_narrower_than_the_inflation_is_not_the_way_when_another_is_known() -> None:
    """A long wall with a 0.11 m gap on the straight line: the path goes round an end."""
    sup = _planner()
    start, goal = _state(0.0, 0.0), _state(0.0, 1.0)
    sup.reset(start, goal)
    wall = np.vstack([_wall(-0.6, -0.055, 0.5), _wall(0.055, 0.6, 0.5)])
    sup.update(0.0, start, wall)
    path = sup.path()
    assert np.abs(path[:, 0]).max() > 0.6  # round an end, not through the gap
    assert _length(path) > 1.5


def test_the_mode_is_arrive_near_the_goal() -> None:
    sup = _planner(arrive_range=0.1)
    sup.reset(_state(0.0, 0.0), _state(0.0, 1.0))
    assert sup.update(0.0, _state(0.0, 0.95), np.zeros((0, 2)))[0] == PlannerMode.arrive
    assert sup.update(0.2, _state(0.0, 0.5), np.zeros((0, 2)))[0] == PlannerMode.follow_path


def test_bad_planner_options_are_refused_by_name() -> None:
    with pytest.raises(ConfigError, match="supervisor.comfort"):
        _planner(inflation=0.1, comfort=0.05)
    with pytest.raises(ConfigError, match="follow_path"):
        _planner(modes={"go": ["J1"]})


def test_barn_stalls_over_its_own_window_unless_given() -> None:
    assert BarnScenario(ZUMO, world=1).stall_rule.window_s == STALL_WINDOW_S
    assert BarnScenario(ZUMO, world=1, stall={"window_s": 3.0}).stall_rule.window_s == 3.0


@pytest.mark.parametrize("world", [1, 151, 299])
def test_the_navigation_experiment_crosses_the_shipped_barn_worlds(run_cfg, world) -> None:
    """Where BUG2 goes round the enclosure (world 1: score 0.14), the planner goes through;
    its search is timed beside the controller's call."""
    result, _ = run_cfg(["+experiment=zumo_nav", "scenario=barn", f"scenario.world={world}"])
    s = result.summary
    assert s["status"] == "arrived" and s["min_clearance_m"] > 0
    assert s["barn_score"] > 0.4
    assert s["sense_cpu_median_ms"] > 0 and s["sense_cpu_p95_ms"] >= s["sense_cpu_median_ms"]


def test_the_navigation_experiment_reaches_the_goal_in_a_corridor(run_cfg) -> None:
    """The goal in a corridor 0.15 m wide, narrower than BUG2's path along a boundary at
    0.08 m can enter: the planner's path goes in."""
    result, _ = run_cfg(["+experiment=zumo_nav", "scenario=zumo_hard_goal_in_corridor"])
    assert result.summary["status"] == "arrived" and result.summary["min_clearance_m"] > 0
