"""The half-block check of a self-calibration (issue 40 item 5): the block split in two, each half adjusted on its
own with the same AP model, the two calibrations compared against their combined σ
(:func:`selfcal.stats.field_sigma.compare_calibrations`): a model-error flag.

**The split** (:func:`split_halves`): by strips where the block has two or more (``images.csv`` ``strip_id``, in
the order they first appear), cut where the two halves' image counts are closest; otherwise by images, the first
half of them in images.csv's order against the rest. Either way each half is a contiguous part of the flight:
it has its own control and tie points, and no image observation is in both halves, so the two estimates are
independent (the control points that both halves see enter both with their surveyed coordinates; their
precision is far below the images', so the dependence this leaves is neglected).

**Each half**: the block the tested adjustment left (its rejections made, its screened AP set, the AP basis it
kept) restricted to that half's images, pruned (a tie point then seen once, an image with too few points go),
adjusted from the converged estimate with the run's options: no robust loss, no snooping, no screening. A half
that cannot be adjusted on its own (too little control for a datum, a rank defect) leaves the check undone with
its reason; nothing else of the run depends on it.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions, adjust
from ..block import Block, leave_out
from ..errors import AdjustmentError
from ..stats.field_sigma import (CalibrationDifference, ap_estimate, compare_calibrations, estimated_frame_cameras,
                                 grid_nodes, observed_nodes, observed_pixels, observed_radius_px)
from .tested import TestedAdjustment, prune_for

__all__ = ["HalfBlock", "HalfBlockCamera", "half_block_check", "half_block_summary", "half_block_notes",
           "split_halves", "halves_text"]


@dataclass(frozen=True)
class HalfBlockCamera:
    """One camera's two half-block calibrations compared, on the grid of distortion_sigma.csv."""

    camera_id: str
    difference: CalibrationDifference
    col_px: np.ndarray                      # the nodes (pixels)
    row_px: np.ndarray


@dataclass
class HalfBlock:
    """The half-block check: how the block was split, each half's adjustment, the comparison per camera (empty
    with ``reason`` where the check could not be made)."""

    split: str                                          # "strips" or "images"
    halves: tuple[tuple[str, ...], tuple[str, ...]]     # the strip ids (split by strips) or image ids of each half
    n_images: tuple[int, int] = (0, 0)
    n_observations: tuple[int, int] = (0, 0)
    sigma0_px: tuple[float, float] = (float("nan"), float("nan"))
    cameras: list[HalfBlockCamera] = field(default_factory=list)
    reason: str = ""
    seconds: float = 0.0

    @property
    def flag(self) -> bool:
        return any(c.difference.flag for c in self.cameras)


def split_halves(block: Block) -> tuple[str, np.ndarray, tuple[tuple[str, ...], tuple[str, ...]]]:
    """(how, in_first (bool over the block's images), the two halves' strip or image ids): module docstring."""
    strips = np.array([str(s) for s in block.images.strip_id], object)
    order = list(dict.fromkeys(s for s in strips if s))
    if len(order) >= 2 and all(strips):
        counts = np.array([np.sum(strips == s) for s in order])
        cut = int(np.argmin(np.abs(np.cumsum(counts)[:-1] - counts.sum() / 2.0))) + 1
        first = np.isin(strips, order[:cut])
        return "strips", first, (tuple(order[:cut]), tuple(order[cut:]))
    n = len(block.images)
    first = np.arange(n) < (n + 1) // 2
    ids = [str(i) for i in block.images.image_id]
    return "images", first, (tuple(i for i, f in zip(ids, first) if f), tuple(i for i, f in zip(ids, first) if not f))


def halves_text(how: str, halves: tuple | list) -> str:
    """The split in words: ``strips S1, S2 | S3, S4``, or ``images: 14 | 14`` (image ids would be too many)."""
    if how == "strips":
        return "strips " + " | ".join(", ".join(h) for h in halves)
    return "images: " + " | ".join(str(len(h)) for h in halves)


def _half(block: Block, images: np.ndarray) -> Block:
    """``block`` with the observations of ``images`` (bool over its images) only, pruned."""
    obs = block.observations
    return prune_for(leave_out(block, observations=~images[obs.image_index]))


