"""Evaluation helpers: exact binomial intervals and the closed-loop stage cost."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import compose_cfg
from mpclab.approx.evaluate import StageCost
from mpclab.record.stats import clopper_pearson


def test_clopper_pearson_matches_the_closed_forms_at_the_edges() -> None:
    # k = 0: upper = 1 - (alpha/2)^(1/n); k = n: lower = (alpha/2)^(1/n)
    lo, hi = clopper_pearson(0, 10)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 10), rel=1e-9)
    lo, hi = clopper_pearson(200, 200)
    assert hi == 1.0 and lo == pytest.approx(0.025 ** (1 / 200), rel=1e-9)
    lo, hi = clopper_pearson(192, 200)
    assert lo < 0.96 < hi


def test_stage_cost_is_zero_at_rest_on_the_goal_and_positive_elsewhere() -> None:
    # without the obstacle nothing is in sight at the goal (with it, J4 charges even there)
    cost = StageCost(compose_cfg(["+experiment=zumo_nn_data", "scenario.layout.discs=[]"]))
    at_goal = pd.DataFrame({"x": [0.4] * 3, "y": [0.4] * 3, "theta": [0.0] * 3,
                            "u1": [0.0, 0.0, np.nan], "u2": [0.0, 0.0, np.nan]})
    assert cost(at_goal) == pytest.approx(0.0, abs=1e-9)
    away = at_goal.assign(x=[0.9, 0.9, 0.9])
    moving = at_goal.assign(u1=[3.0, 3.0, np.nan])
    assert cost(away) > 0 and cost(moving) > 0
    with_obstacle = StageCost(compose_cfg(["+experiment=zumo_nn_data"]))
    assert with_obstacle(at_goal) > 0  # the obstacle 0.15 m away is seen and repels
