"""The exact binomial interval against its definition and known values."""

from __future__ import annotations

import math

import pytest
from scipy.stats import binom

from mpclab.stats import clopper_pearson


@pytest.mark.parametrize("k, n", [(0, 10), (3, 10), (10, 10), (50, 50), (37, 50), (1, 1000)])
def test_bounds_meet_the_tail_probabilities(k, n):
    lo, hi = clopper_pearson(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0
    # the defining equations: P(X >= k | lo) = 2.5 %, P(X <= k | hi) = 2.5 %
    if k > 0:
        assert binom.sf(k - 1, n, lo) == pytest.approx(0.025, rel=1e-6)
    if k < n:
        assert binom.cdf(k, n, hi) == pytest.approx(0.025, rel=1e-6)


def test_all_successes_has_the_closed_form_lower_bound():
    lo, hi = clopper_pearson(50, 50)  # (alpha / 2) ** (1 / n)
    assert lo == pytest.approx(0.025 ** (1 / 50), rel=1e-9) and hi == 1.0


def test_no_trials_and_bad_counts():
    assert all(math.isnan(v) for v in clopper_pearson(0, 0))
    with pytest.raises(ValueError, match="within"):
        clopper_pearson(5, 3)
