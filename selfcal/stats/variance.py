"""Variance components: one variance factor per group of observations.

Users often cannot say how accurate their GNSS antenna positions or IMU
attitudes are. With ``variance_components`` the adjustment estimates a
variance factor for each group g — image coordinates, ground control (GCP),
GNSS positions, IMU attitudes — by Förstner's iterative estimator
(Förstner 1979, "Ein Verfahren zur Schätzung von Varianz- und
Kovarianzkomponenten"; Koch 1999, Sect. 4.4):

    sigma_g^2 = Omega_g / r_g,     Omega_g = v_g' P_g v_g,   r_g = sum of the redundancy numbers of g,

where the r_g add up to the total redundancy n - u. The a-priori standard
deviations of each group are multiplied by sigma_g and the block is adjusted
again, until every factor is 1 within ``tolerance``; at that fixed point the
estimate equals the (locally best invariant quadratic unbiased) estimate of
the variance components. A group is estimated only when its redundancy is at
least ``min_redundancy``; otherwise its a-priori sigma is kept. The a-priori
interior orientation observations (camera.json sigmas) are never rescaled.

The precision of an estimated sigma is about sigma_g / sqrt(2 r_g): groups
with few observations (some dozen GCPs or images) are estimated to 10-20 %.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from ..adjust import AdjustmentResult, AdjustOptions, adjust
from ..block import Block
from .reliability import ObservationTests, observation_tests

__all__ = ["VarianceComponent", "VarianceOptions", "group_redundancy", "estimate_variance_components"]

GROUPS = ("image", "GCP", "GNSS", "IMU", "terrain")
TRAJECTORY_GROUPS = ("GNSS", "IMU")
UNITS = {"image": "px", "GCP": "m", "GNSS": "m", "IMU": "deg", "terrain": "m"}


@dataclass(frozen=True)
class VarianceOptions:
    """``groups``: the groups whose factor is estimated (None: every group). The others are pooled into one
    reference group whose factor stays 1, and each listed group's factor is relative to it:
    (Omega_g / r_g) / (Omega_ref / r_ref). ``groups=TRAJECTORY_GROUPS`` weighs the GNSS and IMU observations
    against the images and control as declared, without rescaling those (:func:`trajectory_weights`)."""

    tolerance: float = 0.01
    max_iterations: int = 10
    min_redundancy: float = 3.0
    groups: tuple[str, ...] | None = None


@dataclass(frozen=True)
class VarianceComponent:
    """A group's a-priori and estimated standard deviations (a-posteriori = scale x a-priori)."""

    group: str
    n_observations: int
    redundancy: float
    scale: float                      # estimated sigma / a-priori sigma
    sigma_apriori: tuple[float, ...]  # per coordinate where the block gives three
    estimated: bool
    unit: str

    @property
    def sigma_aposteriori(self) -> tuple[float, ...]:
        return tuple(self.scale * s for s in self.sigma_apriori)

    def as_dict(self) -> dict:
        return {"group": self.group, "n_observations": self.n_observations, "redundancy": self.redundancy,
                "estimated": self.estimated, "scale": self.scale, "unit": self.unit,
                "sigma_apriori": list(self.sigma_apriori), "sigma_aposteriori": list(self.sigma_aposteriori)}


def group_redundancy(result: AdjustmentResult, tests: ObservationTests) -> dict[str, tuple[int, float, float]]:
    """Per group: (number of observations, Omega_g, r_g). Omega_g and r_g use the a-priori weights."""
    out = {}
    r = tests.image_redundancy
    out["image"] = (r.size, float(np.sum(tests.image_w ** 2 * r)), float(r.sum()))
    r = tests.control_redundancy
    if r.size:
        out["GCP"] = (r.size, float(np.sum(tests.control_w ** 2 * r)), float(r.sum()))
    labels = result.parameter_observations()[2]
    r = tests.parameter_redundancy
    for group in ("GNSS", "IMU"):
        sel = labels == group
        if sel.any():
            out[group] = (int(sel.sum()), float(np.sum(tests.parameter_w[sel] ** 2 * r[sel])), float(r[sel].sum()))
    r = tests.terrain_redundancy
    if r.size:
        out["terrain"] = (r.size, float(np.sum(tests.terrain_w ** 2 * r)), float(r.sum()))
    return out


def _apriori(block: Block, group: str) -> tuple[float, ...]:
    if group == "image":
        return (float(block.image_sigma_px),)
    if group == "GCP":
        gcp = block.points.role == "gcp"
        return tuple(float(v) for v in np.nanmedian(block.points.sigma_m[gcp], axis=0))
    if group == "terrain":
        assert block.terrain_observations is not None
        return (float(block.terrain_observations.sigma_m),)
    if group == "GNSS":
        assert block.gnss_sigma_m is not None           # (the group's observations have it as their sigma)
        return tuple(float(v) for v in block.gnss_sigma_m)
    assert block.imu_sigma_deg is not None
    return tuple(float(v) for v in block.imu_sigma_deg)


