"""Small statistics the tables report: exact binomial intervals for success rates, and a
bootstrap interval for a mean (BARN's score).

The Clopper-Pearson bounds are the success probabilities at which the observed count sits at
a binomial tail of ``(1 - level) / 2``; for whole counts that tail is a finite sum, solved here
for the probability by bisection to double precision. (scipy's beta quantile gives the same
numbers, ``tests/test_stats.py``, but importing scipy.special costs the end of every sweep
about 0.3 s.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def clopper_pearson(successes: int, trials: int, level: float = 0.95) -> tuple[float, float]:
    """The Clopper-Pearson (exact) interval of a success probability from ``successes`` of
    ``trials``: it covers the true rate with probability at least ``level`` for every rate.
    ``(nan, nan)`` without trials."""
    k, n = int(successes), int(trials)
    if not 0 <= k <= n:
        raise ValueError(f"successes must be within 0..trials, got {k} of {n}")
    if n == 0:
        return float("nan"), float("nan")
    alpha = 1.0 - float(level)
    # lower: P(X >= k | p) = alpha / 2; upper: P(X <= k | p) = alpha / 2, i.e.
    # P(X >= k + 1 | p) = 1 - alpha / 2; both tails rise with p
    lo = 0.0 if k == 0 else _tail_quantile(k, n, alpha / 2)
    hi = 1.0 if k == n else _tail_quantile(k + 1, n, 1 - alpha / 2)
    return lo, hi


def upper_tail(m: int, n: int, p: float) -> float:
    """``P(X >= m)`` for ``X ~ Binomial(n, p)``, summed in logs (no overflow for large n)
    over the shorter side (``1 - P(X < m)`` when that has fewer terms)."""
    if m <= 0 or p >= 1.0:
        return 1.0
    if m > n or p <= 0.0:
        return 0.0
    lp, lq, ln = math.log(p), math.log1p(-p), math.lgamma(n + 1)
    below = m < n - m + 1
    logs = [ln - math.lgamma(j + 1) - math.lgamma(n - j + 1) + j * lp + (n - j) * lq
            for j in (range(m) if below else range(m, n + 1))]
    top = max(logs)
    total = math.exp(top) * math.fsum(math.exp(v - top) for v in logs)
    return 1.0 - total if below else total


def _tail_quantile(m: int, n: int, target: float) -> float:
    """The ``p`` in (0, 1) with ``P(X >= m | p) = target`` (1 <= m <= n), by bisection."""
    lo, hi = 0.0, 1.0
    while True:
        mid = 0.5 * (lo + hi)
        if hi - lo <= 1e-15 * hi or mid in (lo, hi):  # about as precise as a double
            return mid
        if upper_tail(m, n, mid) < target:
            lo = mid
        else:
            hi = mid


def bootstrap_mean(
    values: Sequence[float], level: float = 0.95, resamples: int = 10_000, seed: int = 0,
) -> tuple[float, float]:
    """The percentile bootstrap interval of the mean of ``values``: the ``(1 - level) / 2``
    and ``(1 + level) / 2`` quantiles of the means of ``resamples`` resamples with
    replacement, drawn from a seeded generator (a table repeats exactly). ``(nan, nan)``
    without values; both ends the value for a single one."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)
