"""Scaling functions and wavelets tabulated on a fine dyadic grid.

* Daubechies (dbN) and Symlets (symN): exact values at the dyadic points
  k / 2^J from the refinement equation phi(x) = sqrt(2) sum_k h_k phi(2x - k)
  (integer values from its eigenvector, then level by level), filters h from
  PyWavelets; psi(x) = sqrt(2) sum_k g_k phi(2x - k).
* Meyer and Battle-Lemarié (blN): from their Fourier transforms, sampled on
  a fine frequency grid and transformed back with an FFT.

Between the table points the functions are interpolated linearly (the tables
hold 2^12 points per unit, so the interpolation error is below 1e-6).
"""
from __future__ import annotations

import numpy as np

__all__ = ["daubechies_tables", "meyer_tables", "battle_lemarie_tables", "LEVEL"]

#: tables hold 2**LEVEL points per unit
LEVEL = 12


def daubechies_tables(h: np.ndarray, g: np.ndarray, level: int = LEVEL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """phi and psi of an orthogonal compactly supported family on [0, len(h) - 1].

    Returns x, phi, psi with x = i / 2**level.
    """
    h = np.asarray(h, float)
    g = np.asarray(g, float)
    L = len(h)
    n = L - 1                      # support [0, n]
    # integer values: phi(m) = sqrt(2) sum_k h_k phi(2m - k), m = 0..n
    A = np.zeros((n + 1, n + 1))
    for m in range(n + 1):
        for k in range(L):
            j = 2 * m - k
            if 0 <= j <= n:
                A[m, j] += np.sqrt(2.0) * h[k]
    w, V = np.linalg.eig(A)
    vec = np.real(V[:, np.argmin(np.abs(w - 1.0))])
    phi = vec / vec.sum()
    # refine: level j grid has n * 2**j + 1 points
    for j in range(1, level + 1):
        step = 2 ** (j - 1)
        size = n * 2**j + 1
        new = np.zeros(size)
        idx = np.arange(size)
        for k in range(L):
            src = idx - k * step
            ok = (src >= 0) & (src < len(phi))
            new[ok] += np.sqrt(2.0) * h[k] * phi[src[ok]]
        phi = new
    x = np.arange(len(phi)) / 2.0**level
    # psi(y) = sqrt(2) sum_k g_k phi(2y - k) on the same grid: index 2i - k 2**level
    psi = np.zeros_like(phi)
    idx = np.arange(len(phi))
    for k in range(L):
        src = 2 * idx - k * 2**level
        ok = (src >= 0) & (src < len(phi))
        psi[ok] += np.sqrt(2.0) * g[k] * phi[src[ok]]
    return x, phi, psi


def _meyer_nu(t: np.ndarray) -> np.ndarray:
    """The auxiliary function nu of Daubechies (1992, eq. 4.2.4): nu(t) = t^4 (35 - 84 t + 70 t^2 - 20 t^3) on [0, 1]."""
    t = np.clip(t, 0.0, 1.0)
    return t**4 * (35 - 84 * t + 70 * t**2 - 20 * t**3)


def _inverse_fourier(spectrum_fn, half_width: float, level: int):
    """f(x) = (1/2pi) int F(w) e^{iwx} dw sampled at x = i / 2**level, |x| < half_width, by an FFT."""
    per_unit = 2**level
    n = int(2 * half_width * per_unit)
    n += n % 2
    dx = 1.0 / per_unit
    w = 2 * np.pi * np.fft.fftfreq(n, d=dx)
    F = spectrum_fn(w)
    f = np.fft.ifft(F).real / dx
    f = np.fft.fftshift(f)
    x = (np.arange(n) - n // 2) * dx
    return x, f


def meyer_tables(level: int = LEVEL, half_width: float = 32.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Meyer's phi (symmetric about 0) and psi (symmetric about 1/2) on x = i / 2**level."""
    def phi_hat(w):
        a = np.abs(w)
        out = np.where(a <= 2 * np.pi / 3, 1.0, 0.0)
        band = (a > 2 * np.pi / 3) & (a <= 4 * np.pi / 3)
        out = np.where(band, np.cos(np.pi / 2 * _meyer_nu(3 * a / (2 * np.pi) - 1)), out)
        return out.astype(complex)

    def psi_hat(w):
        a = np.abs(w)
        out = np.zeros_like(a)
        b1 = (a > 2 * np.pi / 3) & (a <= 4 * np.pi / 3)
        b2 = (a > 4 * np.pi / 3) & (a <= 8 * np.pi / 3)
        out = np.where(b1, np.sin(np.pi / 2 * _meyer_nu(3 * a / (2 * np.pi) - 1)), out)
        out = np.where(b2, np.cos(np.pi / 2 * _meyer_nu(3 * a / (4 * np.pi) - 1)), out)
        return np.exp(-0.5j * w) * out

    x, phi = _inverse_fourier(phi_hat, half_width, level)
    _, psi = _inverse_fourier(psi_hat, half_width, level)
    return x, phi, psi


def _bspline_hat(w: np.ndarray, order: int) -> np.ndarray:
    """Fourier transform of the centred cardinal B-spline of ``order`` (degree order - 1)."""
    half = w / 2.0
    return np.sinc(half / np.pi) ** order


def _bspline_autocorrelation(w: np.ndarray, order: int, terms: int = 2000) -> np.ndarray:
    """sum_k |B_hat(w + 2 pi k)|^2 (2pi-periodic), evaluated once per distinct residue of w mod 2pi.

    The terms fall like (2 / (2 pi k))^(2 order); 2000 terms leave a tail below 1e-16 for order >= 2.
    """
    wr = np.mod(w + np.pi, 2 * np.pi) - np.pi
    residues, inverse = np.unique(np.round(wr, 13), return_inverse=True)
    k = np.arange(-terms, terms + 1)
    total = np.sum(_bspline_hat(residues[:, None] + 2 * np.pi * k[None, :], order) ** 2, axis=1)
    return total[inverse.reshape(wr.shape)]


def battle_lemarie_tables(order: int, level: int = LEVEL, half_width: float = 32.0
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Battle-Lemarié phi (symmetric about 0) and psi of spline order ``order``.

    phi_hat = B_hat / sqrt(sum_k |B_hat(w + 2 pi k)|^2) with the centred B-spline
    B of ``order`` (Mallat 1989; Daubechies 1992, §5.4); psi_hat(w) =
    e^{-iw/2} conj(m0(w/2 + pi)) phi_hat(w/2) with m0(w) = phi_hat(2w) / phi_hat(w).
    """
    def phi_hat(w):
        return _bspline_hat(w, order) / np.sqrt(_bspline_autocorrelation(w, order))

    def psi_hat(w):
        half = w / 2.0
        shifted = half + np.pi
        with np.errstate(divide="ignore", invalid="ignore"):
            m0 = phi_hat(2 * shifted) / phi_hat(shifted)
        # m0 is 2pi-periodic and continuous; where phi_hat(shifted) vanishes use the periodic copy
        bad = ~np.isfinite(m0)
        if np.any(bad):
            alt = np.mod(shifted[bad] + np.pi, 2 * np.pi) - np.pi
            m0[bad] = phi_hat(2 * alt) / phi_hat(alt)
        return np.exp(-0.5j * w) * np.conj(m0) * phi_hat(half)

    x, phi = _inverse_fourier(phi_hat, half_width, level)
    _, psi = _inverse_fourier(psi_hat, half_width, level)
    return x, phi, psi
