"""The one-step CBF safety filter on the applied input, alone and in the closed loop."""

from __future__ import annotations

import numpy as np
import pytest

from mpclab.controllers.safety_filter import SafetyFilter
from mpclab.core.errors import ConfigError
from mpclab.plants.zumo import Zumo

PLANT = Zumo(input_bounds={"u1": [-10, 10], "u2": [-10, 10]})
X = np.array([0.4, 0.8, 0.0])          # facing +x


def _h(p, q, R):
    return float(np.sum((p - q) ** 2) - R**2)


def test_untouched_when_the_condition_holds() -> None:
    f = SafetyFilter(PLANT, distance=0.065, gamma=0.5, dt=0.2)
    u = np.array([10.0, 10.0])
    assert f.filter(X, u, np.zeros((0, 2))) == (pytest.approx(u), 0)
    behind = np.array([[0.25, 0.8]])
    out, code = f.filter(X, u, behind)
    assert code == 0 and out == pytest.approx(u)


@pytest.mark.parametrize("gamma", [0.1, 0.3, 0.6])
def test_full_speed_at_a_point_ahead_is_slowed_to_the_barrier(gamma) -> None:
    f = SafetyFilter(PLANT, distance=0.065, gamma=gamma, dt=0.2)
    q = np.array([[0.52, 0.8]])          # 0.12 m ahead
    u = np.array([10.0, 10.0])
    p1 = PLANT.step(X, u, 0.2)[:2]
    assert _h(p1, q[0], 0.065) < (1 - gamma) * _h(X[:2], q[0], 0.065)   # nominal breaks it
    out, code = f.filter(X, u, q)
    assert code == 1
    assert np.all(out <= 10 + 1e-9) and np.all(out >= -10 - 1e-9)
    p1 = PLANT.step(X, out, 0.2)[:2]
    bound = (1 - gamma) * _h(X[:2], q[0], 0.065)
    assert _h(p1, q[0], 0.065) >= bound - 1e-9          # the condition on the true next state
    # the nearest such input: a step of 1 % toward u breaks it
    v = out + 0.01 * (u - out)
    assert _h(PLANT.step(X, v, 0.2)[:2], q[0], 0.065) < bound


def test_bad_gamma_is_refused() -> None:
    with pytest.raises(ConfigError, match="gamma"):
        SafetyFilter(PLANT, gamma=2.0)


def test_the_nn_policy_runs_behind_the_filter_and_the_log_says_when(run_cfg) -> None:
    res, _ = run_cfg(["+experiment=zumo_nn", "+safety_filter=cbf", "seed=3"])
    steps = res.steps
    assert "safety_filter" in steps
    codes = steps["safety_filter"].dropna().astype(int)
    assert set(codes) <= {0, 1, 2} and len(codes) == len(steps) - 1
    assert res.summary["status"] != "collision"
