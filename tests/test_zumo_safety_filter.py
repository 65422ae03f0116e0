"""The one-step CBF safety filter on the applied input, alone and in the closed loop."""

from __future__ import annotations

import numpy as np
import pytest

from mpclab.controllers.safety_filter import SHORTFALL_TOL, SafetyFilter
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


def _nearest_by_loop(A, b, lb, ub):
    """The nearest feasible ``d`` by trying every active set one at a time: the reference of
    the batched enumeration."""
    from itertools import combinations

    nu = A.shape[1]
    rows = [(A[i], b[i]) for i in range(len(b))]
    for j in range(nu):
        e = np.eye(nu)[j]
        rows += [(e, lb[j]), (-e, -ub[j])]
    Ar, br = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
    best, best_norm = None, np.inf
    for size in range(nu + 1):
        for S in combinations(range(len(br)), size):
            d = np.zeros(nu)
            if size:
                AS = Ar[list(S)]
                if abs(np.linalg.det(AS @ AS.T)) < 1e-12:
                    continue
                d = AS.T @ np.linalg.solve(AS @ AS.T, br[list(S)])
            if np.max(br - Ar @ d) <= 1e-9 and d @ d < best_norm:
                best, best_norm = d, d @ d
    return best


def test_the_batched_qp_is_the_nearest_feasible_input_of_every_active_set() -> None:
    """On 300 random 2-input QPs with up to 20 rows: the same answer as a plain loop over
    the active sets, to 1e-9, whenever a feasible one exists."""
    rng = np.random.default_rng(7)
    lb, ub = np.full(2, -3.0), np.full(2, 3.0)
    checked = 0
    for _ in range(300):
        m = int(rng.integers(1, 21))
        A = rng.normal(size=(m, 2))
        b = rng.normal(size=m) - 1.0  # most sets feasible within the box
        ref = _nearest_by_loop(A, b, lb, ub)
        d, code = SafetyFilter._qp(A, b, lb, ub)
        if ref is None:
            assert code == 2
            continue
        checked += 1
        assert code == 1
        np.testing.assert_allclose(d, ref, rtol=0, atol=1e-9)
    assert checked > 100


def test_the_filter_changes_the_input_that_collides_and_the_run_does_not(run_cfg) -> None:
    """On a layout where the net alone touches a wall (zumo_random seed 2, at its fourth
    step), the filter modifies inputs and the run keeps its distance; every applied input
    keeps the condition on the model's next state, not linearized, to round-off, as the
    summary counts."""
    alone, _ = run_cfg(["+experiment=zumo_nn", "scenario=zumo_random", "seed=2"], name="a")
    assert alone.summary["status"] == "collision"
    res, _ = run_cfg(["+experiment=zumo_nn", "scenario=zumo_random", "seed=2",
                      "+safety_filter=cbf"], name="b")
    s = res.summary
    assert s["status"] != "collision" and s["min_clearance_m"] > 0
    assert s["safety_filter_modified"] > 0
    short = res.steps["safety_filter_shortfall"].dropna()
    assert s["safety_filter_shortfalls"] == int((short > SHORTFALL_TOL).sum())
    assert short.max() < SHORTFALL_TOL  # inputs on the linearized boundary: round-off only
    assert s["safety_filter_unkept"] == 0 and s["safety_filter_shortfalls"] == 0
