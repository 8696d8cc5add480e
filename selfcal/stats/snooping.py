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

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..adjust import AdjustmentResult, AdjustOptions, adjust
from ..block import Block, prune
from .reliability import ObservationTests, observation_tests

__all__ = ["SnoopingOptions", "SnoopingRound", "snoop", "image_w", "reject_candidates"]


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
    round: int
    rejected: int
    largest_w: float
    sigma0_px: float


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


@dataclass
class SnoopingOutcome:
    result: AdjustmentResult
    tests: ObservationTests
    rejected_rows: np.ndarray                # observation rows (of the block as read) rejected
    rounds: list[SnoopingRound] = field(default_factory=list)


def snoop(block: Block, options: AdjustOptions, snooping: SnoopingOptions = SnoopingOptions(),
          start: AdjustmentResult | None = None, progress: Callable | None = None,
          report: Callable[[SnoopingRound], None] | None = None, **adjust_kwargs) -> SnoopingOutcome:
    """Adjust with data snooping; ``block`` is the pruned block as read."""
    result = adjust(block, options, progress=progress, start=start, **adjust_kwargs)
    critical = snooping.critical if snooping.critical > 0 else np.inf
    tests = observation_tests(result, critical if np.isfinite(critical) else 3.0)
    rejected = np.zeros(0, np.int64)
    rounds: list[SnoopingRound] = []
    for k in range(1, snooping.max_rounds + 1):
        if not np.isfinite(critical):
            break
        w = image_w(tests, snooping.min_redundancy)
        picks = reject_candidates(result.block, w, critical, snooping.mode)
        if picks.size == 0:
            break
        rejected = np.concatenate([rejected, result.block.observations.row[picks]])
        record = SnoopingRound(k, int(picks.size), float(w.max()), result.sigma0_px)
        rounds.append(record)
        if report is not None:
            report(record)
        keep = ~np.isin(block.observations.row, rejected)
        sub = prune(replace(block, observations=block.observations.take(np.flatnonzero(keep))))
        result = adjust(sub, options, progress=progress, start=result, **adjust_kwargs)
        tests = observation_tests(result, critical)
    return SnoopingOutcome(result, tests, np.sort(rejected), rounds)
