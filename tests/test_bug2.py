"""The BUG2 state machine on scripted positions and detections."""

from __future__ import annotations

import numpy as np
import pytest

from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo
from mpclab.supervisors.boundary import ObstacleMemory, Side, offset_path
from mpclab.supervisors.bug2 import BoundaryFollowing, Bug2

GO = frozenset({"J1", "J2", "J3", "J4"})
FOLLOW = frozenset({"J3", "J4", "J5"})


def make() -> Bug2:
    sup = Bug2(
        Zumo(), modes={"go_to_goal": sorted(GO), "wall_follow": sorted(FOLLOW)},
        block_range=0.2, corridor_half_width=0.08, mline_tolerance=0.03, leave_margin=0.05,
    )
    sup.reset(np.array([0.4, 0.8, 0.0]), np.array([0.4, 0.4, 0.0]))
    return sup


NONE = np.zeros((0, 2))


def test_mline_and_free_way() -> None:
    sup = make()
    assert sup.mline == ((0.4, 0.8), (0.4, 0.4))
    # nothing seen, or a point beside the way or behind: keep going to the goal
    assert sup.update(0.0, np.array([0.4, 0.8, 0]), NONE) == ("go_to_goal", GO)
    beside = np.array([[0.55, 0.7]])      # 0.15 off the line toward the goal
    behind = np.array([[0.4, 0.9]])
    assert sup.update(0.2, np.array([0.4, 0.8, 0]), beside)[0] == "go_to_goal"
    assert sup.update(0.4, np.array([0.4, 0.8, 0]), behind)[0] == "go_to_goal"
    far = np.array([[0.4, 0.55]])         # ahead but 0.25 away > block_range
    assert sup.update(0.6, np.array([0.4, 0.8, 0]), far)[0] == "go_to_goal"


def test_hit_follow_and_leave_closer_on_mline() -> None:
    sup = make()
    ahead = np.array([[0.42, 0.65]])      # 0.15 ahead, 0.02 off the line: blocks
    assert sup.update(0.0, np.array([0.4, 0.8, 0]), ahead) == ("wall_follow", FOLLOW)
    assert sup.hit_point == pytest.approx([0.4, 0.8])
    # around the obstacle, off the m-line: keep following whatever is seen
    assert sup.update(1.0, np.array([0.6, 0.7, 0]), NONE)[0] == "wall_follow"
    # back on the m-line but not closer to the goal than the hit point: keep following
    assert sup.update(2.0, np.array([0.41, 0.78, 0]), NONE)[0] == "wall_follow"
    assert sup.update(3.0, np.array([0.6, 0.5, 0]), NONE)[0] == "wall_follow"
    # on the m-line and 0.3 m closer than the hit point: leave
    assert sup.update(4.0, np.array([0.42, 0.5, 0]), NONE) == ("go_to_goal", GO)
    assert sup.hit_point is None and len(sup.hits) == 1


def test_crossing_the_mline_between_steps_counts() -> None:
    sup = make()
    sup.update(0.0, np.array([0.4, 0.8, 0]), np.array([[0.4, 0.7]]))
    sup.update(1.0, np.array([0.45, 0.5, 0]), NONE)         # 0.05 right of the line
    assert sup.update(1.2, np.array([0.35, 0.5, 0]), NONE)[0] == "go_to_goal"


def test_rehit_closer_and_reset() -> None:
    sup = make()
    sup.update(0.0, np.array([0.4, 0.8, 0]), np.array([[0.4, 0.7]]))
    sup.update(1.0, np.array([0.4, 0.6, 0]), NONE)             # leaves (0.2 closer)
    assert sup.update(1.2, np.array([0.4, 0.6, 0]), np.array([[0.4, 0.5]]))[0] == "wall_follow"
    assert sup.hit_point == pytest.approx([0.4, 0.6])
    sup.reset(np.array([0.4, 0.8, 0.0]), np.array([0.4, 0.4, 0.0]))
    assert sup.mode.value == "go_to_goal" and sup.hits == []


def test_modes_must_be_named() -> None:
    with pytest.raises(ConfigError, match="modes"):
        Bug2(Zumo(), modes={"go_to_goal": ["J1"]})