def half_block_check(tested: TestedAdjustment, options: AdjustOptions,
                     say: Callable[[str], None] | None = None) -> HalfBlock | None:
    """The half-block check of a tested adjustment (module docstring); None where no camera has estimated frame
    APs (nothing to compare). ``say`` receives a line as the two adjustments begin."""
    t0 = time.perf_counter()
    result = tested.result
    cameras = estimated_frame_cameras(result)
    if not cameras:
        return None
    block = result.block
    how, first, labels = split_halves(block)
    check = HalfBlock(how, labels)
    if not first.any() or first.all():
        check.reason = "the block has a single image: it cannot be split"
        return check
    models = {cam.camera_id: cam.ap for cam in result.problem.cameras}
    # the screened set of every camera and image parameter; trajectory terms (GNSS, IMU: masks over all the strips'
    # terms, of which a half has only its own) are estimated in full by each half (nuisance parameters: the
    # halves' covariances grow a little, which makes the test conservative)
    cameras_free = {key: mask for key, mask in tested.ap_free.items()
                    if not isinstance(key, str) or key in result.problem.camera_ids}
    if say is not None:
        say(f"half-block check: each half ({halves_text(how, labels)}) adjusted on its own")
    halves = []
    for part in (first, ~first):
        try:
            half = _half(block, part)
            adjusted = adjust(half, options, start=result, free=cameras_free, ap_models=models)
        except AdjustmentError as exc:
            check.reason = f"a half ({halves_text(how, labels)}) cannot be adjusted on its own: " \
                           f"{str(exc).splitlines()[0]}"
            check.seconds = time.perf_counter() - t0
            return check
        if not adjusted.converged:
            check.reason = f"a half's adjustment did not converge ({adjusted.reason})"
            check.seconds = time.perf_counter() - t0
            return check
        halves.append(adjusted)
    a, b = halves
    check.n_images = (len(a.block.images), len(b.block.images))
    check.n_observations = (len(a.block.observations), len(b.block.observations))
    check.sigma0_px = (a.sigma0_px, b.sigma0_px)
    for k in cameras:
        camera_id = result.problem.cameras[k].camera_id
        ka = a.problem.camera_ids.index(camera_id) if camera_id in a.problem.camera_ids else -1
        kb = b.problem.camera_ids.index(camera_id) if camera_id in b.problem.camera_ids else -1
        if ka < 0 or kb < 0:
            continue                        # (the camera's images are all in one half: nothing to compare)
        free_a, values_a, cov_a = ap_estimate(a, ka)
        free_b, values_b, cov_b = ap_estimate(b, kb)
        estimated, _, _ = ap_estimate(result, k)
        if not (np.array_equal(free_a, estimated) and np.array_equal(free_b, estimated)):
            continue                        # (held differently: the coefficients are not the same)
        x, y, col, row = grid_nodes(result, k)
        cam = result.problem.cameras[k]
        bx, by = cam.ap.basis(x, y)
        bx, by = bx[:, estimated], by[:, estimated]
        radius = observed_radius_px(result, camera_id)
        seen = [observed_nodes(col, row, observed_pixels(h, camera_id), radius) for h in (a, b)]
        difference = compare_calibrations(values_a, cov_a, values_b, cov_b, bx, by, seen[0] & seen[1])
        check.cameras.append(HalfBlockCamera(camera_id, difference, col, row))
    if not check.cameras:
        check.reason = "no camera has images in both halves"
    check.seconds = time.perf_counter() - t0
    return check


def half_block_summary(check: HalfBlock) -> dict:
    """summary.json ``half_block``: the split, each half, and by camera id the test (statistic, dof, p, flag) and
    the largest |difference| / σ of the correction with where it is (pixels; the axis ``col`` or ``row``)."""
    cameras = {}
    for c in check.cameras:
        d = c.difference
        at = d.largest_node
        cameras[c.camera_id] = {"statistic": d.statistic, "dof": d.dof,
                        "n_coefficients": d.n_coefficients, "p": d.p_value, "critical": d.critical, "flag": d.flag,
                        "rms_difference_px": d.rms_difference_px, "largest_ratio": d.largest_ratio,
                        "largest_at_col_px": round(float(c.col_px[at]), 2) if at >= 0 else None,
                        "largest_at_row_px": round(float(c.row_px[at]), 2) if at >= 0 else None,
                        "largest_axis": ("col", "row")[d.largest_axis] if at >= 0 else None,
                        "largest_difference_px": float(d.difference[at, d.largest_axis]) * (1 if d.largest_axis == 0
                                                                                           else -1)
                        if at >= 0 else None}
    alpha = check.cameras[0].difference.alpha if check.cameras else None
    return {"split": check.split, "halves": [list(h) for h in check.halves], "n_images": list(check.n_images),
            "n_observations": list(check.n_observations), "sigma0_px": list(check.sigma0_px), "alpha": alpha,
            "flag": check.flag, "done": bool(check.cameras), "reason": check.reason or None, "cameras": cameras,
            "seconds": check.seconds}


def half_block_notes(check: HalfBlock) -> list[str]:
    """The run's warnings from the check: each camera whose halves' calibrations differ, or why it was not made."""
    if check.reason:
        return [f"half-block check not made: {check.reason}"]
    notes = []
    for c in check.cameras:
        d = c.difference
        if d.flag:
            axis = ("col", "row")[d.largest_axis]
            notes.append(f"half-block check: camera '{c.camera_id}' calibrated on the two halves of the block "
                         f"({halves_text(check.split, check.halves)}) differs "
                         f"beyond its precision (T {d.statistic:.1f} > {d.critical:.1f}, chi2({d.dof}), p "
                         f"{d.p_value:.2g}); the correction differs by {d.largest_ratio:.1f} sigma in {axis} at "
                         f"({c.col_px[d.largest_node]:.0f}, {c.row_px[d.largest_node]:.0f}) px: the AP model does not "
                         f"describe the camera the same way in both halves (a model error, or a camera that changed "
                         f"during the flight)")
    return notes
