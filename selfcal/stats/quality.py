"""The quality check of an adjustment: a few figures of the result, each against a stated threshold, graded pass,
warn or fail (the traffic lights that open Pix4D's quality report, here for a bundle adjustment).

Each check is a pure function of numbers the adjustment produced (:mod:`selfcal.report.metrics` gathers them);
the thresholds are the module's constants below, each with its reason. A check that does not apply (no control
point, no focal length) is ``n/a``. The worst status of the checks is the block's.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

__all__ = ["PASS", "WARN", "FAIL", "NOT_APPLICABLE", "Check", "quality_checks", "worst_status",
           "IMAGES_ORIENTED_PASS", "IMAGES_ORIENTED_WARN", "POINTS_PER_IMAGE_PASS", "POINTS_PER_IMAGE_WARN",
           "RAYS_PER_POINT_PASS", "RAYS_PER_POINT_WARN", "FOCAL_CHANGE_PASS", "FOCAL_CHANGE_WARN",
           "SIGMA0_RATIO_PASS", "SIGMA0_RATIO_WARN", "REJECTED_SHARE_PASS", "REJECTED_SHARE_WARN",
           "GCP_RESIDUAL_PASS", "GCP_RESIDUAL_WARN", "CORRELATION_PASS", "CORRELATION_WARN"]

PASS, WARN, FAIL, NOT_APPLICABLE = "pass", "warn", "fail", "n/a"

#: share of the block's images oriented: every image (an image left out is a hole in the product); from 95 % a
#: warning (a few images at the block's edge or with too few points), below it a failure (a part of the block lost)
IMAGES_ORIENTED_PASS, IMAGES_ORIENTED_WARN = 1.0, 0.95
#: median number of points an image observes: 100 and more spread points sample a frame for self-calibration
#: (two to three per cell of a 9 × 6 AP grid); 20 still orient an image (the classical minimum is six) but
#: leave its distortion barely sampled
POINTS_PER_IMAGE_PASS, POINTS_PER_IMAGE_WARN = 100.0, 20.0
#: median number of images a tie point is seen in: three rays make a point's blunders detectable (two rays
#: have one redundant coordinate, and a blunder along the base goes unseen); fewer than two: no intersection
RAYS_PER_POINT_PASS, RAYS_PER_POINT_WARN = 3.0, 2.0
#: the largest relative change |c − c0| / c0 of a camera's focal length against its initial value: within 5 %
#: (Pix4D's quality report's bound for the camera optimisation) the initial calibration and the result agree;
#: up to 20 % a wrong or generic initial value; beyond it a wrong camera or a collapsed block
FOCAL_CHANGE_PASS, FOCAL_CHANGE_WARN = 0.05, 0.20
#: σ̂0 / σ0 (a-posteriori against a-priori sigma of unit weight): within a factor 2 the weights are right; a
#: factor 3 is a weighting to fix (sigma of the image points, of the control); beyond it the weights are wrong
#: and the tests (Baarda's w, the MDB) and every a-posteriori sigma with them
SIGMA0_RATIO_PASS, SIGMA0_RATIO_WARN = (0.5, 2.0), (1.0 / 3.0, 3.0)
#: share of the image observations rejected: matching leaves well under 1 % blunders; up to 5 % the cleaning
#: copes but the matching is poor; beyond it the rejections may hide a model error (a wrong camera, rolling shutter)
REJECTED_SHARE_PASS, REJECTED_SHARE_WARN = 0.01, 0.05
#: largest |residual| / a-priori sigma of a control coordinate: within 3 sigma (the 3-sigma rule); up to 5 a
#: point to look at; beyond it a wrong control point or a wrong sigma
GCP_RESIDUAL_PASS, GCP_RESIDUAL_WARN = 3.0, 5.0
#: largest |correlation| of an estimated camera parameter (interior orientation, AP) with any other unknown:
#: up to 0.99 the block separates the two; to 0.999 weakly (the classical case: c against the images' Z0 in a
#: flat block flown nadir at one height, 0.99 and more even with good control, which separates them through the
#: control heights alone); beyond 0.999 the block does not separate them and the estimate of the one is the other's
CORRELATION_PASS, CORRELATION_WARN = 0.99, 0.999


@dataclass(frozen=True)
class Check:
    """One row of the quality check: what is checked, its value (and the value as shown), the threshold stated
    in words, the status, and a detail (which camera, which point)."""

    key: str
    check: str
    value: float | None
    shown: str
    threshold: str
    status: str
    detail: str = ""

    def as_dict(self) -> dict:
        out = asdict(self)
        del out["key"]
        return out


def _grade(value: float | None, passes: Callable[[float], bool], warns: Callable[[float], bool]) -> str:
    if value is None or not np.isfinite(value):
        return NOT_APPLICABLE
    return PASS if passes(value) else WARN if warns(value) else FAIL


def worst_status(checks: list[Check]) -> str:
    """The worst status of ``checks`` (n/a only if every check is)."""
    statuses = {c.status for c in checks}
    for status in (FAIL, WARN, PASS):
        if status in statuses:
            return status
    return NOT_APPLICABLE


def _median(values) -> float | None:
    values = np.asarray(values, float)
    return float(np.median(values)) if values.size else None


def quality_checks(*, n_images: int, n_images_oriented: int, points_per_image, rays_per_point,
                   focal_change: tuple[float, str] | None, sigma0_ratio: float | None, n_rejected: int,
                   n_observations: int, gcp_ratio: tuple[float, str] | None,
                   camera_correlation: tuple[float, str] | None) -> list[Check]:
    """The checks of one adjustment.

    ``n_images`` the images of the block as read, ``n_images_oriented`` those the adjustment estimated;
    ``points_per_image`` (per oriented image) and ``rays_per_point`` (per tie point) counts of the kept
    observations; ``focal_change`` (largest |c − c0| / c0, its camera) or None (no focal length);
    ``sigma0_ratio`` σ̂0 / σ0; ``n_rejected`` of ``n_observations`` image observations rejected; ``gcp_ratio``
    (largest |residual| / sigma of a weighted control coordinate, its point and axis) or None (no weighted
    control); ``camera_correlation`` (largest |ρ| of an estimated camera parameter with another unknown, the two
    names) or None (no camera parameter estimated)."""
    share = n_images_oriented / n_images if n_images else None
    ppi, rpp = _median(points_per_image), _median(rays_per_point)
    rejected = n_rejected / n_observations if n_observations else None
    lo, hi = SIGMA0_RATIO_PASS
    wlo, whi = SIGMA0_RATIO_WARN
    focal, focal_camera = focal_change if focal_change else (None, "")
    gcp, gcp_point = gcp_ratio if gcp_ratio else (None, "")
    rho, rho_names = camera_correlation if camera_correlation else (None, "")

    def pct(x):
        return "–" if x is None else f"{100.0 * x:.1f} %"

    def num(x, spec):
        return "–" if x is None or not np.isfinite(x) else format(x, spec)
    return [
        Check("images_oriented", "images oriented", share, f"{pct(share)} ({n_images_oriented} of {n_images})",
              f"pass {IMAGES_ORIENTED_PASS:.0%}, warn ≥ {IMAGES_ORIENTED_WARN:.0%}",
              _grade(share, lambda x: x >= IMAGES_ORIENTED_PASS - 1e-12, lambda x: x >= IMAGES_ORIENTED_WARN)),
        Check("points_per_image", "points per image (median)", ppi, num(ppi, ".0f"),
              f"pass ≥ {POINTS_PER_IMAGE_PASS:g}, warn ≥ {POINTS_PER_IMAGE_WARN:g}",
              _grade(ppi, lambda x: x >= POINTS_PER_IMAGE_PASS, lambda x: x >= POINTS_PER_IMAGE_WARN)),
        Check("rays_per_point", "images per tie point (median)", rpp, num(rpp, ".1f"),
              f"pass ≥ {RAYS_PER_POINT_PASS:g}, warn ≥ {RAYS_PER_POINT_WARN:g}",
              _grade(rpp, lambda x: x >= RAYS_PER_POINT_PASS, lambda x: x >= RAYS_PER_POINT_WARN)),
        Check("camera_change", "focal length against its initial value |c − c0| / c0", focal, pct(focal),
              f"pass ≤ {FOCAL_CHANGE_PASS:.0%}, warn ≤ {FOCAL_CHANGE_WARN:.0%}",
              _grade(focal, lambda x: x <= FOCAL_CHANGE_PASS, lambda x: x <= FOCAL_CHANGE_WARN), focal_camera),
        Check("sigma0_ratio", "σ̂0 / a-priori σ0", sigma0_ratio, num(sigma0_ratio, ".3f"),
              f"pass {lo:g} to {hi:g}, warn {wlo:.2f} to {whi:g}",
              _grade(sigma0_ratio, lambda x: lo <= x <= hi, lambda x: wlo <= x <= whi)),
        Check("observations_rejected", "image observations rejected", rejected,
              f"{pct(rejected)} ({n_rejected} of {n_observations})",
              f"pass ≤ {REJECTED_SHARE_PASS:.0%}, warn ≤ {REJECTED_SHARE_WARN:.0%}",
              _grade(rejected, lambda x: x <= REJECTED_SHARE_PASS, lambda x: x <= REJECTED_SHARE_WARN)),
        Check("gcp_residuals", "control residual / its σ (largest coordinate)", gcp, num(gcp, ".2f"),
              f"pass ≤ {GCP_RESIDUAL_PASS:g}, warn ≤ {GCP_RESIDUAL_WARN:g}",
              _grade(gcp, lambda x: x <= GCP_RESIDUAL_PASS, lambda x: x <= GCP_RESIDUAL_WARN), gcp_point),
        Check("weak_parameters", "camera parameters: largest |ρ| with another unknown", rho, num(rho, ".3f"),
              f"pass ≤ {CORRELATION_PASS:g}, warn ≤ {CORRELATION_WARN:g}",
              _grade(rho, lambda x: x <= CORRELATION_PASS, lambda x: x <= CORRELATION_WARN), rho_names),
    ]
