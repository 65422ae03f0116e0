"""Clearance in continuous time: closed-form arcs against analytic geometry and dense samples,
and the loop that declares a collision between samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpclab.controllers.base import Controller, ControlStep
from mpclab.core.status import SolveStatus
from mpclab.plants.unicycle import Unicycle
from mpclab.plants.zumo import Zumo
from mpclab.runner.loop import PATH_CLEARANCE, Run, simulate
from mpclab.world.clearance import DENSE_TOL_M, ContinuousClearance, arc_distance
from mpclab.world.sim_world import SimWorld
from mpclab.world.zumo_world import ObstacleScenario


def _arc_points(pose, v, omega, duration, n=20_001):
    """Exact unicycle positions at ``n`` times (closed form, independent of the module)."""
    x, y, th = pose
    s = np.linspace(0.0, duration, n)
    if omega == 0:
        return np.column_stack([x + v * s * np.cos(th), y + v * s * np.sin(th)])
    R = v / omega
    return np.column_stack([x + R * (np.sin(th + omega * s) - np.sin(th)),
                            y - R * (np.cos(th + omega * s) - np.cos(th))])


def test_straight_pass_is_the_perpendicular_distance():
    # along +x from the origin for 0.4 m: a centre above the middle, one beyond the end
    d = arc_distance((0.0, 0.0, 0.0), 0.2, 0.0, 2.0, np.array([[0.2, 0.099], [0.5, 0.0]]))
    assert d == pytest.approx([0.099, 0.1], abs=1e-12)


def test_arc_about_a_centre_and_the_far_point_of_the_circle():
    # v = 0.1, omega = 1: a circle of radius 0.1 about (0, 0.1)
    pose = (0.0, 0.0, 0.0)
    d = arc_distance(pose, 0.1, 1.0, 0.5, np.array([[0.0, 0.1]]))
    assert d == pytest.approx([0.1], abs=1e-12)  # the arc's own centre: always R away
    top = np.array([[0.0, 0.4]])  # nearest circle point (0, 0.2) is reached after pi s
    assert arc_distance(pose, 0.1, 1.0, math.pi, top) == pytest.approx([0.2], abs=1e-12)
    # over 1 s only 1 rad is swept: the nearest point is the arc's end
    end = np.array([0.1 * math.sin(1.0), 0.1 - 0.1 * math.cos(1.0)])
    assert arc_distance(pose, 0.1, 1.0, 1.0, top) == pytest.approx(
        [np.linalg.norm(top[0] - end)], abs=1e-12)
    # turning right (omega < 0) about (0, -0.1) with the same centre: never swept toward it
    assert arc_distance(pose, 0.1, -1.0, 2 * math.pi, top) == pytest.approx([0.4], abs=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_arc_distance_matches_dense_samples(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        pose = (*rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi))
        v = rng.uniform(-0.2, 0.2)
        omega = rng.choice([0.0, rng.uniform(-4, 4), rng.uniform(-1e-5, 1e-5)])
        duration = rng.uniform(0.01, 2.5)  # up to 10 rad: past a full turn too
        centres = rng.uniform(-0.8, 0.8, (8, 2))
        exact = arc_distance(pose, v, omega, duration, centres)
        pts = _arc_points(pose, v, omega, duration)
        dense = np.min(np.linalg.norm(pts[:, None] - centres[None], axis=2), axis=0)
        step = abs(v) * duration / (len(pts) - 1)  # path between dense samples
        # 1e-9 m: rounding, when an almost straight path is an arc of radius up to 1e5 m
        assert np.all(exact <= dense + 1e-9)  # a point of the path is never nearer
        assert np.all(dense <= exact + step / 2 + 1e-9)  # and the nearest one is found


def _rk4_dense_min(plant, x, pieces, discs, n=2000):
    """Least distance minus radii over fine RK4 sub-steps of the plant's own step."""
    least = np.inf
    for u, duration in pieces:
        for _ in range(n):
            p = x[:2]
            least = min(least, np.min(np.linalg.norm(discs[:, :2] - p, axis=1) - discs[:, 2]))
            x = plant.step(x, u, duration / n)
    p = x[:2]
    return min(least, np.min(np.linalg.norm(discs[:, :2] - p, axis=1) - discs[:, 2]))


