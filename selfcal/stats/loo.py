"""Leave-one-out validation of the control: each control point against the block adjusted without it.

Left out of the control, a ground control point is a check point of the other control: its error

    d_i = X_hat_(-i) - X_i            (the estimate without its surveyed coordinates minus those)

with the cofactor C_d = Q_(-i) + C_i (the estimate's, the survey's C_i = (W_i^T W_i)^-1; unit weight 1, the
a-priori precision Baarda's w-test of the control group uses). Per axis w = d / sigma_d is standard normal, and
the 3-D T = d^T C_d^-1 d is chi2(3) for a control point whose coordinates fit; a mis-surveyed or misidentified
target fails it.

For a linear model the deletion of the three observations of point i is a rank-3 downdate of the converged
adjustment (:func:`downdate`): with the whitened residual v_i = W_i (X_hat_i - X_i), the point's cofactor
Q_ii and Q_vv,i = I - W_i Q_ii W_i^T,

    d_i = W_i^-1 Q_vv,i^-1 v_i,        C_d = W_i^-1 Q_vv,i^-1 W_i^-T,        T = v_i^T Q_vv,i^-1 v_i.

The collinearity equations are not linear: on seed 000's block (27 control points 1.7 / 2.9 cm, 1:10,000) the
downdate misses the re-adjusted error by up to 2.3e-5 m, the re-linearisation's share (DESIGN-NOTES, "Leave-one-
out control validation"); the workflow (:mod:`selfcal.workflows.loo`) re-adjusts, and this module takes the
errors and cofactors it gives (:class:`LeaveOneOut`). Pure: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from .distributions import chi2_isf, chi2_sf, normal_sf

__all__ = ["LeaveOneOut", "downdate", "critical_t3"]


def critical_t3(critical_w: float) -> float:
    """The critical value of T ~ chi2(3) at the significance of Baarda's two-sided w-test with ``critical_w``
    (3.0: alpha 0.27 %, T 14.2)."""
    alpha = 2.0 * normal_sf(critical_w)
    return float(chi2_isf(alpha, 3))


def fully_controlled(W: np.ndarray) -> np.ndarray:
    """(n,) bool: control points whose whitening ``W`` (n, 3, 3) is finite and of full rank, i.e. controlled on
    all three axes (not a plan-only point, a radius-only ISIS constraint or a held point)."""
    W = np.asarray(W, float)
    ok = np.isfinite(W).all(axis=(1, 2))
    s = np.zeros((len(W), 3))
    s[ok] = np.linalg.svd(W[ok], compute_uv=False)
    return ok & (s[:, 2] > 1e-9 * np.maximum(s[:, 0], 1e-300))


def downdate(W: np.ndarray, Q_pp: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The linear leave-one-out prediction of control points (module docstring): ``W`` (n, 3, 3) their whitening
    (W^T W = C^-1), ``Q_pp`` (n, 3, 3) their cofactors in the adjustment with them, ``v`` (n, 3) X_hat - X in
    object units. Returns d (n, 3) and its cofactor C_d (n, 3, 3); NaN for a point whose coordinates nothing
    else determines (Q_vv singular)."""
    n = len(W)
    v_w = np.einsum("nij,nj->ni", W, v)
    Q_vv = np.eye(3) - np.einsum("nij,njk,nlk->nil", W, Q_pp, W)
    d = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    whole = fully_controlled(W)
    for k in range(n):
        if not whole[k] or np.linalg.eigvalsh(0.5 * (Q_vv[k] + Q_vv[k].T)).min() <= 1e-12:
            continue
        W_inv = np.linalg.inv(W[k])
        Q_inv = np.linalg.inv(Q_vv[k])
        d[k] = W_inv @ Q_inv @ v_w[k]
        cov[k] = W_inv @ Q_inv @ W_inv.T
    return d, cov


@dataclass
class LeaveOneOut:
    """Each control point's leave-one-out error and cofactor along ``axes`` (rows: east, north, up or the object
    frame's X, Y, Z), and the critical value of Baarda's w-test the adjustment used."""

    point_id: np.ndarray            # (n,)
    role: np.ndarray                # (n,) "gcp", or "demoted": checked instead by the tests (its error is direct)
    d_m: np.ndarray                 # (n, 3) X_hat without it - surveyed, along axes; NaN where not determined
    cov_m2: np.ndarray              # (n, 3, 3) its cofactor (estimate + survey, unit weight 1), along axes
    critical_w: float
    method: str = "re-adjustment"   # how d was found (every point re-adjusted from the converged estimate)
    seconds: float | None = None    # what finding them took
    linear_gap_m: float | None = None   # the largest difference of the linear downdate from the re-adjusted d

    def __len__(self) -> int:
        return len(self.point_id)

    @property
    def sigma_m(self) -> np.ndarray:
        """(n, 3) the a-priori sigma of d per axis."""
        var = np.einsum("nii->ni", self.cov_m2)
        return np.sqrt(np.where(var > 0, var, np.nan))

    @property
    def w(self) -> np.ndarray:
        """(n, 3) d standardised per axis."""
        return self.d_m / self.sigma_m

    @property
    def t3(self) -> np.ndarray:
        """(n,) the 3-D statistic d^T C_d^-1 d (chi2(3) where the coordinates fit); NaN where not determined."""
        out = np.full(len(self), np.nan)
        for k in np.flatnonzero(np.all(np.isfinite(self.d_m), axis=1)):
            out[k] = float(self.d_m[k] @ np.linalg.solve(self.cov_m2[k], self.d_m[k]))
        return out

    @property
    def p(self) -> np.ndarray:
        """(n,) P(chi2(3) > T): the probability of so large an error for coordinates that fit."""
        return chi2_sf(self.t3, 3)

    @property
    def critical_t3(self) -> float:
        return critical_t3(self.critical_w)

    @property
    def fails(self) -> np.ndarray:
        """(n,) bool: T above :attr:`critical_t3`."""
        t = self.t3
        return np.isfinite(t) & (np.nan_to_num(t) > self.critical_t3)

    def worst(self) -> int | None:
        """The index of the largest T (None without a determined point)."""
        t = self.t3
        return None if not np.isfinite(t).any() else int(np.nanargmax(t))
