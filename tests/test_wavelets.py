"""Scaling functions and wavelets: orthonormality, partition of unity, refinement, supports."""
import numpy as np
import pytest

from selfcal.wavelets import TRUNCATION, get_wavelet
from selfcal.wavelets._tables import LEVEL

NAMES = ["db2", "db4", "db8", "sym4", "sym8", "meyer", "bl2", "bl4"]
STEP = 2.0 ** -LEVEL


def _inner(a, b, shift_units):
    """integral a(x) b(x - k) dx on the common table grid (Riemann sum, step 2^-12)."""
    s = int(round(shift_units / STEP))
    n = len(a)
    if abs(s) >= n:
        return 0.0
    if s >= 0:
        return float(np.sum(a[s:] * b[: n - s]) * STEP)
    return float(np.sum(a[: n + s] * b[-s:]) * STEP)


@pytest.mark.parametrize("name", NAMES)
def test_integer_translates_are_orthonormal(name):
    w = get_wavelet(name)
    # db2 is only Hoelder-0.55 smooth: the Riemann sum on the table converges slowly, still < 1e-6
    for k in range(-6, 7):
        assert _inner(w.phi_table, w.phi_table, k) == pytest.approx(float(k == 0), abs=1e-6)
        assert _inner(w.psi_table, w.psi_table, k) == pytest.approx(float(k == 0), abs=5e-6)
        assert abs(_inner(w.phi_table, w.psi_table, k)) < 1e-6


@pytest.mark.parametrize("name", NAMES)
def test_partition_of_unity(name):
    w = get_wavelet(name)
    t = np.random.default_rng(1).uniform(-3, 3, 500)
    total = sum(w.phi(t + k) for k in range(-40, 41))
    # exact at table points; linear interpolation between them costs < 1e-6
    assert np.max(np.abs(total - 1.0)) < 1e-6


@pytest.mark.parametrize("name", ["db4", "sym4", "db8"])
def test_refinement_equation_holds_off_the_dyadic_points(name):
    import pywt
    w = get_wavelet(name)
    h = np.array(pywt.Wavelet(name).rec_lo)
    t = np.random.default_rng(2).uniform(0, 2 * len(h) - 2, 400) / 2 + 1e-5
    rhs = np.sqrt(2) * sum(hk * w.phi(2 * t - k) for k, hk in enumerate(h))
    assert np.max(np.abs(w.phi(t) - rhs)) < 5e-4        # interpolation of a function of limited smoothness


def test_known_values_and_supports():
    db4 = get_wavelet("db4")
    assert db4.phi(0.0) == pytest.approx(0.0, abs=1e-12) and db4.phi(7.0) == 0.0
    assert float(db4.phi(1.0)) == pytest.approx(1.0071699777256, abs=1e-9)   # eigenvector value phi(1) of db4
    # Meyer and BL are symmetric about 0; their truncation follows the stated thresholds
    for name in ("meyer", "bl4"):
        w = get_wavelet(name)
        t = np.linspace(0.1, 6, 50)
        np.testing.assert_allclose(w.phi(t), w.phi(-t), atol=1e-12)
        peak = np.abs(w.phi_table).max()
        lo, hi = w.support
        assert abs(w.phi(hi + 0.01)) < w.threshold * peak <= abs(w.phi(hi - 0.01)) + 1e-12
        assert w.threshold == TRUNCATION[w.family]


def test_unknown_names_are_rejected():
    with pytest.raises(ValueError, match="unknown wavelet"):
        get_wavelet("haar2")
    with pytest.raises(ValueError, match="PyWavelets has no"):
        get_wavelet("db99")


@pytest.mark.parametrize("name", ["db4", "sym4", "meyer", "bl4"])
def test_evaluation_gives_np_interp_bits(name):
    """phi, psi and their derivatives find each point's interval by index arithmetic: the values are np.interp's
    to the last bit, also at the table's nodes, one ulp either side of them, outside the table and in any
    shape."""
    w = get_wavelet(name)
    rng = np.random.default_rng(7)
    x = w.x
    t = np.concatenate([rng.uniform(x[0] - 2, x[-1] + 2, 200_000), x[::7], x[::7] + STEP / 3,
                        np.nextafter(x[::7], -np.inf), np.nextafter(x[::7], np.inf), x[[0, -1]],
                        rng.uniform(-1, 1, 20_000) * STEP, [np.inf, -np.inf]])
    for function, table in ((w.phi, w.phi_table), (w.psi, w.psi_table), (w.dphi, w.dphi_table),
                            (w.dpsi, w.dpsi_table)):
        want = np.interp(t, x, table, left=0.0, right=0.0)
        np.testing.assert_array_equal(function(t), want)
        np.testing.assert_array_equal(function(t[:12].reshape(3, 4)), want[:12].reshape(3, 4))
        assert function(float(t[5])) == want[5]
