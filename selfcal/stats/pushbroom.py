"""Baarda's data snooping for pushbroom adjustments (seed 001 blocks): the same test as for frame
blocks (:mod:`.snooping`), one observation per round, on the w of the dense pushbroom solution."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..adjust.pushbroom import PushbroomResult, adjust_pushbroom
from .snooping import SnoopingOptions

__all__ = ["SnoopedPushbroom", "adjust_pushbroom_with_snooping", "MAX_REJECTED_SHARE"]

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
                                   snooping: SnoopingOptions | None = SnoopingOptions()) -> SnoopedPushbroom:
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
                                  control_index, control_ecef, control_cov, model, image_sigma_px)
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
