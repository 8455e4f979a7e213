"""The few distribution functions a fit needs, without importing scipy.

``scipy.stats`` takes 0.9–1.3 s to import on the 2-core station PC and ``scipy.special``
0.3–0.7 s, more than a whole 150-pose fit; ``identify fit`` needs only a χ² median (the χ²
check) and the quantiles of the confidence bands.  These are computed here from the
regularised incomplete gamma function (series and continued fraction, relative accuracy
~1e-14) and the standard library's normal distribution; ``tests/identify/test_distributions.py``
checks them against ``scipy.stats``.  Anything more (t, F, linear regression) still uses
scipy, imported where it is used.
"""

from __future__ import annotations

import math
from functools import lru_cache
from statistics import NormalDist

_EPS = 1e-15
_TINY = 1e-300


def gamma_p(a: float, x: float) -> float:
    """Regularised lower incomplete gamma ``P(a, x)`` (``a > 0``, ``x ≥ 0``)."""
    if a <= 0:
        raise ValueError(f"gamma_p: a must be > 0, got {a}")
    if x <= 0:
        return 0.0
    log_pre = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1.0:  # series
        term = total = 1.0 / a
        ap = a
        for _ in range(10_000):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        return min(1.0, total * math.exp(log_pre))
    # continued fraction for Q (modified Lentz)
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return max(0.0, 1.0 - math.exp(log_pre) * h)


def chi2_cdf(x: float, dof: float) -> float:
    """``P(χ²_dof ≤ x)``."""
    return gamma_p(dof / 2.0, x / 2.0)


@lru_cache(maxsize=256)
def chi2_ppf(p: float, dof: float) -> float:
    """Quantile of the χ² distribution: ``x`` with ``P(χ²_dof ≤ x) = p`` (bisection, relative 1e-13)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"chi2_ppf: p must be in (0, 1), got {p}")
    lo, hi = 0.0, dof + 10.0 * math.sqrt(2.0 * dof) + 50.0
    while chi2_cdf(hi, dof) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, dof) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


def chi2_median(dof: float) -> float:
    """Median of the χ² distribution with ``dof`` degrees of freedom."""
    return chi2_ppf(0.5, dof)


def norm_ppf(p: float) -> float:
    """Quantile of the standard normal distribution."""
    return NormalDist().inv_cdf(p)
