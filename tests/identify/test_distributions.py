"""The χ² and normal quantiles the fit uses without scipy, checked against scipy.stats."""

from __future__ import annotations

import pytest
from scipy import stats

from quickhealth.identify.distributions import chi2_cdf, chi2_median, chi2_ppf, norm_ppf


@pytest.mark.parametrize("dof", [1, 2, 3, 5, 7, 40, 500, 1500, 6000])
@pytest.mark.parametrize("p", [0.001, 0.05, 0.5, 0.95, 0.999])
def test_chi2_quantiles_match_scipy(dof: int, p: float) -> None:
    assert chi2_ppf(p, dof) == pytest.approx(stats.chi2.ppf(p, dof), rel=1e-9)
    x = stats.chi2.ppf(p, dof)
    assert chi2_cdf(x, dof) == pytest.approx(p, rel=1e-9, abs=1e-12)


def test_median_and_normal_quantile() -> None:
    assert chi2_median(861) == pytest.approx(stats.chi2.median(861), rel=1e-10)
    for p in (0.025, 0.5, 0.975):
        assert norm_ppf(p) == pytest.approx(stats.norm.ppf(p), rel=1e-12, abs=1e-15)
    with pytest.raises(ValueError):
        chi2_ppf(1.0, 3)
