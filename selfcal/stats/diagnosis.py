"""Diagnosis of what an adjustment left systematic: a residual field over the image, a dome in the heights.

Two tests, each with the size of the error it detects with 80 % power (its power stated, not only its verdict):

* **Residual field** (:func:`residual_field_test`): the image is cut into a grid of zones; in each, the mean
  residual vector of the kept observations. Under a right model a residual has the variance
  ``s^2 sigma_i^2 r_i`` (``sigma_i`` its a-priori sigma, ``r_i`` its redundancy number, ``s^2`` the variance factor
  estimated from the same residuals), so a zone mean has ``sum(s^2 sigma_i^2 r_i) / n^2`` per axis and
  ``T = sum over zones and axes of mean^2 / variance`` is chi^2 with 2K degrees of freedom (the residuals taken as
  independent; the model's own parameters absorb a share of any field, which makes the test conservative). A
  field is *found* when T exceeds its critical value **and** the largest zone mean is at least
  :data:`PRACTICAL_FIELD_PX`: at 70 000 observations a 0.02 px field is significant without mattering. Moran's I of
  the standardised zone means over rook neighbours (a permutation p-value) says whether the field is smooth over
  the image (a lens) or scattered (noise, blunders).
* **Dome** (:func:`dome_test`): the check points' height errors fitted by ``dZ = a + b r^2`` (``r`` the distance
  from the block's centre, least squares, unit weights), ``b`` tested by Student's t with n - 2 degrees of freedom:
  the doming a radial distortion error leaves in a nadir block whose datum comes from camera positions or from
  control at its edge (James & Robson 2014, ESPL 39: 1413-1420). The dome's height is ``b r_max^2``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from .distributions import chi2_isf, chi2_sf, ncx2_sf, normal_ppf, t_isf, t_sf

__all__ = ["FieldTest", "DomeTest", "residual_field_test", "residual_field_tests", "dome_test", "findings", "ALPHA",
           "FIELD_GRIDS", "PRACTICAL_FIELD_PX"]

#: significance level of both tests (two-sided for the dome)
ALPHA = 0.001
#: power at which the detectable sizes are stated
POWER = 0.80
#: a residual field matters when a zone's mean residual reaches this (pixels)
PRACTICAL_FIELD_PX = 0.05
#: the grids of the field test: zones of about 1000 px (a field over the image) and 500 px (a local defect) on a
#: 6000 x 4000 px frame; each is tested at ALPHA / len(FIELD_GRIDS) and in each the two statistics at half that
FIELD_GRIDS = ((6, 4), (12, 8))
#: zones with fewer observations are left out of the field test (their mean is too noisy to see)
MIN_ZONE_OBSERVATIONS = 20
#: the dome test needs this many check points
MIN_DOME_POINTS = 6
#: permutations of Moran's I
PERMUTATIONS = 999


@dataclass(frozen=True)
class FieldTest:
    camera_id: str
    grid: tuple[int, int]
    n_zones: int                 # zones with enough observations
    statistic: float             # T, chi^2 with 2 n_zones degrees of freedom under a right model
    critical: float
    p_value: float
    largest_zone_statistic: float        # the largest zone's mean^2 / variance, chi^2(2) per zone
    largest_zone_critical: float         # at alpha / n_zones (Bonferroni: the largest of n_zones)
    largest_zone_mean_px: float  # length of the largest zone mean vector
    largest_zone: tuple[int, int]        # (column, row) of that zone in the grid
    rms_zone_mean_px: float
    detectable_rms_px: float     # RMS of a field the test finds with POWER
    morans_i: float | None
    morans_p: float | None
    found: bool

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class DomeTest:
    n_points: int
    b_per_m2: float              # dZ = a + b r^2
    sigma_b_per_m2: float
    t: float
    critical: float
    p_value: float
    radius_m: float              # r_max: the farthest check point from the centre
    dome_height_m: float         # b r_max^2
    sigma_dome_height_m: float
    detectable_height_m: float   # |b| r_max^2 the test finds with POWER
    found: bool

    def as_dict(self) -> dict:
        return asdict(self)


def _noncentrality(dof: int, alpha: float = ALPHA, power: float = POWER) -> float:
    """The non-centrality at which a chi^2(dof) test at ``alpha`` rejects with ``power``."""
    from scipy.optimize import brentq
    critical = chi2_isf(alpha, dof)
    return float(brentq(lambda lam: ncx2_sf(critical, dof, lam) - power, 1e-9, 1e6))


def _morans_i(values: np.ndarray, cells: np.ndarray, grid: tuple[int, int], rng) -> tuple[float | None, float | None]:
    """Moran's I of ``values`` (zones x 2, standardised) over rook neighbours, both axes pooled, and its
    permutation p-value (one-sided: a smooth field gives I > 0)."""
    gx, gy = grid
    n = len(cells)
    if n < 4:
        return None, None
    ix, iy = cells % gx, cells // gx
    w = ((np.abs(ix[:, None] - ix[None, :]) + np.abs(iy[:, None] - iy[None, :])) == 1).astype(float)
    if w.sum() == 0:
        return None, None

    z = values - values.mean(axis=0)
    scale = n / w.sum() / float(np.sum(z * z))
    observed = float(scale * np.sum(z * (w @ z)))
    shuffled = z[np.argsort(rng.random((PERMUTATIONS, n)), axis=1)]           # (permutations, n, 2)
    perms = scale * np.einsum("pik,pik->p", shuffled, np.einsum("ij,pjk->pik", w, shuffled))
    return observed, float((1 + np.sum(perms >= observed)) / (PERMUTATIONS + 1))


def residual_field_test(camera_id: str, col_px: np.ndarray, row_px: np.ndarray, v_px: np.ndarray,
                        sigma_px: np.ndarray, redundancy: np.ndarray, width_px: float, height_px: float,
                        grid: tuple[int, int] = (6, 4), alpha: float = ALPHA, seed: int = 0) -> FieldTest | None:
    """The residual-field test of one camera's kept observations on one grid (module docstring): ``v_px`` (n, 2)
    the residuals, ``sigma_px`` (n,) their a-priori sigmas, ``redundancy`` (n, 2) their redundancy numbers. Two
    statistics at ``alpha`` each: the sum over the zones (a field over the image) and the largest zone (a local
    defect, at alpha / zones). None where no zone has enough observations."""
    gx, gy = grid
    r = np.clip(np.asarray(redundancy, float), 1e-6, 1.0)
    var_unit = (np.asarray(sigma_px, float)[:, None] ** 2) * r                 # variance / s^2 per axis
    s2 = float(np.mean(v_px ** 2 / var_unit))                                  # the variance factor they show
    ix = np.clip((col_px / width_px * gx).astype(int), 0, gx - 1)
    iy = np.clip((row_px / height_px * gy).astype(int), 0, gy - 1)
    cell = iy * gx + ix
    count = np.bincount(cell, minlength=gx * gy)
    kept = np.flatnonzero(count >= MIN_ZONE_OBSERVATIONS)
    if len(kept) == 0:
        return None
    n_zone = count[kept, None].astype(float)
    mean = np.column_stack([np.bincount(cell, weights=v_px[:, k], minlength=gx * gy) for k in range(2)])[kept] / n_zone
    var = np.column_stack([np.bincount(cell, weights=s2 * var_unit[:, k], minlength=gx * gy)
                           for k in range(2)])[kept] / n_zone ** 2
    per_zone = np.sum(mean ** 2 / var, axis=1)
    statistic = float(np.sum(per_zone))
    dof = 2 * len(kept)
    length = np.hypot(mean[:, 0], mean[:, 1])
    worst = int(np.argmax(length))
    detectable = float(np.sqrt(2.0 * _noncentrality(dof, alpha) / np.sum(1.0 / var)))  # vector RMS, equal axes
    critical = float(chi2_isf(alpha, dof))
    zone_critical = float(chi2_isf(alpha / len(kept), 2))
    largest = int(np.argmax(per_zone))
    moran, moran_p = _morans_i(mean / np.sqrt(var), kept, grid, np.random.default_rng(seed))
    significant = statistic > critical or float(per_zone[largest]) > zone_critical
    found = significant and float(length[worst]) >= PRACTICAL_FIELD_PX
    return FieldTest(camera_id, (gx, gy), len(kept), statistic, critical, float(chi2_sf(statistic, dof)),
                     float(per_zone[largest]), zone_critical,
                     float(length[worst]), (int(kept[worst] % gx), int(kept[worst] // gx)),
                     float(np.sqrt(np.mean(length ** 2))), detectable, moran, moran_p, found)


def residual_field_tests(camera_id: str, col_px, row_px, v_px, sigma_px, redundancy, width_px: float,
                         height_px: float, grids=FIELD_GRIDS) -> list[FieldTest]:
    """:func:`residual_field_test` on each of ``grids`` (a 6000 x 4000 px frame's; others keep the zones' shape,
    scaled to the frame's aspect), the level shared so that the family of tests holds ALPHA."""
    out = []
    alpha = ALPHA / (2 * len(grids))
    for gx, gy in grids:
        gy = max(1, int(round(gx * height_px / width_px)))
        test = residual_field_test(camera_id, col_px, row_px, v_px, sigma_px, redundancy, width_px, height_px,
                                   (gx, gy), alpha)
        if test is not None:
            out.append(test)
    return out


def dome_test(xy_m: np.ndarray, dz_m: np.ndarray, centre_xy_m: np.ndarray) -> DomeTest | None:
    """The dome test of the check points' height errors ``dz_m`` at ``xy_m`` (n, 2) about ``centre_xy_m``
    (module docstring); None below :data:`MIN_DOME_POINTS` points."""
    n = len(dz_m)
    if n < MIN_DOME_POINTS:
        return None
    r2 = np.sum((np.asarray(xy_m, float) - centre_xy_m) ** 2, axis=1)
    a = np.column_stack([np.ones(n), r2])
    coef, *_ = np.linalg.lstsq(a, dz_m, rcond=None)
    e = dz_m - a @ coef
    dof = n - 2
    s2 = float(e @ e / dof)
    q = np.linalg.inv(a.T @ a)
    sigma_b = float(np.sqrt(s2 * q[1, 1]))
    b = float(coef[1])
    t = b / sigma_b if sigma_b > 0 else 0.0
    critical = float(t_isf(ALPHA / 2, dof))
    # the shift of t at which |t| > critical with POWER (t's critical value plus the normal quantile of the power:
    # the non-central t's own quantiles fail numerically at a few points and differ little)
    delta = critical + float(normal_ppf(POWER))
    r_max2 = float(np.max(r2))
    return DomeTest(n, b, sigma_b, t, critical, float(2 * t_sf(abs(t), dof)), float(np.sqrt(r_max2)),
                    b * r_max2, sigma_b * r_max2, delta * sigma_b * r_max2, abs(t) > critical)


def findings(fields: list[FieldTest], dome: DomeTest | None, oblique: bool | None = None) -> list[str]:
    """Sentences naming what the tests found, its likely cause and the remedy (or what they could have found)."""
    out: list[str] = []
    if dome is not None and dome.found:
        shape = "dome" if dome.b_per_m2 < 0 else "bowl"
        out.append(f"the check points' heights form a {shape} ({dome.dome_height_m:+.3f} ± "
                   f"{dome.sigma_dome_height_m:.3f} m at {dome.radius_m:.0f} m from the centre, t = {dome.t:.1f}): "
                   f"a radial distortion error that the block's geometry cannot tell from the heights (James & "
                   f"Robson 2014); remedy: add oblique or convergent images, a GCP near the centre of the block, or "
                   f"hold the radial terms from an independent calibration")
    for f in fields:
        if f.found:
            smooth = f.morans_p is not None and f.morans_p < 0.01
            out.append(f"camera '{f.camera_id}': the image residuals keep a {'smooth ' if smooth else ''}field "
                       f"(zone means up to {f.largest_zone_mean_px:.2f} px at zone {f.largest_zone} of "
                       f"{f.grid[0]}x{f.grid[1]}, T = {f.statistic:.0f} against {f.critical:.0f}, largest zone "
                       f"{f.largest_zone_statistic:.0f} against {f.largest_zone_critical:.0f}"
                       + (f", Moran's I {f.morans_i:.2f}" if f.morans_i is not None else "") + "): "
                       + ("the AP model does not represent the lens; remedy: another AP model (a wavelet AP on a "
                          "finer grid), or APs per strip or per flight" if smooth else
                          "a scattered field: look for blunders or a poorly matched image area"))
    if not out:
        parts = []
        if fields:
            parts.append(f"an image residual field of RMS {max(f.detectable_rms_px for f in fields):.3f} px")
        if dome is not None:
            parts.append(f"a dome of {dome.detectable_height_m:.3f} m")
        if parts:
            out.append("no systematic error found; the tests would find " + " or ".join(parts)
                       + f" with {POWER:.0%} power at α = {ALPHA:g}")
    return out
