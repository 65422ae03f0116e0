"""The exact binomial interval against its definition and known values."""

from __future__ import annotations

import math

import pytest
from scipy.special import betaincinv
from scipy.stats import binom

from mpclab.record.stats import clopper_pearson

CASES = [(0, 10), (3, 10), (10, 10), (50, 50), (37, 50), (1, 1000), (500, 1000), (4000, 5000)]


@pytest.mark.parametrize("k, n", CASES)
def test_bounds_meet_the_tail_probabilities(k, n):
    lo, hi = clopper_pearson(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0
    # the defining equations: P(X >= k | lo) = 2.5 %, P(X <= k | hi) = 2.5 %
    if k > 0:
        assert binom.sf(k - 1, n, lo) == pytest.approx(0.025, rel=1e-6)
    if k < n:
        assert binom.cdf(k, n, hi) == pytest.approx(0.025, rel=1e-6)


@pytest.mark.parametrize("k, n", CASES)
def test_bounds_are_the_beta_quantiles(k, n):
    # the same interval as scipy's inverse of the regularized incomplete beta function
    lo, hi = clopper_pearson(k, n)
    assert lo == (0.0 if k == 0 else pytest.approx(betaincinv(k, n - k + 1, 0.025), rel=1e-10))
    assert hi == (1.0 if k == n else pytest.approx(betaincinv(k + 1, n - k, 0.975), rel=1e-10))


def test_all_successes_has_the_closed_form_lower_bound():
    lo, hi = clopper_pearson(50, 50)  # (alpha / 2) ** (1 / n)
    assert lo == pytest.approx(0.025 ** (1 / 50), rel=1e-9) and hi == 1.0


def test_no_trials_and_bad_counts():
    assert all(math.isnan(v) for v in clopper_pearson(0, 0))
    with pytest.raises(ValueError, match="within"):
        clopper_pearson(5, 3)


def test_robustness_rows_and_figure(tmp_path):
    import pandas as pd

    from mpclab.sweeps.robustness import plot_robustness, robustness_levels
    from mpclab.tables import group_table

    status = ["arrived"] * 5 + ["arrived", "timeout", "arrived", "stalled", "timeout"]
    df = pd.DataFrame({
        "backend": ["casadi"] * 10, "scenario": ["zumo_dead_end"] * 10, "status": status,
        "sim.timing.latency_scale": [1] * 5 + [10] * 5, "seed": list(range(10)),
        "arrival_time_s": [2.5, 2.6, 2.5, 2.5, 2.7, 3.0, None, 3.2, None, None],
        "run_dir": [str(tmp_path / f"run{i}") for i in range(10)],  # no step logs: no times
    })
    df.attrs["params"] = ["sim.timing.latency_scale", "seed"]
    assert robustness_levels(df) == ["sim.timing.latency_scale"]
    t = group_table(df).set_index("sim.timing.latency_scale")  # one row per level, seeds pooled
    assert t.loc[1, "success_rate"] == 1.0 and t.loc[10, "success_rate"] == 0.4
    assert (t.loc[10, "success_low"], t.loc[10, "success_high"]) == pytest.approx(
        clopper_pearson(2, 5))
    assert t.loc[10, "arrival_median_s"] == pytest.approx(3.1)
    path = plot_robustness(group_table(df), "sim.timing.latency_scale", tmp_path / "r.png")
    assert path.stat().st_size > 1000


@pytest.mark.parametrize("k, n, lo, hi", [
    (0, 1000, 0.0, 0.00368),     # the "rule of three" neighbourhood: 3.69 / n
    (3, 1000, 0.00062, 0.00874),
    (993, 1000, 0.98563, 0.99718),
])
def test_known_values(k, n, lo, hi):
    got = clopper_pearson(k, n)
    assert got == pytest.approx((lo, hi), abs=6e-6)


def test_collision_rate_beside_the_success_rate(tmp_path):
    import pandas as pd

    from mpclab.tables import group_table

    status = ["arrived"] * 6 + ["collision", "collision", "timeout", "stalled"]
    df = pd.DataFrame({
        "backend": ["casadi"] * 10, "scenario": ["zumo_random"] * 10, "status": status,
        "seed": list(range(10)), "arrival_time_s": [3.0] * 6 + [None] * 4,
        "min_clearance_m": [0.02, 0.03, 0.01, 0.05, 0.04, 0.02, -0.004, -0.001, 0.01, 0.02],
        "run_dir": [str(tmp_path / f"run{i}") for i in range(10)],
    })
    df.attrs["params"] = ["seed"]
    g = group_table(df).iloc[0]
    assert (g["runs"], g["arrived"], g["collisions"], g["timeouts"]) == (10, 6, 2, 1)
    assert g["collision_rate"] == pytest.approx(0.2)
    assert (g["collision_low"], g["collision_high"]) == pytest.approx(clopper_pearson(2, 10))
    assert (g["success_low"], g["success_high"]) == pytest.approx(clopper_pearson(6, 10))
    assert g["min_clearance_m"] == pytest.approx(-0.004)
