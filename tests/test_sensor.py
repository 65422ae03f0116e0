"""The range sensor against hand-computed geometry; the obstacle world's hooks."""

from __future__ import annotations

import numpy as np
import pytest

from mpclab.world.obstacles import wall
from mpclab.world.sensor import RangeSensor, ray_disc_distances


def test_hit_straight_ahead() -> None:
    # disc centre 1 m ahead, radius 0.2: the surface is 0.8 m away
    d = ray_disc_distances((0, 0), [0.0], [[1.0, 0.0, 0.2]])
    assert d[0] == pytest.approx(0.8)


def test_hit_off_centre_chord() -> None:
    # ray along +x, disc at (1, 0.1) radius 0.2: x = 1 - sqrt(0.2^2 - 0.1^2)
    d = ray_disc_distances((0, 0), [0.0], [[1.0, 0.1, 0.2]])
    assert d[0] == pytest.approx(1 - np.sqrt(0.03))


def test_miss_and_behind() -> None:
    d = ray_disc_distances((0, 0), [0.0, np.pi], [[1.0, 0.5, 0.2]])
    assert np.isinf(d[0])  # passes 0.5 m from the centre, radius 0.2
    d = ray_disc_distances((0, 0), [np.pi], [[1.0, 0.0, 0.2]])
    assert np.isinf(d[0])  # the disc is behind the ray


def test_tangent_ray_touches() -> None:
    # ray along +x, disc of radius 0.2 centred 0.2 above the ray at x = 1: touches at x = 1
    d = ray_disc_distances((0, 0), [0.0], [[1.0, 0.2, 0.2]])
    assert d[0] == pytest.approx(1.0, abs=1e-6)


def test_nearest_of_several_and_diagonal() -> None:
    discs = [[3.0, 0.0, 0.5], [1.0, 0.0, 0.1], [2.0, 0.0, 0.1]]
    d = ray_disc_distances((0, 0), [0.0], discs)
    assert d[0] == pytest.approx(0.9)
    # 45 degrees to a disc at (1, 1), radius 0.1: sqrt(2) - 0.1
    d = ray_disc_distances((0, 0), [np.pi / 4], [[1.0, 1.0, 0.1]])
    assert d[0] == pytest.approx(np.sqrt(2) - 0.1)


def test_origin_inside_disc_is_zero() -> None:
    d = ray_disc_distances((0.0, 0.0), [0.0, 1.0, 2.0], [[0.05, 0.0, 0.1]])
    assert np.all(d == 0.0)


def test_sensor_rays_heading_range_and_points() -> None:
    s = RangeSensor(n_rays=20, max_range=0.3)
    assert np.allclose(np.diff(s.angles(0.0)), np.deg2rad(18))
    # robot at origin heading +y (pi/2): ray 0 points at +y, ray 5 at -x (90 deg later)
    discs = np.array([[0.0, 0.25, 0.05], [-0.5, 0.0, 0.05]])
    r = s.distances((0.0, 0.0, np.pi / 2), discs)
    assert r[0] == pytest.approx(0.2)
    assert np.isinf(r[5])                   # 0.45 m away: beyond range
    assert np.isfinite(r).sum() == 1        # 0.05/0.25 rad half-width: only ray 0 sees it
    pts = s.detect((0.0, 0.0, np.pi / 2), discs)
    assert pts == pytest.approx(np.array([[0.0, 0.2]]))
    ends, hit = s.end_points((0.0, 0.0, np.pi / 2), discs)
    assert ends.shape == (20, 2) and hit.sum() == 1
    assert np.linalg.norm(ends[~hit], axis=1) == pytest.approx(np.full(19, 0.3))


def test_wall_is_a_row_of_discs() -> None:
    w = wall([0.0, 0.0], [0.5, 0.0], spacing=0.05, radius=0.05)
    assert w.shape == (11, 3)
    assert np.allclose(np.diff(w[:, 0]), 0.05) and np.all(w[:, 2] == 0.05)