def test_goal_in_sight_leaves_off_the_mline() -> None:
    """A goal beside a wall, in sight and nearer than the hit point: leave without reaching
    the m-line (zumo_goal_near_wall followed the wall around instead: 17 s against 4.4 s)."""
    sup = make()
    sup.sight = 0.3
    sup.update(0.0, np.array([0.4, 0.8, 0]), np.array([[0.4, 0.7]]))      # hit at the start
    wall = np.array([[0.5, 0.31], [0.55, 0.31], [0.6, 0.31]])              # below the way
    p = np.array([0.62, 0.5, 0])                                            # 0.22 from the goal
    assert sup.update(1.0, p, wall) == ("go_to_goal", GO)


def test_goal_in_sight_needs_a_free_way_progress_and_range() -> None:
    sup = make()
    sup.sight = 0.3
    sup.update(0.0, np.array([0.4, 0.8, 0]), np.array([[0.4, 0.7]]))
    p = np.array([0.62, 0.5, 0])
    on_the_way = np.array([[0.5, 0.45]])                                    # in the corridor
    assert sup.update(1.0, p, on_the_way)[0] == "wall_follow"
    far = np.array([0.75, 0.55, 0])                                         # 0.38 from the goal
    assert sup.update(1.2, far, NONE)[0] == "wall_follow"
    # in sight but not closer than the hit point by the margin: keep following
    sup2 = make()
    sup2.sight = 0.3
    sup2.update(0.0, np.array([0.4, 0.62, 0]), np.array([[0.4, 0.55]]))     # hit 0.22 away
    assert sup2.update(1.0, np.array([0.6, 0.45, 0]), NONE)[0] == "wall_follow"
    # off (the default): only the m-line rule
    sup3 = make()
    sup3.update(0.0, np.array([0.4, 0.8, 0]), np.array([[0.4, 0.7]]))
    assert sup3.update(1.0, p, NONE)[0] == "wall_follow"


def test_goal_sight_range_must_be_nonnegative() -> None:
    with pytest.raises(ConfigError, match="goal_sight_range"):
        Bug2(Zumo(), goal_sight_range=-0.1)


def test_memory_joins_points_nearer_than_the_link_and_keeps_them() -> None:
    mem = ObstacleMemory(0.15)
    wall = np.c_[np.linspace(0.0, 0.3, 7), np.zeros(7)]          # 5 cm apart
    disc = np.array([[0.8, 0.0], [0.82, 0.03]])
    ids = mem.add(np.vstack([wall, disc]))
    assert mem.obstacle(ids[0])[ids[:7]].all() and not mem.obstacle(ids[0])[ids[7:]].any()
    assert mem.obstacle(ids[7])[ids[7:]].all()
    assert mem.add(np.zeros((0, 2))).shape == (0,)
    # the same cell again is the same point; a point out of view stays remembered
    assert mem.add(wall[:1] + 0.001)[0] == ids[0] and len(mem.points) == 9
    # a gap narrower than the link (the robot cannot pass) joins the two obstacles
    bridge = mem.add(np.array([[0.42, 0.0], [0.55, 0.0], [0.68, 0.0]]))
    assert mem.labels[ids[0]] == mem.labels[ids[7]] == mem.labels[bridge[0]]


def test_the_hit_boundary_is_the_one_followed() -> None:
    sup = make()
    wall = np.c_[np.linspace(0.3, 0.5, 5), np.full(5, 0.65)]      # across the way, 0.15 ahead
    other = np.array([[0.9, 0.9]])                                 # another obstacle
    det = np.vstack([other, wall])
    assert sup.update(0.0, np.array([0.4, 0.8, 0]), det)[0] == "wall_follow"
    assert np.allclose(np.sort(sup.followed(reach=2.0), axis=0), wall, atol=0.01)
    # the next step sees the wall shifted a little and a new far point: still the wall
    moved = np.vstack([wall + [0.01, 0.0], [[0.1, 0.1]]])
    sup.update(0.2, np.array([0.45, 0.8, 0]), moved)
    followed = sup.followed(reach=2.0)
    assert len(followed) >= 5 and np.all(np.abs(followed[:, 1] - 0.65) < 0.01)
    # back to the goal: nothing is followed
    sup.update(4.0, np.array([0.42, 0.5, 0]), NONE)
    assert sup.mode == "go_to_goal" and len(sup.followed()) == 0


