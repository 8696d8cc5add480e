"""Whether a calibration's stated sigma can be trusted (issue 44 item 5; DESIGN-NOTES "Honest precision").

The a-posteriori sigma of a camera parameter, sqrt(s0^2 Q_jj), describes the scatter that white image noise gives
the estimate when the model is right. Two things make it miss the actual error on real blocks: a parameter that
the adjustment determines only through its correlation with others (a free close-range network's c with Brown's
affinity b1, x0 with the decentring p1) moves along that correlation with any small systematic image error, which
no sigma describes; and such an error shows as a spread of the estimate over the images that the sigma does not
predict. This module states both, per camera, for every estimated parameter (core: a frame camera's c, x0, y0;
and the active AP coefficients):

* ``sigma_aps_held``: the sigma the parameter would have with the camera's active APs held at their estimates,
  sqrt(s0^2 (Q_jj - Q_ja Q_aa^-1 Q_aj)); ``ap_inflation`` = sigma / sigma_aps_held = 1 / sqrt(1 - R^2), R the
  multiple correlation of the parameter with the APs (a core parameter only);
* ``partner``, ``rho``: the other estimated parameter of the camera it is most correlated with;
* with a jackknife over groups of images (:func:`jackknife_spread`; the replicates come from
  :mod:`selfcal.workflows.jackknife`): ``sigma_jackknife`` = sqrt((G - 1)/G sum_g (theta_(g) - mean)^2) of the G
  estimates with one group left out, and ``ratio`` = sigma_jackknife / sigma. With the model right the ratio is
  about 1; a ratio above :func:`critical_ratio` (twice, or the chi^2(G - 1) bound at ``alpha`` where that is larger)
  flags the parameter: the images disagree about it more than the noise explains.

:func:`precision_statement` turns these into the verdict summary.json ``calibration_precision`` and the report
give: trusted (a jackknife found no core parameter flagged: c, x0, y0 of a frame camera; the AP coefficients' ratios
are given, their field is judged by the half-block check), not trusted (it did, or the half-block check flags the
camera: the honest sigma is the jackknife's),
or not verified (no jackknife: the parameters whose sigma the APs inflate at least :data:`NAMED_INFLATION` times
are named with their partner).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..adjust.result import AdjustmentResult
from .correlation import correlation_matrix
from .distributions import chi2_isf

__all__ = ["ParameterPrecision", "CameraPrecision", "camera_precision", "jackknife_spread", "critical_ratio",
           "precision_statement", "JACKKNIFE_ALPHA", "NAMED_INFLATION"]

#: the jackknife flags a parameter whose spread exceeds its sigma at this level (the diagnosis's level) ...
JACKKNIFE_ALPHA = 0.001
#: ... and by more than this factor (issue 44: a sigma must cover the error within 2x). The delete-one-group
#: jackknife's variance over a few unequal groups (the end images of an arc weigh more) scatters more than
#: chi^2(G - 1): over 20 seeds of the simulated close-range block with the right model the ratios of c, x0, y0 reached
#: 1.99 (90th percentile 1.3-1.8), where chi^2(10) at 0.001 allows 1.72 (benchmarks/study_honest_precision.py)
JACKKNIFE_FACTOR = 2.0
#: a core parameter whose sigma the APs inflate this many times (R >= 0.87 with them) is named as weakly
#: determined when no jackknife checked it
NAMED_INFLATION = 2.0


@dataclass
class ParameterPrecision:
    name: str                       # c, x0, y0 or an AP coefficient's name
    unit: str                       # of value and sigmas (px for every one: c, x0, y0 converted by the pixel size)
    value: float
    sigma: float
    core: bool
    sigma_aps_held: float | None = None
    ap_inflation: float | None = None
    partner: str | None = None
    rho: float | None = None
    sigma_jackknife: float | None = None
    ratio: float | None = None
    flagged: bool | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class CameraPrecision:
    camera_id: str
    parameters: list[ParameterPrecision] = field(default_factory=list)

    def by_name(self) -> dict[str, ParameterPrecision]:
        return {p.name: p for p in self.parameters}


def _estimated(result: AdjustmentResult, k: int) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray]:
    """Camera k's estimated parameters: their positions in its parameter vector, names, scale to the reported
    unit (a frame camera's c, x0, y0 from mm to px) and whether each is a core parameter."""
    cam = result.problem.cameras[k]
    free = np.flatnonzero(cam.free)
    pixel = getattr(result.block.cameras[cam.camera_id], "pixel_size_mm", None)
    core_mm = [i < cam.n_core and cam.units[i] == "mm" for i in free] if hasattr(cam, "units") else \
        [i < cam.n_core for i in free]
    scale = np.array([1.0 / pixel if (mm and pixel) else 1.0 for mm in core_mm])
    return free, [cam.names[i] for i in free], scale, free < cam.n_core


def camera_precision(result: AdjustmentResult) -> list[CameraPrecision]:
    """Each camera's estimated parameters with sigma, the sigma with the APs held, the AP inflation and the
    strongest correlation (module docstring); c, x0, y0 of a frame camera in pixels."""
    out = []
    for k, cam in enumerate(result.problem.cameras):
        free, names, scale, core = _estimated(result, k)
        if not free.size:
            continue
        start = result.problem.d_offset[k]
        index = np.arange(start, start + free.size)
        Q = np.asarray(result.Q_theta[np.ix_(index, index)], float)
        s2 = result.variance_factor
        sigma = np.sqrt(s2 * np.maximum(Q.diagonal(), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.nan_to_num(correlation_matrix(result.Q_theta, index))
        values = np.asarray(result.state.cameras[k], float)[free]
        aps = np.flatnonzero(~core)
        entries = []
        for j in range(free.size):
            unit = "px" if (core[j] and scale[j] != 1.0) or not core[j] else cam.units[free[j]] \
                if hasattr(cam, "units") else ""
            p = ParameterPrecision(names[j], unit, float(values[j] * scale[j]), float(sigma[j] * scale[j]), bool(core[j]))
            others = np.delete(np.arange(free.size), j)
            if others.size:
                best = others[np.argmax(np.abs(rho[j, others]))]
                p.partner, p.rho = names[best], float(rho[j, best])
            if core[j] and aps.size:
                held = Q[j, j] - Q[j, aps] @ np.linalg.lstsq(Q[np.ix_(aps, aps)], Q[aps, j], rcond=None)[0]
                p.sigma_aps_held = float(np.sqrt(s2 * max(held, 0.0)) * scale[j])
                p.ap_inflation = float(p.sigma / p.sigma_aps_held) if p.sigma_aps_held > 0 else None
            entries.append(p)
        out.append(CameraPrecision(cam.camera_id, entries))
    return out


def critical_ratio(groups: int, alpha: float = JACKKNIFE_ALPHA) -> float:
    """The largest sigma_jackknife / sigma accepted from G groups: the larger of :data:`JACKKNIFE_FACTOR` and
    what a right model gives at level ``alpha``, sqrt(chi^2_{G-1}(1 - alpha) / (G - 1))."""
    dof = groups - 1
    return max(JACKKNIFE_FACTOR, float(np.sqrt(chi2_isf(alpha, dof) / dof)))


def jackknife_spread(precision: CameraPrecision, replicates: dict[str, np.ndarray],
                     alpha: float = JACKKNIFE_ALPHA) -> None:
    """Fill ``precision``'s jackknife fields from ``replicates``: parameter name -> its G estimates (one per group
    left out; NaN where that replicate did not estimate it), in the unit of the precision's values."""
    for p in precision.parameters:
        theta = np.asarray(replicates.get(p.name, []), float)
        theta = theta[np.isfinite(theta)]
        if theta.size < 3 or not p.sigma > 0:
            continue
        g = theta.size
        p.sigma_jackknife = float(np.sqrt((g - 1) / g * np.sum((theta - theta.mean()) ** 2)))
        p.ratio = p.sigma_jackknife / p.sigma
        p.flagged = bool(p.ratio > critical_ratio(g, alpha))


def _said(p: ParameterPrecision) -> str:
    text = f"{p.name} {p.value:.6g} ± {p.sigma:.2g} {p.unit}".rstrip()
    if p.ratio is not None:
        text += f" (jackknife {p.sigma_jackknife:.2g}, {p.ratio:.1f}x)"
    if p.partner is not None and p.rho is not None and abs(p.rho) >= 0.8:
        text += f", ρ({p.name}, {p.partner}) = {p.rho:+.2f}"
    if p.ap_inflation is not None and p.ap_inflation >= NAMED_INFLATION:
        text += f", σ {p.ap_inflation:.1f}x its value with the APs held"
    return text


def precision_statement(cameras: list[CameraPrecision], jackknife_done: bool,
                        findings: list[str] | tuple[str, ...] = ()) -> tuple[bool | None, str]:
    """The verdict on the cameras' sigmas and one sentence that says why: (True, ...) a jackknife found every
    parameter's spread within its sigma; (False, ...) it did not for some (named, with the jackknife's sigma and
    their strongest correlation), or another check found a model error (``findings``: sentences, e.g. the
    half-block check's); (None, ...) not verified (no jackknife), naming the weakly determined core parameters if
    any."""
    trusted, statement = _jackknife_statement(cameras, jackknife_done)
    if not findings:
        return trusted, statement
    found = "; ".join(findings)
    if trusted is False:
        return False, f"{statement}; and {found}"
    return False, f"the calibration's sigma does not hold: {found} (a model error the sigma does not describe)"


def _jackknife_statement(cameras: list[CameraPrecision], jackknife_done: bool) -> tuple[bool | None, str]:
    if jackknife_done:
        flagged = [(c.camera_id, p) for c in cameras for p in c.parameters if p.flagged and p.core]
        checked = [p for c in cameras for p in c.parameters if p.ratio is not None and p.core]
        if not checked:
            return None, "the jackknife left too few replicates to judge the calibration's sigma"
        if not flagged:
            worst = max(checked, key=lambda p: p.ratio or 0.0)
            return True, (f"the calibration's sigma holds: over the jackknife's replicates every core parameter "
                          f"scatters within twice its sigma (largest ratio {worst.ratio:.2f}, {worst.name})")
        listed = "; ".join(f"camera {cid}: {_said(p)}" for cid, p in flagged)
        return False, (f"the calibration's sigma does not hold for {len(flagged)} parameter(s): the images disagree "
                       f"about them more than the noise explains (a model error; the jackknife's sigma is the "
                       f"honest one): {listed}")
    weak = [(c.camera_id, p) for c in cameras for p in c.parameters
            if p.core and p.ap_inflation is not None and p.ap_inflation >= NAMED_INFLATION]
    if not weak:
        return None, ("the calibration's sigma is not verified (no jackknife: selfcal adjust --jackknife G); no "
                      "core parameter's sigma is inflated by its correlation with the APs")
    listed = "; ".join(f"camera {cid}: {_said(p)}" for cid, p in weak)
    return None, (f"the calibration's sigma is not verified, and {len(weak)} core parameter(s) are determined only "
                  f"through their correlation with the APs: a systematic image error too small for the tests moves "
                  f"them along it by more than their sigma says ({listed}); selfcal adjust --jackknife G checks "
                  f"it")