def test_obstacle_scenario_hooks() -> None:
    from conftest import compose_cfg
    from mpclab.runner.single_run import build_run

    cfg = compose_cfg(["+experiment=zumo_potential", "recorder=none"])
    scen = build_run(cfg).scenario
    assert scen.obstacles.shape == (1, 3)
    x0 = scen.x0                                  # (0.4, 0.8), disc (0.4, 0.6) r 0.05
    assert scen.clearance(x0) == pytest.approx(0.2 - 0.05 - 0.05)
    assert not scen.collided(x0)
    assert scen.collided(np.array([0.4, 0.68, 0.0]))   # 0.08 < 0.05 + 0.05
    assert scen.rays(x0).shape == (20, 2)
    # ray 15 (270 deg from heading +x) looks straight down at the disc's top (0.4, 0.65)
    assert scen.rays(x0)[15] == pytest.approx([0.4, 0.65])
    assert scen.detect(x0).shape[1] == 2 and len(scen.detect(x0)) >= 1
    # the loop's single reading equals the separate hooks
    det, ranges = scen.sense(x0)
    np.testing.assert_array_equal(det, scen.detect(x0))
    np.testing.assert_array_equal(ranges, scen.ranges(x0))
    assert ranges[15] == pytest.approx(0.15)


def test_stall_rule() -> None:
    from conftest import compose_cfg
    from mpclab.runner.single_run import build_run

    cfg = compose_cfg(["+experiment=zumo_potential", "recorder=none"])
    scen = build_run(cfg).scenario          # window 4 s, progress 0.01 m, displacement 0.05 m
    t = [0.2 * k for k in range(21)]
    still = [np.array([0.4, 0.8 - 0.0001 * k, 0.0]) for k in range(21)]
    assert scen.stalled(t, still)
    assert not scen.stalled(t[:10], still[:10])  # shorter than the window
    moving = [np.array([0.4, 0.8 - 0.01 * k, 0.0]) for k in range(21)]
    assert not scen.stalled(t, moving)
    # a detour away from the goal is movement, not a stall
    detour = [np.array([0.4 + 0.02 * k, 0.8 + 0.01 * k, 0.0]) for k in range(21)]
    assert not scen.stalled(t, detour)
    # out 0.2 m and back to where it was (a U-turn at a blocked gap): it moved
    u_turn = [np.array([0.4 + 0.02 * min(k, 20 - k), 0.8, 0.0]) for k in range(21)]
    assert not scen.stalled(t, u_turn)
    # rocking 3 cm either way and back, in place: stalled
    rocking = [np.array([0.4 + 0.03 * np.sin(k), 0.8, 0.0]) for k in range(21)]
    assert scen.stalled(t, rocking)


def test_scenario_metrics_heading_change_and_sign_changes() -> None:
    """A loop in place shows as a heading change over 2 pi; chatter as sign changes per s."""
    import pandas as pd

    from conftest import compose_cfg
    from mpclab.runner.single_run import build_run

    scen = build_run(compose_cfg(["+experiment=zumo_potential", "recorder=none"])).scenario
    n = 11                                        # t = 0 .. 2 s, the last row the final state
    steps = pd.DataFrame({
        "t": 0.2 * np.arange(n),
        "x": np.full(n, 0.4), "y": np.linspace(0.8, 0.7, n),
        "theta": np.linspace(0.0, -7.0, n),       # more than a full turn clockwise
        "u1": [5, -5, 5, -5, 0, 5, 5, 5, 5, 5, np.nan],   # 4 flips, the zero skipped
        "u2": [3] * (n - 1) + [np.nan],
    })
    m = scen.metrics(steps, {})
    assert m["heading_change_rad"] == pytest.approx(-7.0)
    assert m["max_heading_change_rad"] == pytest.approx(7.0)
    assert m["max_heading_change_rad"] > 2 * np.pi
    assert m["u1_sign_changes_per_s"] == pytest.approx(4 / 2.0)
    assert m["u2_sign_changes_per_s"] == 0.0
    assert m["path_length_m"] == pytest.approx(0.1)
