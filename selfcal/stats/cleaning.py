"""Robust cleaning: what a robust adjustment (:mod:`selfcal.adjust.robust`) says is a gross error, and why.

After the robust adjustment every image point and control point has a normalised residual size u (its whitened
residual's length over the robust scale) and a weight. The cleaning, before Baarda's tests of what is left:

* image observations with u above ``reject`` (5 robust sigmas by default: a blunder-free image point exceeds it
  with probability exp(-12.5) = 4e-6; the robust scale is never below the a-priori sigma) are rejected; those that then fit the least-squares adjustment of the
  cleaned block (the good rays a point's blunder pulled along) are taken back (:func:`readmissible`), and all
  face Baarda's tests afterwards;
* an image with most of its observations rejected (more than :data:`IMAGE_SHARE`) is left out: its
  orientation cannot come from the rest, and what is left of it would hold the others;
* a control point whose surveyed coordinates are grossly off (more than :data:`CONTROL_FACTOR` times ``reject``
  sigmas of the control: a misidentified target, a typed 1 m) no longer controls the block: it is checked instead
  (its role becomes ``chk``), named; a moderate error is left to the tests of the control group;
* the diagnosis tells contamination from a model that does not fit: the robust scale s (the bulk of the
  residuals in units of their a-priori sigma) against the share of gross errors. A bulk at the a-priori sigma
  with many gross errors is a contaminated block (matcher output); a bulk far above it is a model that misses
  something (a focal length, the distortion) or a-priori sigmas that are too small.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..block import Block

__all__ = ["Cleaning", "clean", "readmissible", "IMAGE_SHARE", "MISFIT_SCALE", "diagnosis"]

#: an image with more than this share of its observations rejected is left out of the adjustment
IMAGE_SHARE = 0.5
#: a robust scale above this (the bulk of the residuals this many times their a-priori sigma) is a model misfit
MISFIT_SCALE = 2.0
#: a share of gross errors above this is reported as heavy contamination
HEAVY_SHARE = 0.1
#: control is checked instead of used only this many times further off than an image point is rejected: a misfit of
#: the model shows at control points too, and a control point whose error is only moderate is left to the w-test of
#: the control group in the tests (:mod:`selfcal.workflows.tested`)
CONTROL_FACTOR = 3.0
#: the cleaning never leaves fewer control points than this (more are the tests' to demote)
MIN_CONTROL_LEFT = 5
#: a point none of whose rays kept this much weight in the robust adjustment is not determined by it
HOPELESS_WEIGHT = 0.01


@dataclass
class Cleaning:
    """What the robust cleaning found, by the rows (``Observations.row``) of the block as read."""

    loss: str
    c: float
    scale: float                                    # the robust scale at the end (1 = the a-priori sigmas)
    residual_scale: float                           # the residuals' own scale (trimmed MAD), below 1 where they fit
    reject: float                                   # the threshold, in robust sigmas
    rows: np.ndarray                                # every observation of the robust adjustment
    weight: np.ndarray                              # its final weight factor
    u: np.ndarray                                   # its normalised residual size
    rejected_rows: np.ndarray                       # rejected as gross errors (u > reject or in an image left out)
    images_left_out: list[str] = field(default_factory=list)
    control_demoted: list[tuple[str, float]] = field(default_factory=list)   # (point id, u)
    control_lost: list[str] = field(default_factory=list)   # gcp / chk whose rays all went
    iterations: int = 0
    messages: list[str] = field(default_factory=list)
    readmitted_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def apply(self, block: Block, prune: Callable[[Block], Block]) -> Block:
        """``block`` (the one the robust adjustment started from, or its like) without the rejected rows, with the
        control that was demoted checked instead, pruned by ``prune``."""
        keep = np.flatnonzero(~np.isin(block.observations.row, self.rejected_rows))
        roles = np.asarray(block.points.role).copy()
        where = {p: k for k, p in enumerate(block.points.point_id)}
        for name, _ in self.control_demoted:
            if name in where:
                roles[where[name]] = "chk"
        return prune(replace(block, observations=block.observations.take(keep), points=replace(block.points,
                                                                                                 role=roles)))

    def readmit(self, rows: np.ndarray) -> None:
        """Take ``rows`` back out of the rejected ones (they fit the cleaned adjustment)."""
        rows = np.asarray(rows, np.int64)
        self.readmitted_rows = np.union1d(self.readmitted_rows, rows)
        self.rejected_rows = np.setdiff1d(self.rejected_rows, rows)

    def revoke(self, why: str) -> None:
        """Take every rejection back (the rows, the images left out, the control checked instead): the cleaned
        block could not be adjusted (``why``); the record keeps the robust adjustment's weights and sizes."""
        self.readmit(self.rejected_rows)
        self.images_left_out, self.control_demoted, self.control_lost = [], [], []
        self.messages = [f"the robust cleaning's rejections are taken back: {why}"]

    @property
    def share(self) -> float:
        """The share of the image observations rejected."""
        return float(len(self.rejected_rows) / max(len(self.rows), 1))

    def as_dict(self) -> dict:
        """summary.json ``robust``."""
        return {"loss": self.loss, "c": self.c, "scale": self.scale, "residual_scale": self.residual_scale,
                "reject_u": self.reject,
                "n_rejected": int(len(self.rejected_rows)), "share_rejected": self.share,
                "images_left_out": list(self.images_left_out),
                "control_demoted": [{"point_id": p, "u": u} for p, u in self.control_demoted],
                "control_lost": list(self.control_lost), "iterations": self.iterations,
                "n_readmitted": int(len(self.readmitted_rows)),
                "diagnosis": diagnosis(self.scale, self.share)}


