"""Random layouts with the hard cases, always solvable; the curated hard layouts."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import compose_cfg
from mpclab.core.errors import ConfigError
from mpclab.runner.single_run import build_run
from mpclab.world.free_space import connected
from mpclab.world.obstacles import wall
from mpclab.world.random_layout import random_layout, random_walls

START, GOAL, EXTENT = (0.4, 0.8), (0.4, 0.4), (-0.1, 1.3, -0.1, 1.3)
R = 0.05  # obstacle and robot radius


def _gap_wall(width: float) -> np.ndarray:
    """A wall at y = 0.6 across the whole extent with a gap of ``width`` between the
    surfaces of its two middle discs, centred on x = 0.4."""
    left = wall((-0.3, 0.6), (0.4 - width / 2 - R, 0.6), 0.05, R)
    right = wall((0.4 + width / 2 + R, 0.6), (1.5, 0.6), 0.05, R)
    return np.concatenate([left, right])


@pytest.mark.parametrize("width, passable", [
    (0.09, False), (0.099, False), (0.111, True), (0.12, True)])
def test_connected_knows_a_gap_the_robot_disc_fits_through(width, passable):
    # the robot (diameter 0.10) fits only through a wider gap; the check keeps a margin of
    # cell / 2 = 2.5 mm a side and needs a column of cell centres (5 mm) in what is left,
    # so it passes every gap from 0.110 m and may refuse narrower ones (conservative)
    assert connected(_gap_wall(width), START, GOAL, R, EXTENT) is passable


def test_a_goal_walled_in_is_not_connected_and_its_layout_is_refused():
    ring = np.array([[0.4 + 0.15 * np.cos(a), 0.4 + 0.15 * np.sin(a), R]
                     for a in np.linspace(0, 2 * np.pi, 24, endpoint=False)])
    assert not connected(ring, START, GOAL, R, EXTENT)
    assert connected(ring[:-6], START, GOAL, R, EXTENT)  # an opening 0.14 m wide
    conf = {"n_walls": 1, "max_layouts": 3}
    with pytest.raises(ConfigError, match="reach the goal"):
        random_layout(np.random.default_rng(0), conf, R, 0.05, START, GOAL, R, EXTENT,
                      fixed=ring)


def _layout(scenario: str, seed: int):
    cfg = compose_cfg(["+experiment=zumo_bug2", f"scenario={scenario}", f"seed={seed}",
                       "recorder=none"])
    return build_run(cfg).scenario


@pytest.mark.parametrize("scenario", ["zumo_random", "zumo_random_hard"])
def test_random_layouts_are_seeded_and_solvable(scenario):
    for seed in range(6):
        scen = _layout(scenario, seed)
        again = _layout(scenario, seed)
        np.testing.assert_array_equal(scen.obstacles, again.obstacles)
        assert scen.clearance(scen.goal) >= 0 and scen.clearance(scen.x0) >= 0
        # an independent check on a finer grid with no margin: a path exists
        assert connected(scen.obstacles, scen.x0[:2], scen.goal[:2], scen.robot_radius,
                         scen.extent, cell=0.002, margin=0.0)


def test_hard_defaults_include_the_hard_cases():
    """Over 20 seeds zumo_random_hard often places a wall near the goal, always small discs."""
    near_goal, small = 0, 0
    for seed in range(20):
        discs = _layout("zumo_random_hard", seed).obstacles
        surface = np.linalg.norm(discs[:, :2] - np.array(GOAL), axis=1) - discs[:, 2]
        near_goal += surface.min() < 0.1
        small += (discs[:, 2] < 0.03).sum() == 3
    assert near_goal >= 5 and small == 20


def _conf(**kw):
    return {"n_walls": 0, "across": False, "region": [0.0, 0.9, 0.15, 1.05], **kw}


def test_goal_wall_passes_at_the_given_distance():
    for seed in range(10):
        discs = random_walls(np.random.default_rng(seed),
                             _conf(goal_wall=1.0, goal_wall_gap=[0.06, 0.06]),
                             R, 0.05, START, GOAL)
        surface = np.linalg.norm(discs[:, :2] - np.array(GOAL), axis=1) - R
        # the wall's line passes 0.06 from the goal; its nearest disc is at most half a
        # spacing along it from the foot of the perpendicular
        assert 0.06 - 1e-9 <= surface.min() <= np.hypot(0.11, 0.025) - R + 1e-9


def test_crossing_wall_gap_has_the_given_width():
    for seed in range(10):
        discs = random_walls(np.random.default_rng(seed),
                             _conf(n_walls=1, across=True, gap=1.0, gap_width=[0.12, 0.12],
                                   length=[0.5, 0.6]), R, 0.05, START, GOAL)
        centres = discs[:, :2]
        direction = centres[-1] - centres[0]
        order = np.argsort(centres @ direction)
        steps = np.linalg.norm(np.diff(centres[order], axis=0), axis=1)
        gaps = steps[steps > 0.05 + 1e-9] - 2 * R
        assert gaps == pytest.approx([0.12], abs=1e-9)


def test_corridor_puts_the_goal_between_two_walls():
    for seed in range(10):
        discs = random_walls(np.random.default_rng(seed),
                             _conf(corridor=1.0, corridor_width=[0.16, 0.16]),
                             R, 0.05, START, GOAL)
        surface = np.linalg.norm(discs[:, :2] - np.array(GOAL), axis=1) - R
        assert surface.min() == pytest.approx(0.08, abs=0.004)
        # a wall on each side: discs both ways along the corridor's normal
        near = discs[surface < 0.09, :2] - np.array(GOAL)
        n = near[0] / np.linalg.norm(near[0])
        assert (near @ n).min() < 0 < (near @ n).max()


def test_isolated_discs_have_their_own_radius():
    discs = random_walls(np.random.default_rng(1),
                         _conf(n_discs=4, disc_radius=[0.02, 0.02], disc_on_path=0.5),
                         R, 0.05, START, GOAL)
    assert len(discs) == 4 and np.allclose(discs[:, 2], 0.02)


HARD = ["zumo_hard_goal_in_corridor", "zumo_hard_goal_near_wall", "zumo_hard_narrow_gap",
        "zumo_hard_between_rays", "zumo_hard_around_corner", "zumo_hard_goal_in_corner"]


@pytest.mark.parametrize("scenario", HARD)
def test_curated_hard_layouts_are_solvable(scenario):
    scen = _layout(scenario, 0)
    assert connected(scen.obstacles, scen.x0[:2], scen.goal[:2], scen.robot_radius,
                     scen.extent, cell=0.002, margin=0.0)


def test_a_layout_can_be_required_to_pass_with_a_clearance():
    # the goal in a ring of discs open by 0.12 m between surfaces: the robot disc fits (0.10)
    # but not while keeping 15 mm from both sides (0.13)
    half = np.arcsin(0.11 / 0.2)  # the two discs beside the opening: centres 0.22 m apart
    angles = np.linspace(np.pi / 2 + half, 5 * np.pi / 2 - half, 40)  # facing the start (+y)
    ring = np.array([[0.4 + 0.2 * np.cos(a), 0.4 + 0.2 * np.sin(a), R] for a in angles])
    conf = {"n_walls": 0, "max_layouts": 3}
    assert connected(ring, START, GOAL, R, EXTENT)
    random_layout(np.random.default_rng(0), conf, R, 0.05, START, GOAL, robot_radius=R,
                  extent=EXTENT, fixed=ring)
    with pytest.raises(ConfigError, match="clearance 0.015"):
        random_layout(np.random.default_rng(0), {**conf, "clearance": 0.015}, R, 0.05,
                      START, GOAL, robot_radius=R, extent=EXTENT, fixed=ring)
