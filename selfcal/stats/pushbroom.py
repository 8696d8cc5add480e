"""Baarda's data snooping for pushbroom adjustments (seed 001 blocks): the same test as for frame
blocks (:mod:`.snooping`), one observation per round, on the w of the dense pushbroom solution."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..adjust.pushbroom import PushbroomResult, adjust_pushbroom
from .snooping import SnoopingOptions

__all__ = ["SnoopedPushbroom", "adjust_pushbroom_with_snooping"]


@dataclass
class SnoopedPushbroom:
    result: PushbroomResult
    kept: np.ndarray                 # bool over the observations given
    rejected: list[tuple[int, float]]   # (observation index, |w| when rejected), in order


def adjust_pushbroom_with_snooping(images, obs_image, obs_point, obs_row, obs_col, points_ecef, control_index,
                                   control_ecef, control_cov, model, image_sigma_px: float,
                                   snooping: SnoopingOptions | None = SnoopingOptions()) -> SnoopedPushbroom:
    """:func:`~selfcal.adjust.pushbroom.adjust_pushbroom`, then reject the image point with the largest
    |w| above the critical value and adjust again, until none is above it. Both coordinates of a
    rejected image point go (a misidentified point spoils both). Coordinates with a redundancy number
    below ``snooping.min_redundancy`` are not tested (they are not controlled)."""
    kept = np.ones(len(obs_row), bool)
    rejected: list[tuple[int, float]] = []
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
        kept[idx[k]] = False
        rejected.append((int(idx[k]), float(worst[k])))
    return SnoopedPushbroom(result, kept, rejected)
