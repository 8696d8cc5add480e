"""Redundancy numbers, Baarda's w-test and reliability of every observation.

For whitened observations (P = I) the cofactor matrix of the residuals is
Q_vv = I - J Q Jᵀ, so the redundancy number of observation i is

    r_i = 1 - h_i,    h_i = j_i Q j_iᵀ,

and sum_i r_i = n - u. The leverages h come from the result
(:meth:`selfcal.adjust.AdjustmentResult.image_leverages` and its siblings:
the Schur structure, no inverse of the full system, :mod:`selfcal.adjust.leverage`).

Baarda's w-test uses the a-priori sigma (unit weight 1 after whitening):
w_i = v_i / sqrt(r_i), standard normal for a blunder-free observation.
Internal reliability: the minimal detectable blunder
MDB_i = delta0 · sigma_i / sqrt(r_i); external reliability: Baarda's factor
delta_bar_i = delta0 · sqrt((1 - r_i) / r_i), the largest effect of an
undetected blunder of size MDB_i on any function of the unknowns, in units of
that function's standard deviation. delta0 = k + z(beta0) with the critical
value k of the test and the power beta0 = 80 %.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from .distributions import normal_ppf

__all__ = ["ObservationTests", "observation_tests", "noncentrality"]

POWER = 0.80


def noncentrality(critical: float, power: float = POWER) -> float:
    """delta0 of Baarda's test: the blunder (in sigma) detected with probability ``power``."""
    return float(critical + normal_ppf(power))


@dataclass
class ObservationTests:
    """Per-observation statistics; image arrays follow ``result.block.observations`` order."""

    image_redundancy: np.ndarray   # (m, 2) for x and y
    image_w: np.ndarray            # (m, 2)
    image_mdb_px: np.ndarray       # (m, 2) minimal detectable blunder, pixels
    image_external: np.ndarray     # (m, 2) Baarda's external reliability factor
    control_redundancy: np.ndarray  # (n_gcp, 3)
    control_w: np.ndarray           # (n_gcp, 3)
    parameter_redundancy: np.ndarray  # (k,)
    parameter_w: np.ndarray           # (k,)
    critical: float
    delta0: float
    #: the terrain heights of tie points (issue 42; ``result.problem.terrain``'s order), empty without them
    terrain_redundancy: np.ndarray = field(default_factory=lambda: np.zeros(0))     # (n_terrain,)
    terrain_w: np.ndarray = field(default_factory=lambda: np.zeros(0))              # (n_terrain,)

    @property
    def total_redundancy(self) -> float:
        return float(self.image_redundancy.sum() + self.control_redundancy.sum() + self.parameter_redundancy.sum()
                     + self.terrain_redundancy.sum())

    def image_w_max(self) -> np.ndarray:
        """Per image observation, the w of the coordinate with the larger ``|w|`` (sign kept)."""
        w = self.image_w
        pick = np.argmax(np.abs(w), axis=1)
        return w[np.arange(len(w)), pick]


def observation_tests(result, critical: float = 3.0) -> ObservationTests:
    """Redundancy numbers, w-tests and reliability of all observations of an adjustment."""
    delta0 = noncentrality(critical)
    h, image_v = result.image_leverages()             # block order; whitened residuals v = f - l
    image_r = np.clip(1.0 - h, 1e-12, None)
    sigma_px = result.block.observations.sigma_px[:, None]
    image_w = image_v / np.sqrt(image_r)
    mdb = delta0 * sigma_px / np.sqrt(image_r)
    external = delta0 * np.sqrt((1.0 - image_r) / image_r)

    _, ctl_h, ctl_v = result.control_leverages()
    ctl_r = np.clip(1.0 - ctl_h, 1e-12, None)
    par_h, par_v = result.parameter_leverages()
    par_r = np.clip(1.0 - par_h, 1e-12, None)
    _, ter_h, ter_v = result.terrain_leverages()
    ter_r = np.clip(1.0 - ter_h, 1e-12, None)
    return ObservationTests(
        image_redundancy=image_r, image_w=image_w, image_mdb_px=mdb, image_external=external,
        control_redundancy=ctl_r, control_w=ctl_v / np.sqrt(ctl_r),
        parameter_redundancy=par_r, parameter_w=par_v / np.sqrt(par_r),
        critical=critical, delta0=delta0, terrain_redundancy=ter_r, terrain_w=ter_v / np.sqrt(ter_r),
    )