def diagnosis(scale: float, share: float) -> str:
    """``"clean"``, ``"contaminated"`` (many gross errors, the bulk fitting) or ``"misfit"`` (the bulk itself far
    above its a-priori sigma): see the module docstring."""
    if scale > MISFIT_SCALE:
        return "misfit"
    return "contaminated" if share > HEAVY_SHARE else "clean"


def clean(result, reject: float, prune: Callable[[Block], Block]) -> tuple[Block, Cleaning]:
    """The block of the robust adjustment ``result`` without what it found to be gross errors, pruned by ``prune``
    (a point left with one ray, an image with too few points), and the record of it (module docstring)."""
    weighting = result.robust
    problem = result.problem
    u_problem, u_control = weighting.normalised(problem, result.state)
    obs = result.block.observations
    u = np.empty(len(obs))
    u[problem.obs_order] = u_problem
    weight = np.empty(len(obs))
    weight[problem.obs_order] = problem.obs_weight
    gross = u > reject
    # a point that none of its rays determined in the robust adjustment (every weight below HOPELESS_WEIGHT: its
    # estimate floated along them) goes with all its rays: where it ended says nothing
    n_points = len(result.block.points)
    strongest = np.zeros(n_points)
    np.maximum.at(strongest, obs.point_index, weight)
    # (a control or check point's rays, measured by hand, are judged one by one)
    gross |= (strongest < HOPELESS_WEIGHT)[obs.point_index] & ~np.isin(result.block.points.role[obs.point_index],
                                                                       weighting.options.hand)
    messages: list[str] = []
    # images with most of their observations wrong
    n_img = len(result.block.images)
    share = np.bincount(obs.image_index, gross, minlength=n_img) / np.maximum(
        np.bincount(obs.image_index, minlength=n_img), 1)
    left_out = np.flatnonzero(share > IMAGE_SHARE)
    image_ids = [str(result.block.images.image_id[i]) for i in left_out]
    for i, name in zip(left_out, image_ids):
        messages.append(f"image '{name}' left out: {share[i]:.0%} of its observations are gross errors "
                        f"(more than {reject:g} robust sigmas)")
    gross |= np.isin(obs.image_index, left_out)
    # control points whose coordinates do not fit
    demoted: list[tuple[str, float]] = []
    points = result.block.points
    control = problem.control_index
    bad_control = np.flatnonzero(u_control > CONTROL_FACTOR * reject) if weighting.options.control else \
        np.zeros(0, np.int64)
    # the worst first, and never down to four or fewer control points (the datum)
    bad_control = bad_control[np.argsort(-u_control[bad_control])][:max(0, len(control) - MIN_CONTROL_LEFT)]
    for k in bad_control:
        p = control[k]
        demoted.append((str(points.point_id[p]), float(u_control[k])))
        messages.append(f"control point '{points.point_id[p]}' does not fit the block: its surveyed coordinates are "
                        f"{u_control[k]:.1f} robust sigmas off (a misidentified target? a typing error?); it is "
                        f"checked instead of used as control")
    cleaning = Cleaning(weighting.loss.name, weighting.loss.c, weighting.scale, weighting.residual_scale, reject,
                        obs.row.copy(), weight, u,
                        np.sort(obs.row[gross]), image_ids, demoted, [], result.iterations, messages)
    pruned = cleaning.apply(result.block, prune)
    lost = [str(p) for p, r in zip(points.point_id, points.role) if r in ("gcp", "chk")
            and p not in set(pruned.points.point_id.tolist())]
    for name in lost:
        messages.append(f"{'control' if name in set(points.point_id[control].tolist()) else 'check'} point "
                        f"'{name}' lost: the robust cleaning rejected its rays")
    cleaning.control_lost = lost
    what = diagnosis(cleaning.scale, cleaning.share)
    if what == "misfit":
        messages.append(f"the bulk of the image residuals is {cleaning.scale:.1f}x their a-priori sigma: the model "
                        f"does not fit the data (a focal length or the distortion not modelled?) or the a-priori "
                        f"sigma is too small; gross errors are judged against that bulk")
    elif what == "contaminated":
        messages.append(f"heavily contaminated: {cleaning.share:.1%} of the image observations are gross errors "
                        f"(more than {reject:g} robust sigmas, the bulk at {cleaning.scale:.2f}x the a-priori sigma); "
                        f"rejected before the tests")
    return pruned, cleaning


def readmissible(cleaning: Cleaning, block_read: Block, result) -> np.ndarray:
    """The rows rejected by ``cleaning`` that fit the least-squares adjustment ``result`` of the cleaned block: an
    image point whose residual at its estimate (predicted, as it is not in the adjustment) is below the cleaning's
    threshold in units of that adjustment's sigma0 (both coordinates together; the prediction's own error only makes
    it larger), of an image still in the adjustment: the good rays that a point's blunder pulled along in the
    robust adjustment. Taken back, they face Baarda's tests like every other observation.
    ``block_read``: a block that holds the rejected rows (the one cleaned)."""
    obs = block_read.observations
    sel = np.flatnonzero(np.isin(obs.row, cleaning.rejected_rows))
    if not sel.size:
        return np.zeros(0, np.int64)
    images = block_read.images.image_id[obs.image_index[sel]]
    pred = result.predict_pixels(images, block_read.points.point_id[obs.point_index[sel]])
    sigma = obs.sigma_px[sel] * float(np.sqrt(result.variance_factor))
    u = np.hypot(*(pred - obs.pixel[sel]).T) / sigma
    fits = np.isfinite(u) & (u < cleaning.reject) & ~np.isin(images, cleaning.images_left_out)
    return obs.row[sel[fits]]