def test_zumo_period_in_two_pieces_matches_fine_integration():
    plant = Zumo()
    discs = np.array([[0.3, 0.2, 0.05], [0.1, 0.35, 0.05], [0.45, 0.5, 0.05]])
    guard = ContinuousClearance(plant, discs, robot_radius=0.05)
    assert guard.exact and guard.tolerance_m == 0.0
    rng = np.random.default_rng(3)
    for _ in range(10):
        x = np.array([*rng.uniform(0.1, 0.4, 2), rng.uniform(-np.pi, np.pi)])
        u_old, u_new = rng.uniform(-10, 10, 2), rng.uniform(-10, 10, 2)
        tau = rng.uniform(0.0, 0.2)
        pieces = [(u_old, tau), (u_new, 0.2 - tau)]
        dense = _rk4_dense_min(plant, x.copy(), pieces, discs) - 0.05
        # the second arc starts from the RK4 state at the switch, as the simulator's
        assert guard.interval(x, pieces) == pytest.approx(dense, abs=2e-6)


def test_non_arc_plant_falls_back_to_dense_substeps_within_its_tolerance():
    plant = Unicycle()  # speed is a state: the path is not an arc
    discs = np.array([[0.5, 0.15, 0.05], [0.2, -0.3, 0.1]])
    guard = ContinuousClearance(plant, discs, robot_radius=0.1)
    assert not guard.exact and guard.tolerance_m == DENSE_TOL_M
    x = np.array([0.0, 0.0, 0.2, 1.0])
    pieces = [(np.array([2.0, 1.5]), 0.1), (np.array([-1.0, -3.0]), 0.4)]
    fine = _rk4_dense_min(plant, x.copy(), pieces, discs, n=20_000) - 0.1
    got = guard.interval(x, pieces)
    assert fine - 1e-9 <= got <= fine + DENSE_TOL_M


class _Constant(Controller):
    """Holds one input forever (a stand-in for a controller)."""

    def __init__(self, plant, u):
        super().__init__(plant, horizon=1, dt=0.2)
        self.u = np.asarray(u, dtype=float)

    def _solve(self, t, x, ctx):
        return ControlStep(self.u, np.tile(x, (2, 1)), self.u[None], SolveStatus.converged)


def _straight_run(world_kw=None):
    """A Zumo driving along +x at 0.2 m/s past a disc whose surface lies 1 mm inside the
    robot's radius at x = 0.1, midway between the samples at x = 0.08 and 0.12."""
    plant = Zumo()
    scen = ObstacleScenario(
        plant, "between_samples", start={"x": -0.2}, goal={"x": 1.0},
        arrival={"weights": {"x": 1, "y": 1}, "threshold": 1e-4}, t_max=4.0,
        layout={"discs": [[0.1, 0.099]]}, robot_radius=0.05,
    )
    world = SimWorld(plant, dt=0.2, **(world_kw or {}))
    run = Run(plant=plant, controller=_Constant(plant, [10.0, 10.0]), scenario=scen,
              world=world)
    return simulate(run)


def test_touching_between_samples_is_a_collision():
    result = _straight_run()
    s, steps = result.summary, result.steps
    assert s["status"] == "collision"
    assert (steps["clearance_m"] >= 0).all()  # no sample ever saw it
    assert s["min_clearance_sampled_m"] == pytest.approx(math.hypot(0.02, 0.099) - 0.1,
                                                         abs=1e-9)
    assert s["min_clearance_m"] == pytest.approx(-0.001, abs=1e-9)
    # the run stops after the period in which it touched (x = 0.08 -> 0.12)
    assert steps["x"].iloc[-1] == pytest.approx(0.12, abs=1e-9)
    assert steps[PATH_CLEARANCE].iloc[-2] == pytest.approx(-0.001, abs=1e-9)


def test_under_latency_the_old_input_is_the_first_piece():
    # 100 ms late: nothing moves for the first half period, so every sample and the pass
    # shift by 0.02 m and the closest approach falls on a sample (x = 0.1)
    result = _straight_run({"latency": 100.0})
    s = result.summary
    assert s["status"] == "collision"
    assert s["min_clearance_m"] == pytest.approx(-0.001, abs=1e-9)
    assert s["min_clearance_sampled_m"] == pytest.approx(-0.001, abs=1e-9)
