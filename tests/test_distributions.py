"""selfcal.stats.distributions against scipy.stats: the same tails and quantiles over the ranges the tests use."""
import numpy as np
import pytest
from scipy import stats

from selfcal.stats import distributions as d


@pytest.mark.parametrize("dof", [1, 2, 3, 7, 40, 2500.5])
def test_chi2_chi_and_t_equal_scipy_stats(dof):
    x = np.array([1e-3, 0.5, 1.0, 3.0, 7.8, 30.0, 200.0])
    alpha = np.array([1e-9, 1e-4, 0.001, 0.05, 0.5, 0.95])
    np.testing.assert_allclose(d.chi2_sf(x, dof), stats.chi2.sf(x, dof), rtol=1e-10, atol=1e-300)
    np.testing.assert_allclose(d.chi2_isf(alpha, dof), stats.chi2.isf(alpha, dof), rtol=1e-10)
    np.testing.assert_allclose(d.chi2_ppf(1 - alpha, dof), stats.chi2.ppf(1 - alpha, dof), rtol=1e-10)
    np.testing.assert_allclose(d.chi_cdf(x, dof), stats.chi(dof).cdf(x), rtol=1e-10, atol=1e-300)
    np.testing.assert_allclose(d.chi_ppf(alpha, dof), stats.chi(dof).ppf(alpha), rtol=1e-9)
    np.testing.assert_allclose(d.t_sf(x, dof), stats.t.sf(x, dof), rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(d.t_isf(alpha, dof), stats.t.isf(alpha, dof), rtol=1e-9)


def test_normal_f_and_noncentral_chi2_equal_scipy_stats():
    x = np.array([-4.0, -1.96, 0.0, 1.0, 3.29, 8.0])
    q = np.array([1e-6, 0.025, 0.5, 0.8, 0.95, 0.999])
    np.testing.assert_allclose(d.normal_sf(x), stats.norm.sf(x), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(d.normal_ppf(q), stats.norm.ppf(q), rtol=1e-12)
    for num, den in [(1, 5), (3, 100), (7, 80_000), (40, 1e6)]:
        np.testing.assert_allclose(d.f_ppf(q, num, den), stats.f.ppf(q, num, den), rtol=1e-8)
    for dof, nc in [(2, 0.5), (3, 10.0), (14, 25.0)]:
        crit = stats.chi2.isf(0.001, dof)
        np.testing.assert_allclose(d.ncx2_sf(crit, dof, nc), stats.ncx2.sf(crit, dof, nc), rtol=1e-8)


def test_the_adjustment_loads_no_scipy_stats():
    """The engine's import chain (the command's start-up) leaves scipy.stats out: 0.5-0.8 s of every process."""
    import subprocess
    import sys
    code = ("import sys, selfcal.workflows.adjust, selfcal.io, selfcal.stats; "
            "print(sorted(m for m in sys.modules if m.startswith('scipy.stats')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