def reweighted(block: Block, scale: dict[str, float]) -> Block:
    """``block`` with the a-priori sigmas of each group multiplied by ``scale[group]``."""
    changes: dict[str, Any] = {}
    s = scale.get("image", 1.0)
    if s != 1.0:
        changes["observations"] = replace(block.observations, sigma_px=block.observations.sigma_px * s)
        changes["image_sigma_px"] = block.image_sigma_px * s
    s = scale.get("GCP", 1.0)
    if s != 1.0:
        factor = np.where(block.points.role == "gcp", s, 1.0)[:, None]
        changes["points"] = replace(block.points, sigma_m=block.points.sigma_m * factor)
    images: dict[str, np.ndarray] = {}
    if scale.get("GNSS", 1.0) != 1.0:
        assert block.gnss_sigma_m is not None, "the block has no GNSS observations to reweight"
        changes["gnss_sigma_m"] = tuple(scale["GNSS"] * v for v in block.gnss_sigma_m)
        if block.images.gnss_sigma_m is not None:         # the images' own sigmas scale with the group's
            images["gnss_sigma_m"] = scale["GNSS"] * block.images.gnss_sigma_m
    if scale.get("IMU", 1.0) != 1.0:
        assert block.imu_sigma_deg is not None, "the block has no IMU observations to reweight"
        changes["imu_sigma_deg"] = tuple(scale["IMU"] * v for v in block.imu_sigma_deg)
        if block.images.imu_sigma_rad is not None:
            images["imu_sigma_rad"] = scale["IMU"] * block.images.imu_sigma_rad
    if images:
        changes["images"] = replace(block.images, **images)
    if scale.get("terrain", 1.0) != 1.0:
        assert block.terrain_observations is not None, "the block has no terrain observations to reweight"
        changes["terrain_observations"] = replace(block.terrain_observations,
                                                  sigma_m=scale["terrain"] * block.terrain_observations.sigma_m)
    return replace(block, **changes) if changes else block


def estimate_variance_components(block: Block, options: AdjustOptions, vce: VarianceOptions = VarianceOptions(),
                                 start: AdjustmentResult | None = None, free: dict | None = None,
                                 ap_models: dict | None = None, critical: float = 3.0,
                                 progress: Callable | None = None,
                                 ) -> tuple[AdjustmentResult, ObservationTests, list[VarianceComponent], bool]:
    """Adjust ``block`` with a variance factor per observation group.

    Returns the final adjustment (of the reweighted block), its observation
    tests, the components (scales relative to ``block``'s a-priori sigmas) and
    whether the factors reached 1 within the tolerance.
    """
    result = start if start is not None else adjust(block, options, progress=progress, free=free,
                                                    ap_models=ap_models)
    tests = observation_tests(result, critical)
    scale: dict[str, float] = {}
    converged = False
    for iteration in range(vce.max_iterations + 1):
        groups = group_redundancy(result, tests)
        factors = _factors(groups, vce)
        converged = all(abs(f - 1.0) <= vce.tolerance for f in factors.values())
        if converged or iteration == vce.max_iterations:
            break
        for g, f in factors.items():
            scale[g] = scale.get(g, 1.0) * float(np.sqrt(f))
        result = adjust(reweighted(block, scale), options, progress=progress, start=result, free=free,
                        ap_models=ap_models)
        tests = observation_tests(result, critical)
    groups = group_redundancy(result, tests)
    estimated = _factors(groups, vce)
    components = [VarianceComponent(g, n, r, scale.get(g, 1.0) if g in estimated else 1.0,
                                    _apriori(block, g), g in estimated, UNITS[g])
                  for g, (n, _, r) in groups.items()]
    return result, tests, components, converged


def _factors(groups: dict[str, tuple[int, float, float]], vce: VarianceOptions) -> dict[str, float]:
    """The variance factor of each group to estimate (its redundancy at least ``vce.min_redundancy``): Omega_g / r_g,
    or relative to the pooled others where ``vce.groups`` lists the groups to estimate."""
    if vce.groups is None:
        return {g: omega / r for g, (_, omega, r) in groups.items() if r >= vce.min_redundancy}
    rest = [(omega, r) for g, (_, omega, r) in groups.items() if g not in vce.groups]
    omega_ref, r_ref = (sum(v) for v in zip(*rest)) if rest else (0.0, 0.0)
    if r_ref < vce.min_redundancy or omega_ref <= 0:
        return {}
    return {g: (omega / r) / (omega_ref / r_ref) for g, (_, omega, r) in groups.items()
            if g in vce.groups and r >= vce.min_redundancy}
