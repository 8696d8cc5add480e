"""The tests of frame blocks on pushbroom adjustments (seed 001 blocks).

* Baarda's data snooping (:mod:`.snooping`), one image point per round, on the w of the dense
  pushbroom solution;
* screening of the calibration parameters (:mod:`.screening`): backward elimination of the least
  significant parameter, t = |x - x0| / sigma(x) below ``significance``, else of the less significant
  of the most correlated pair above ``max_correlation``; each drop is followed by a re-adjustment
  (a pushbroom block has tens of parameters, so re-adjusting costs less than a second and is exact).
  x0 is the start value: zero for the attitude corrections and the 1-D wavelet APs of the detector
  lines, the given (or calibrated) focal length and boresight. A dropped parameter is held at x0. The guard is the joint test of everything
  dropped against the full model, F = (Omega_S - Omega) / (|S| sigma0^2) against the 1 - ``joint_alpha``
  quantile of F(|S|, redundancy): a drop that would make the dropped set jointly significant is
  undone and the screening stops.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from scipy.stats import f as f_distribution

from ..adjust.pushbroom import PushbroomResult, SensorModel, adjust_pushbroom
from ..sensors.pushbroom import PARAMETER_NAMES
from .screening import ScreeningDecision, ScreeningOptions, ScreeningRound
from .snooping import SnoopingOptions

__all__ = ["SnoopedPushbroom", "adjust_pushbroom_with_snooping", "MAX_REJECTED_SHARE", "ScreenedPushbroom",
           "screen_pushbroom"]

#: data snooping stops with a failure rather than reject more than this share of the image points:
#: so many outliers are a wrong model, not blunders
MAX_REJECTED_SHARE = 0.1


@dataclass
class SnoopedPushbroom:
    result: PushbroomResult
    kept: np.ndarray                 # bool over the observations given
    rejected: list[tuple[int, float]]   # (observation index, |w| when rejected), in order
    failure: str = ""                   # why the tests stopped short, if they did


def adjust_pushbroom_with_snooping(images, obs_image, obs_point, obs_row, obs_col, points_ecef, control_index,
                                   control_ecef, control_cov, model, image_sigma_px: float,
                                   snooping: SnoopingOptions | None = SnoopingOptions(),
                                   line_aps: dict | None = None, line_ap_sigma_px: float | None = None
                                   ) -> SnoopedPushbroom:
    """:func:`~selfcal.adjust.pushbroom.adjust_pushbroom`, then reject the image point with the largest
    |w| above the critical value and adjust again, until none is above it. Both coordinates of a
    rejected image point go (a misidentified point spoils both). Coordinates with a redundancy number
    below ``snooping.min_redundancy`` are not tested (they are not controlled)."""
    kept = np.ones(len(obs_row), bool)
    rejected: list[tuple[int, float]] = []
    limit = max(1, int(MAX_REJECTED_SHARE * len(obs_row)))
    rounds = snooping.max_rounds if snooping is not None and snooping.critical > 0 else 0
    for _ in range(rounds + 1):
        idx = np.flatnonzero(kept)
        result = adjust_pushbroom(images, obs_image[idx], obs_point[idx], obs_row[idx], obs_col[idx], points_ecef,
                                  control_index, control_ecef, control_cov, model, image_sigma_px,
                                  line_aps=line_aps, line_ap_sigma_px=line_ap_sigma_px)
        if len(rejected) >= rounds or not result.converged:
            break
        w = np.abs(result.w_test)
        w[result.redundancy_numbers < snooping.min_redundancy] = 0.0
        worst = np.max(w, axis=1)
        k = int(np.argmax(worst))
        if worst[k] <= snooping.critical:
            break
        if len(rejected) >= limit:
            return SnoopedPushbroom(result, kept, rejected, (
                f"data snooping would reject more than {MAX_REJECTED_SHARE:.0%} of the image points (|w| "
                f"{worst[k]:.1f} after {len(rejected)}): the sensor model does not fit the data (a focal length "
                f"not calibrated? too few parameters?)"))
        kept[idx[k]] = False
        rejected.append((int(idx[k]), float(worst[k])))
    return SnoopedPushbroom(result, kept, rejected)


@dataclass
class ScreenedPushbroom:
    models: list[SensorModel]            # per image: the parameters kept
    line_ap_masks: dict                  # camera id -> bool mask of the line-AP coefficients kept
    dropped: list[ScreeningDecision]     # in order; camera_id is the image id
    joint: ScreeningRound | None         # the joint test of everything dropped (None: nothing dropped)
    n_initial: int                       # parameters estimated before screening
    result: PushbroomResult              # the adjustment with the kept parameters

    @property
    def n_kept(self) -> int:
        return self.n_initial - len(self.dropped)


def _t_values(result: PushbroomResult, start: dict[str, float]) -> np.ndarray:
    x0 = np.array([start.get(n, 0.0) for n in result.parameter_names])       # line APs start at zero
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(result.parameter_values - x0) / result.parameter_sigma


def _candidate(result: PushbroomResult, t: np.ndarray, options: ScreeningOptions) -> tuple[int, str] | None:
    """The parameter to drop next, and why (None: every parameter stays)."""
    if not t.size:
        return None
    k = int(np.nanargmin(t))
    if t[k] < options.significance:
        return k, "insignificant"
    rho = np.abs(result.correlation - np.eye(len(t)))
    i, j = np.unravel_index(int(np.argmax(rho)), rho.shape)
    if rho[i, j] <= options.max_correlation:
        return None
    k, other = (i, j) if t[i] <= t[j] else (j, i)
    return int(k), f"correlated with {result.parameter_names[other]} (rho {result.correlation[i, j]:+.3f})"


def _without(models: list[SensorModel], image_index: int, name: str) -> list[SensorModel]:
    out = list(models)
    m = out[image_index]
    out[image_index] = replace(m, name=m.name + " screened", free=tuple(n for n in m.free if n != name))
    return out


def screen_pushbroom(adjust: Callable[[list[SensorModel], dict], PushbroomResult], image_ids: list[str],
                     start: list[np.ndarray], models: list[SensorModel],
                     options: ScreeningOptions = ScreeningOptions(), line_aps: dict | None = None
                     ) -> ScreenedPushbroom:
    """Screen the calibration parameters of a pushbroom adjustment (see the module docstring).

    ``adjust(models, line_ap_masks)`` adjusts with one :class:`SensorModel` per image and the line-AP
    coefficients of each camera that the masks leave free (the observations are fixed by the caller);
    ``start`` are the images' parameter vectors before adjustment (x0 of the t-test); ``line_aps``:
    camera id -> :class:`~selfcal.ap.line.LineWaveletAP` screened with the rest.
    """
    x0 = {f"{i}.{n}": float(p[k]) for i, p in zip(image_ids, start) for k, n in enumerate(PARAMETER_NAMES)}
    line_aps = line_aps or {}
    masks = {cid: np.ones(ap.size, bool) for cid, ap in line_aps.items()}
    full = adjust(models, masks)
    result, dropped, joint = full, [], None
    omega_full = full.sigma0 ** 2 * full.redundancy
    n_initial = len(full.parameter_names)
    for _ in range(n_initial):
        t = _t_values(result, x0)
        pick = _candidate(result, t, options)
        if pick is None:
            break
        k, reason = pick
        owner, name = result.parameter_names[k].split(".", 1)
        trial_models, trial_masks = models, masks
        if name in PARAMETER_NAMES:
            trial_models = _without(models, image_ids.index(owner), name)
        else:
            trial_masks = {cid: m.copy() for cid, m in masks.items()}
            trial_masks[owner][line_aps[owner].names.index(name)] = False
        trial = adjust(trial_models, trial_masks)
        n_dropped = len(dropped) + 1
        increase = (trial.sigma0 ** 2 * trial.redundancy - omega_full) / full.sigma0 ** 2
        test = ScreeningRound(n_dropped, float(increase), float(f_distribution.ppf(1.0 - (options.joint_alpha or 0.0),
                                                                                   n_dropped, full.redundancy))
                              if options.joint_alpha else float("inf"))
        if test.jointly_significant or not trial.converged:
            break
        models, masks, result, joint = trial_models, trial_masks, trial, test
        dropped.append(ScreeningDecision(owner, name, float(t[k]), reason))
    return ScreenedPushbroom(models, masks, dropped, joint, n_initial, result)