def test_the_path_keeps_the_clearance_along_a_wall_and_rounds_its_end() -> None:
    wall = np.c_[np.linspace(-1.0, 0.0, 201), np.zeros(201)]     # ends at the origin
    path = offset_path(np.array([-0.6, 0.1]), wall, 0.08, Side.right, 0.01, 120, heading=0.0)
    dist = np.min(np.linalg.norm(path[:, None, :2] - wall[None], axis=2), axis=1)
    # on the clearance from the first point on, with the wall on its right (+x first)
    assert np.all(np.abs(dist[1:] - 0.08) < 0.002)
    assert path[10, 0] > path[0, 0] and abs(path[10, 2]) < 0.1
    # round the end on a circle of that radius, and back along the wall's other side
    assert path[-1, 1] < -0.07 and path[-1, 0] < -0.05 and abs(abs(path[-1, 2]) - np.pi) < 0.1
    left = offset_path(np.array([-0.6, 0.08]), wall, 0.08, Side.left, 0.01, 10, heading=np.pi)
    assert left[-1, 0] < -0.65                                     # the other way round
    # in a corridor both walls' lines are near: the robot joins the one with its wall on
    # the followed side of its heading, either way it faces
    upper = wall + [0.0, 0.2]
    both = np.vstack([wall, upper])
    east = offset_path(np.array([-0.6, 0.1]), both, 0.08, Side.right, 0.01, 20, heading=0.0)
    west = offset_path(np.array([-0.6, 0.1]), both, 0.08, Side.right, 0.01, 20,
                       heading=np.pi)
    assert east[-1, 0] > -0.45 and abs(east[-1, 1] - 0.08) < 0.002
    assert west[-1, 0] < -0.75 and abs(west[-1, 1] - 0.12) < 0.002


def test_the_supervisor_hands_over_the_path_only_while_following() -> None:
    sup = Bug2(Zumo(), modes={"go_to_goal": ["J1"], "wall_follow": ["Jp"]},
               boundary=BoundaryFollowing(path_speed=0.15, clearance=0.08))
    sup.reset(np.array([0.4, 0.8, 0.0]), np.array([0.4, 0.4, 0.0]))
    assert sup.update(0.0, np.array([0.4, 0.9, 0.0]), NONE)[0] == "go_to_goal"
    assert sup.target(0.0, 10, 0.2) is None
    wall = np.c_[np.linspace(0.0, 1.0, 21), np.full(21, 0.75)]    # across the way
    assert sup.update(0.2, np.array([0.4, 0.85, 0.0]), wall)[0] == "wall_follow"
    ref = sup.target(0.2, 10, 0.2)
    assert ref.shape == (11, 3) and np.allclose(ref[0, :2], [0.4, 0.85])
    step = np.linalg.norm(np.diff(ref[:, :2], axis=0), axis=1)
    assert np.all(np.abs(step[1:] - 0.03) < 0.002)                 # 0.15 m/s for 0.2 s
    # the wall (below) on the right: the path runs in +x, on the clearance
    assert ref[-1, 0] > 0.6 and np.allclose(ref[1:, 1], 0.83, atol=0.005)


def test_a_pocket_is_traced_around_not_circled() -> None:
    # a pocket of the random layout 305: a wall end on the left, another on the right, a
    # wall below and a small disc, all nearer each other than twice the clearance; the
    # robot sits where they are all about 0.1 m away, heading into the pocket
    discs = [(0.296, 0.614, 0.05), (0.343, 0.624, 0.05), (0.603, 0.677, 0.05),
             (0.632, 0.683, 0.05), (0.660, 0.689, 0.05), (0.614, 0.354, 0.05),
             (0.629, 0.401, 0.05), (0.643, 0.447, 0.05), (0.433, 0.504, 0.019)]
    ang = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    points = np.vstack([np.c_[cx + r * np.cos(ang), cy + r * np.sin(ang)]
                        for cx, cy, r in discs])
    p = np.array([0.497, 0.593])
    path = offset_path(p, points, 0.08, Side.right, 0.03, 20, heading=3.59)
    assert np.linalg.norm(path[-1, :2] - p) > 0.25
    dist = np.min(np.linalg.norm(path[1:, None, :2] - points[None], axis=2), axis=1)
    assert np.all(np.abs(dist - 0.08) < 0.002)


