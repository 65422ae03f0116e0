"""Study B's closed-loop outcomes (Figs. 4-8, docs/studies.md), the main command's and BUG2's
on random layouts."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.slow


@pytest.mark.parametrize(
    ("experiment", "scenario", "arrives", "status"),
    [
        ("zumo_potential", "zumo_one_obstacle", True, "arrived"),      # Fig. 4
        ("zumo_potential", "zumo_wall", False, "stalled"),             # Fig. 5
        ("zumo_right_hand", "zumo_wall", True, "arrived"),             # Fig. 6
        ("zumo_right_hand", "zumo_dead_end", False, None),             # Fig. 7
        ("zumo_bug2_study", "zumo_dead_end", True, "arrived"),         # Fig. 8
        ("zumo_bug2_study", "zumo_wall", True, "arrived"),
        ("zumo_bug2_study", "zumo_one_obstacle", True, "arrived"),
        ("zumo_bug2", "zumo_dead_end", True, "arrived"),               # on constraints
        ("zumo_bug2", "zumo_wall", True, "arrived"),
        ("zumo_bug2", "zumo_one_obstacle", True, "arrived"),
    ],
)
def test_study_b_outcomes(run_cfg, experiment, scenario, arrives, status) -> None:
    res, _ = run_cfg([f"+experiment={experiment}", f"scenario={scenario}"])
    s = res.summary
    assert s["arrived"] is arrives, s
    if status is not None:
        assert s["status"] == status
    assert s["status"] != "collision" and s["min_clearance_m"] > 0
    assert s["solver_failures"] == 0 or not arrives


def test_main_command_is_converged_smooth_and_purposeful(run_cfg) -> None:
    """`+experiment=zumo_bug2` (zumo_dead_end) arrives converged and without chatter:
    measured 8.8 s, converged 1.0, u1 0.34 sign changes/s (the left wheel reverses three
    times, turning in place at the dead end's corners), heading change at most 5.8 rad,
    clearance 0.017 m; the study's formulation (zumo_bug2_study) 10.4 s."""
    res, _ = run_cfg(["+experiment=zumo_bug2"])
    s = res.summary
    assert s["status"] == "arrived" and s["arrival_time_s"] <= 11.0, s
    assert s["converged_fraction"] >= 0.95 and s["solver_failures"] == 0, s
    assert s["u1_sign_changes_per_s"] <= 0.5, s
    assert s["max_heading_change_rad"] < 2 * math.pi, s     # no loop in place
    assert s["min_clearance_m"] > 0, s
    assert set(res.steps["mode"].dropna()) - {""} == {"go_to_goal", "wall_follow"}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bug2_on_random_layouts(run_cfg, seed) -> None:
    res, _ = run_cfg(["+experiment=zumo_bug2", "scenario=zumo_random_easy", f"seed={seed}"])
    s = res.summary
    assert s["status"] == "arrived", s
    # the layout does block the straight way (the first wall crosses it)
    steps = res.steps
    assert (steps["mode"] == "wall_follow").any()
    assert np.isfinite(s["min_clearance_m"]) and s["min_clearance_m"] > 0


def test_bug2_dead_end_on_two_sqp_steps_with_the_hard_constraint(run_cfg) -> None:
    """The truncated option still arrives, honestly labelled (one SQP step a sample stalls
    at the dead end's corner: the plan is too far from converged to track the path). A few
    of its calls fail (the Hessian's eigen-decomposition for its convexification does not
    converge): each is counted failed and falls back."""
    res, _ = run_cfg(["+experiment=zumo_bug2", "controller=casadi_sqp_capped",
                      "controller.solve.sqp_iterations=2",
                      "objective.constraints.obstacles.mode=hard"])
    s = res.summary
    assert s["status"] == "arrived", s
    assert s["solver_failures"] == s["solves_failed"] <= 0.1 * len(res.steps), s
    assert s["solves_truncated"] > 0 and s["converged_fraction"] < 1.0, s
    assert s["min_clearance_m"] > 0
