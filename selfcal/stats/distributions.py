"""The test distributions of the adjustment's statistics (normal, chi, chi², Student's t, Fisher's F, non-central
chi²), as the few tail and quantile functions the tests use, on ``scipy.special``'s cumulative distribution
functions.

Why not ``scipy.stats``: importing it costs 0.5-0.8 s in every ``selfcal`` process (its 100-odd distributions are
built at import), which a one-second adjustment cannot hide (issue 45: no step silent for more than 2 s); the same
numbers come from the special functions below it, which the sparse solvers have loaded already. Every function
takes arrays as NumPy does and equals ``scipy.stats``' own to the last digits (tests/test_distributions.py).
"""
from __future__ import annotations

import numpy as np
from scipy import special


def normal_sf(x):
    """P(N(0, 1) > x)."""
    return special.ndtr(-np.asarray(x, float))


def normal_ppf(q):
    """The quantile of N(0, 1) at probability q."""
    return special.ndtri(q)


def chi2_sf(x, dof):
    """P(chi²(dof) > x)."""
    return special.chdtrc(dof, x)


def chi2_isf(alpha, dof):
    """The critical value of chi²(dof) exceeded with probability alpha."""
    return special.chdtri(dof, alpha)


def chi2_ppf(q, dof):
    """The quantile of chi²(dof) at probability q."""
    return 2.0 * special.gammaincinv(0.5 * np.asarray(dof, float), q)


def chi_cdf(x, dof):
    """P(chi(dof) <= x): the distribution of the length of a dof-dimensional standard normal vector."""
    x = np.asarray(x, float)
    return special.chdtr(dof, x * x)


def chi_ppf(q, dof):
    """The quantile of chi(dof) at probability q."""
    return np.sqrt(chi2_ppf(q, dof))


def t_sf(x, dof):
    """P(t(dof) > x)."""
    return special.stdtr(dof, -np.asarray(x, float))


def t_isf(alpha, dof):
    """The critical value of Student's t(dof) exceeded with probability alpha."""
    return -special.stdtrit(dof, alpha)


def f_ppf(q, dof_num, dof_den):
    """The quantile of Fisher's F(dof_num, dof_den) at probability q."""
    return special.fdtri(dof_num, dof_den, q)


def ncx2_sf(x, dof, noncentrality):
    """P(chi²(dof, noncentrality) > x): the power of a chi² test whose alternative shifts the statistic's mean by
    the non-centrality."""
    return 1.0 - special.chndtr(x, dof, noncentrality)
