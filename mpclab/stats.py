"""Small statistics the tables report: exact binomial intervals for success rates."""

from __future__ import annotations

from mpclab.lazy import lazy_import

# the beta distribution's quantile comes from scipy.special (scipy.stats is slow to import),
# loaded at the first interval: a run that makes none does not import scipy
special = lazy_import("scipy.special")


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
    lo = 0.0 if k == 0 else float(special.betaincinv(k, n - k + 1, alpha / 2))
    hi = 1.0 if k == n else float(special.betaincinv(k + 1, n - k, 1 - alpha / 2))
    return lo, hi
