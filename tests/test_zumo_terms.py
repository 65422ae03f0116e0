"""J1..J5 against values computed by hand; the Zumo plant's kinematics."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpclab.objectives.base import TermContext
from mpclab.objectives.potential import (
    GoalAttraction,
    HeadingNearGoal,
    LeftHandPull,
    ObstacleRepulsion,
)
from mpclab.objectives.quadratic import QuadraticTracking
from mpclab.plants.zumo import Zumo

PLANT = Zumo()


def value(term, p1, u=(0.0, 0.0), goal=(0.4, 0.4, 0.0), x0=(0.0, 0.0, 0.0), det=(), mask=()):
    """The term's cost for a one-step horizon whose predicted state is ``p1``."""
    term.bind(PLANT)
    X = ca.DM(np.column_stack([x0, p1]))
    U = ca.DM(np.asarray(u, dtype=float).reshape(2, 1))
    det = np.asarray(det, dtype=float).reshape(-1, 2)
    ctx = TermContext(
        goal=ca.DM(goal), x0=ca.DM(x0), target=ca.DM(np.column_stack([goal, goal])),
        u_prev=ca.DM.zeros(2),
        detections=ca.DM(det.T if len(det) else np.full((2, 1), 1e3)),
        mask=ca.DM(np.asarray(mask, dtype=float) if len(det) else [0.0]),
    )
    return float(term.casadi_cost(X, U, ctx))


def test_zumo_kinematics() -> None:
    r, d = PLANT.params.r, PLANT.params.d
    f = PLANT.f
    # equal wheel speeds: straight at V = r u along the heading, no turning
    assert np.asarray(f([0, 0, np.pi / 2], [5, 5])).ravel() == pytest.approx([0, r * 5, 0])
    # opposite wheel speeds: turn on the spot at omega = r (u2 - u1) / (2 d)
    assert np.asarray(f([0, 0, 0], [-5, 5])).ravel() == pytest.approx([0, 0, r * 10 / (2 * d)])


def test_j1_goal_attraction() -> None:
    # predicted (0.7, 0.8), goal (0.4, 0.4): distance 0.5
    v = value(GoalAttraction(C1=5500, L1=2), (0.7, 0.8, 0.0))
    assert v == pytest.approx(-5500 * np.exp(-0.25), rel=1e-5)


def test_j2_input_effort() -> None:
    v = value(QuadraticTracking(input_weights={"u1": 0.01, "u2": 0.01}), (0, 0, 0), u=(2, 3))
    assert v == pytest.approx(0.01 * 4 + 0.01 * 9)


def test_j3_heading_near_goal_wraps() -> None:
    # 0.05 m from the goal, heading 0.3 rad off the goal heading 0
    term = HeadingNearGoal(C2=100, L2=0.04, eps=1e-12)
    expect = 0.3**2 * 100 * np.exp(-0.05 / 0.04)
    assert value(term, (0.43, 0.44, 0.3)) == pytest.approx(expect, rel=1e-4)
    # the same heading one turn later costs the same (the error is wrapped)
    assert value(term, (0.43, 0.44, 0.3 + 2 * np.pi)) == pytest.approx(expect, rel=1e-4)


def test_j4_repulsion_sums_masked_points() -> None:
    term = ObstacleRepulsion(C3=1500, L3=0.05, eps=1e-12)
    p1 = (0.43, 0.44, 0.0)
    det = [(0.46, 0.48), (0.43, 0.54), (0.0, 0.0)]   # 0.05 m, 0.1 m, and a padded slot
    v = value(term, p1, det=det, mask=(1, 1, 0))
    assert v == pytest.approx(1500 * (np.exp(-1.0) + np.exp(-2.0)), rel=1e-4)
    assert value(term, p1, det=det, mask=(0, 0, 0)) == 0.0


def test_j5_left_hand_pull() -> None:
    # robot at the origin sees a point at (1, 0); rotated 70 deg left: g = (cos 70, sin 70)
    g = np.array([np.cos(np.deg2rad(70)), np.sin(np.deg2rad(70))])
    p1 = (*(g + [0.3, 0.4]), 0.0)           # 0.5 m from g
    goal = (p1[0], p1[1] + 0.2, 0.0)        # Q = 0.2 m to the goal
    det, mask = [(1.0, 0.0)], (1,)
    v = value(LeftHandPull(C4=900, L4=0.3), p1, goal=goal, det=det, mask=mask)
    assert v == pytest.approx(0.2 * -900 * np.exp(-0.5 / 0.3), rel=1e-4)
    flat = LeftHandPull(C4=900, L4=0.3, goal_scaled=False)
    assert value(flat, p1, goal=goal, det=det, mask=mask) == pytest.approx(
        -900 * np.exp(-0.5 / 0.3), rel=1e-4
    )


def test_terms_finite_derivatives_at_zero_distance() -> None:
    # at the goal and on a detected point the sqrt(. + eps) keeps gradients finite
    X = ca.SX.sym("X", 3, 2)
    U = ca.SX.sym("U", 2, 1)
    p = TermContext(goal=ca.DM([0.4, 0.4, 0]), x0=ca.DM([0, 0, 0]), target=None,
                    u_prev=ca.DM.zeros(2), detections=ca.DM([[0.4], [0.4]]), mask=ca.DM([1.0]))
    for term in (GoalAttraction(), HeadingNearGoal(), ObstacleRepulsion(), LeftHandPull()):
        term.bind(PLANT)
        grad = ca.Function("g", [X, U], [ca.gradient(term.casadi_cost(X, U, p), X)])
        out = np.asarray(grad(ca.DM([[0, 0.4], [0, 0.4], [0, 0]]), ca.DM.zeros(2, 1)))
        assert np.all(np.isfinite(out)), type(term).__name__
