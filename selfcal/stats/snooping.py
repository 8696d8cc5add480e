"""Baarda's data snooping: reject image observations with |w| above a critical value and re-adjust.

Two modes:

* ``single`` — the classic procedure: one observation (the largest |w|) per
  round, then re-adjust. Exact, but one adjustment per blunder.
* ``batch`` (default) — per round, every point's observation with the largest
  |w| above the critical value is rejected (at most one ray per point, since a
  blunder in one ray raises the w of the point's other rays too), then
  re-adjust. Large blocks with hundreds of blunders need a handful of rounds
  instead of hundreds; the final round is a test of the same statistic, so
  no observation above the critical value survives in either mode.

The x and y coordinates of an image point are rejected together. Coordinates
with a redundancy number below ``min_redundancy`` are not controlled by the
others (a blunder there cannot be seen) and are not tested.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..block import Block
from .reliability import ObservationTests

__all__ = ["SnoopingOptions", "SnoopingRound", "image_w", "reject_candidates"]


@dataclass(frozen=True)
class SnoopingOptions:
    """critical: Baarda's critical value (seed 000 uses 3.0; 0 disables snooping)."""

    critical: float = 3.0
    mode: str = "batch"
    max_rounds: int = 60
    min_redundancy: float = 0.01

    def __post_init__(self):
        if self.mode not in ("batch", "single"):
            raise ValueError(f"snooping mode must be 'batch' or 'single', found '{self.mode}'")
        if self.critical < 0:
            raise ValueError(f"the critical value must not be negative, found {self.critical}")


@dataclass
class SnoopingRound:
    """One round of the tests: observations rejected, APs dropped, and the state before it."""

    round: int
    rejected: int
    dropped_aps: int
    largest_w: float
    sigma0_px: float
    control_w: float | None = None      # |w| of the control point checked instead in this round, if one was


def image_w(tests: ObservationTests, min_redundancy: float) -> np.ndarray:
    """|w| per image observation (the larger of x and y); 0 where not controlled."""
    w = np.abs(tests.image_w)
    w[tests.image_redundancy < min_redundancy] = 0.0
    return w.max(axis=1)


def reject_candidates(block: Block, w: np.ndarray, critical: float, mode: str) -> np.ndarray:
    """Indices (into ``block.observations``) to reject this round."""
    above = np.flatnonzero(w > critical)
    if above.size == 0:
        return above
    if mode == "single":
        return above[[int(np.argmax(w[above]))]]
    pts = block.observations.point_index[above]
    order = np.lexsort((-w[above], pts))
    first = np.ones(order.size, bool)
    first[1:] = pts[order][1:] != pts[order][:-1]
    return above[order[first]]