def test_a_gap_narrower_than_twice_the_clearance_is_not_passed() -> None:
    # along the underside of a wall (on the right, heading -x); 0.15 m below it the top of
    # another wall: the memory links the two (0.15 < 2 x 0.08), so the path turns down the
    # second wall's near side instead of passing between them
    top = np.c_[np.linspace(-1.0, 1.0, 201), np.zeros(201)]
    stem = np.c_[np.zeros(46), np.linspace(-0.15, -0.6, 46)]
    points = np.vstack([top, stem])
    path = offset_path(np.array([0.6, -0.08]), points, 0.08, Side.right, 0.01, 100,
                       heading=np.pi)
    assert np.all(path[:, 0] > 0.035) and path[-1, 1] < -0.4


def test_a_pocket_whose_way_out_is_narrow_is_left_at_a_lower_clearance() -> None:
    # a box 0.3 m wide, its mouth 0.15 m wide (closed at a clearance of 0.08, open at
    # 0.07); the robot inside: the path at 0.08 circles inside, at 0.07 it leads out
    side = np.linspace(0.0, 0.3, 31)
    box = np.vstack([np.c_[side, np.zeros(31)], np.c_[np.zeros(31), side],
                     np.c_[np.full(31, 0.3), side],
                     np.c_[np.linspace(0.0, 0.075, 9), np.full(9, 0.3)],
                     np.c_[np.linspace(0.225, 0.3, 9), np.full(9, 0.3)]])
    p = np.array([0.15, 0.12])
    trapped = offset_path(p, box, 0.08, Side.right, 0.03, 40, heading=0.0)
    assert np.all(trapped[:, 1] < 0.3)
    out = offset_path(p, box, 0.08, Side.right, 0.03, 40, heading=0.0, least=0.07)
    assert np.max(out[:, 1]) > 0.35
    # in the mouth, heading in: the pocket is not joined, the line outside is
    for heading in (-np.pi / 2, -np.pi / 4, -3 * np.pi / 4):
        mouth = offset_path(np.array([0.15, 0.3]), box, 0.08, Side.right, 0.03, 20,
                            heading=heading)
        inner = (np.abs(mouth[1:, :2] - 0.15) < 0.15).all(axis=1)
        assert not inner.any()


def within_5cm(x: np.ndarray) -> bool:
    return bool(np.hypot(x[0] - 0.4, x[1] - 0.4) < 0.05)


@pytest.mark.parametrize(("where", "arrived", "stuck"), [
    ((0.4, 0.6), None, True),          # no progress beside a wall: stuck
    ((0.4, 0.6), within_5cm, True),    # ... and still, 20 cm from the goal
    ((0.4, 0.43), None, True),         # without an arrival rule the goal is not known
    ((0.4, 0.43), within_5cm, False),  # where it measures the goal: not stuck, it is there
])
def test_a_robot_at_its_measured_goal_is_not_stuck(where, arrived, stuck) -> None:
    sup = Bug2(Zumo(), block_range=0.2, corridor_half_width=0.08,
               stuck={"window": 1.0})
    sup.reset(np.array([0.4, 0.8, 0.0]), np.array([0.4, 0.4, 0.0]), arrived)
    x = np.array([*where, -np.pi / 2])
    beside = np.array([[x[0] + 0.15, x[1]]])  # near, out of the corridor toward the goal
    modes = [sup.update(0.2 * k, x, beside)[0] for k in range(8)]
    assert (modes[-1] == "wall_follow") is stuck


def test_a_robot_at_its_measured_goal_leaves_the_wall() -> None:
    sup = Bug2(Zumo(), block_range=0.2, corridor_half_width=0.08, mline_tolerance=0.03)
    sup.reset(np.array([0.4, 0.8, 0.0]), np.array([0.4, 0.4, 0.0]), within_5cm)
    wall = np.c_[np.linspace(0.3, 0.5, 5), np.full(5, 0.65)]
    assert sup.update(0.0, np.array([0.4, 0.8, 0.0]), wall)[0] == "wall_follow"
    off_mline = np.array([0.445, 0.41, 0.0])  # 4.5 cm off the m-line, beside the goal
    assert not sup.can_leave(off_mline[:2])
    assert sup.update(0.2, off_mline, wall)[0] == "go_to_goal"
