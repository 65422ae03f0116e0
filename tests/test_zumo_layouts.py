"""BUG2 on layouts nobody tuned it for (conf/scenario/zumo_*.yaml): the study's potential-field
formulation (`+experiment=zumo_bug2_study`, the arrival times measured with it) and the
constrained default (`+experiment=zumo_bug2`), also where the goal lies near a wall:
a wall longer than the sensor range across the way, an L, a cup open toward the robot, a
narrow and a wide gap, a goal near a wall; in all of them the goal is abeam of the start
heading (the robot faces +x, the goal lies straight below it)."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow

# measured (zumo_bug2_study, experiments/zumo/README.md's outcomes): arrival [s]; whether
# BUG2 follows a wall
LAYOUTS = {
    "zumo_long_wall": (11.0, True),        # 1.1 m across, its ends out of sight of the hit point
    "zumo_l_wall": (12.0, True),           # the wall turns up beside the start
    "zumo_cup": (10.2, True),              # drives into a cup, climbs out along its wall
    "zumo_narrow_gap": (9.6, True),        # 3 cm a side: J4 bars it; blocked, goes around
    "zumo_wide_gap": (2.2, False),         # straight through, nothing blocks
    "zumo_goal_near_wall": (4.4, True),    # leaves the disc with the goal in sight
}


@pytest.mark.parametrize("scenario", sorted(LAYOUTS))
def test_bug2_arrives_on_untuned_layouts(run_cfg, scenario) -> None:
    res, _ = run_cfg(["+experiment=zumo_bug2_study", f"scenario={scenario}"])
    s = res.summary
    measured_t, follows = LAYOUTS[scenario]
    assert s["status"] == "arrived", s
    assert s["arrival_time_s"] <= 1.5 * measured_t + 1.0, s   # no long detour crept in
    assert s["solver_failures"] == 0 and s["converged_fraction"] >= 0.95, s
    assert s["min_clearance_m"] > 0.02, s
    assert s["u1_sign_changes_per_s"] <= 0.5, s
    modes = res.steps["mode"].dropna()
    assert ((modes == "wall_follow").any()) is follows


@pytest.mark.parametrize("scenario", sorted(LAYOUTS) + [
    "zumo_goal_near_wall_nodisc", "zumo_goal_near_wall_027"])
def test_constrained_bug2_arrives_without_touching(run_cfg, scenario) -> None:
    res, _ = run_cfg(["+experiment=zumo_bug2", f"scenario={scenario}"])
    s = res.summary
    assert s["status"] == "arrived", s
    assert s["solver_failures"] == 0 and s["converged_fraction"] >= 0.95, s
    assert s["min_clearance_m"] > 0, s   # the derived margin keeps the surfaces off the robot
    assert s["constraints"]["obstacles"]["distance_m"] == pytest.approx(s["margin"]["total_m"])


def test_the_study_formulation_stops_short_of_a_goal_near_a_wall(run_cfg) -> None:
    """J4 from the wall outweighs J1's pull: what the constraint replaces."""
    res, _ = run_cfg(["+experiment=zumo_bug2_study", "scenario=zumo_goal_near_wall_nodisc"])
    assert res.summary["status"] != "arrived"
