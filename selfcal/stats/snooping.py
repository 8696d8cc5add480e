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

__all__ = ["SnoopingOptions", "SnoopingRound", "image_w", "reject_candidates", "terrain_w", "with_terrain"]


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


def terrain_w(tests: ObservationTests, min_redundancy: float) -> np.ndarray:
    """|w| per terrain height (``result.problem.terrain``'s order); 0 where not controlled."""
    w = np.abs(tests.terrain_w)
    w[tests.terrain_redundancy < min_redundancy] = 0.0
    return w


def with_terrain(block: Block, w_image: np.ndarray, image_picks: np.ndarray, terrain_point: np.ndarray,
                 w_terrain: np.ndarray, critical: float, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """The image observations (indices into ``block.observations``) and the terrain heights (positions in
    ``terrain_point``, the points they observe) to reject this round, the terrain heights tested with the image
    observations (issue 42): ``single`` rejects the one largest |w| of either; ``batch`` a point's terrain height
    where its |w| is above ``critical`` and at least that of every ray of the point (at most one observation
    per point in a round, as for the rays: a wrong DEM height pulls the point, and with it the rays' w), and no
    ray in a round that rejects terrain heights: an area of wrong DEM heights pulls the block, and with it the
    rays of points elsewhere; they are tested again in the next round, without it."""
    none = np.zeros(0, np.int64)
    above = np.flatnonzero(w_terrain > critical)
    if not above.size:
        return image_picks, none
    if mode == "single":
        k = int(above[np.argmax(w_terrain[above])])
        best_image = float(w_image[image_picks].max()) if image_picks.size else 0.0
        return (none, np.array([k], np.int64)) if w_terrain[k] > best_image else (image_picks, none)
    rays = np.zeros(len(block.points))
    np.maximum.at(rays, block.observations.point_index, w_image)
    terrain = above[w_terrain[above] >= rays[terrain_point[above]]]
    return (none, terrain) if terrain.size else (image_picks, none)


#: the fewest rays that determine a point of each role (:func:`selfcal.block.prune`)
_RAYS_NEEDED = {"gcp": 1, "chk": 2}


def left_without_rays(before: Block, after: Block, rejected_rows: np.ndarray, named=()) -> list[str]:
    """One warning per control or check point of ``before`` that had the rays to take part and is not in ``after``
    (their rejection by data snooping or the robust cleaning, ``rejected_rows``, left too few, or their images went),
    naming it; points in ``named`` (already warned about) are passed over."""
    rays = np.bincount(before.observations.point_index, minlength=len(before.points))
    kept = set(after.points.point_id.tolist())
    messages = []
    for p in np.flatnonzero(np.isin(before.points.role, list(_RAYS_NEEDED))):
        name, role = str(before.points.point_id[p]), str(before.points.role[p])
        if rays[p] < _RAYS_NEEDED[role] or name in kept or name in named:
            continue
        rows = before.observations.row[before.observations.point_index == p]
        n_rejected = int(np.isin(rows, rejected_rows).sum())
        why = (f"{n_rejected} of its {len(rows)} rays rejected as blunders" if n_rejected else
               f"its images left out ({len(rows)} rays)")
        messages.append(f"{'control' if role == 'gcp' else 'check'} point '{name}' left without rays: {why}, too few "
                        f"left to determine it; it "
                        + ("no longer controls the block" if role == "gcp" else "is not checked"))
    return messages
