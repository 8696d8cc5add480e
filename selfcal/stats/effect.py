"""Practical significance: what a parameter does to the adjusted image coordinates over the observed area.

A t-test asks whether a parameter differs from zero; with 80,000 observations it answers yes for fields of a
hundredth of a pixel. What matters to a user is whether the parameter changes the adjustment's result: its *effect*
is the largest change of an adjusted image coordinate over the observed area, or of an adjusted point in ground
pixels (the metres one image pixel spans there), when the parameter is held at its reference value and every other
unknown (orientations, points, the interior orientation, the other additional parameters, the trajectory terms)
takes it up as far as it can. The points count because a field they absorb (a dome shared by the images) moves
them without moving a ray against them: on a simulated local + Brown block one WAP of 0.09 px effect on the rays
moved the check-point heights by 16 % of their RMSD. A parameter stays only if its effect reaches
:data:`MIN_EFFECT_PX`; the model choice asks the same of a model's gain in prediction
(:func:`selfcal.stats.prediction.simplest_within_one_se`).

The observed area is sampled (:func:`sample_positions`): in each cell of a grid over each camera's observations,
the rays of one well-observed point; the effect is the largest move of those rays' adjusted coordinates (their
points intersected again), computed for every parameter at once from the rows of the sampled rays and the
cofactor matrix, and kept through the screening's sweeps by rank-one updates (:class:`EffectTracker`).
"""
from __future__ import annotations

import numpy as np

from ..adjust.linalg import rank_one_update

__all__ = ["MIN_EFFECT_PX", "SAMPLE_CELLS", "EffectTracker", "effect_tracker", "sample_positions"]

#: a calibration parameter (or a model's gain) must move some adjusted image coordinate over the observed area by at
#: least this much (px): a tenth of a pixel, a fifth of the a-priori sigma of seed 000's image points and about
#: what a matcher's sub-pixel accuracy promises
MIN_EFFECT_PX = 0.1
#: cells of each camera's observed area (across, down) in which one ray is sampled for the effects: the rays of the
#: sampled points (about five each) stand for the observed area
SAMPLE_CELLS = (16, 12)


def sample_positions(problem, cells: tuple[int, int] = SAMPLE_CELLS) -> np.ndarray:
    """Positions (in the problem's point order) of the points whose rays sample each camera's observed area: in
    every cell of a grid over the box of the camera's observations that holds one, the point of the most rays
    among those observed there (control points and points of fewer than three rays only where no other is)."""
    counts = np.diff(problem.point_start)
    position = problem.point_positions()
    rays = counts[position[problem.obs_point]]
    role = problem.point_role[problem.obs_point] if problem.point_role is not None else None
    priority = rays + 1000 * ((rays >= 3) & (role != "gcp") if role is not None else (rays >= 3))
    cam_of = problem.image_camera[problem.obs_image]
    chosen = []
    for k in range(len(problem.cameras)):
        o = np.flatnonzero(cam_of == k)
        if not o.size:
            continue
        xy = problem.obs_value[o]
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        ij = np.clip(((xy - lo) / np.maximum(hi - lo, 1e-12) * np.array(cells)).astype(np.int64), 0,
                     np.array(cells) - 1)
        cell = ij[:, 1] * cells[0] + ij[:, 0]
        order = np.lexsort((-priority[o], cell))
        first = np.r_[True, cell[order][1:] != cell[order][:-1]]
        chosen.append(position[problem.obs_point[o[order[first]]]])
    return np.unique(np.concatenate(chosen)) if chosen else np.zeros(0, np.int64)


class EffectTracker:
    """The effects of holding each parameter, kept through the sweeps of a backward elimination.

    With Ã the projected rows of the sampled rays (:func:`selfcal.adjust.folds.projected_rows`) and Q the cofactor
    matrix of θ, holding θ_j at its reference moves θ by -Q[:, j] θ_j / Q_jj and the sampled rays by
    -G[:, j] θ_j / Q_jj, G = Ã Q; the sampled points by -G_p[:, j] θ_j / Q_jj, G_p = R Q (R their response to θ).
    A sweep that holds θ_i changes Q by -q q^T / q_ii and G by -G[:, i] q^T / q_ii (rank one, 2m n operations).

    A field the points absorb moves them without moving the rays against them (a dome shared by every image): the
    effect is therefore the larger of the rays' move (px) and the points' (in ground pixels: metres over the metres
    a pixel spans across a ray at the point), where the block's datum is fixed (by control or trajectory
    observations; in a free network the points' move includes the datum's)."""

    def __init__(self, rows: np.ndarray, px_per_unit: np.ndarray, Q: np.ndarray,
                 point_rows: np.ndarray | None = None, metres_per_px: np.ndarray | None = None):
        self.G = rows @ Q
        self.px = px_per_unit
        self.G_p = None if point_rows is None else point_rows @ Q
        self.metres_per_px = metres_per_px

    def drop(self, i: int, q: np.ndarray) -> None:
        """After ``q`` = Q[:, i] (before the sweep that holds θ_i)."""
        for G in (self.G, self.G_p):
            if G is not None:
                rank_one_update(G, -1.0 / q[i], G[:, i].copy(), q)
                G[:, i] = 0.0

    def move_px(self, i: int, theta: np.ndarray, q_diag: np.ndarray) -> np.ndarray:
        """The move of the sampled rays (px, x and y) and points (ground pixels, X, Y, Z) when θ_i is held, one
        vector (to add the moves of several drops)."""
        scale = theta[i] / q_diag[i]
        rays = self.G[:, i] * scale * self.px
        if self.G_p is None or self.metres_per_px is None:
            return rays
        points = (self.G_p[:, i] * scale).reshape(-1, 3) / self.metres_per_px[:, None]
        return np.concatenate([rays, points.ravel()])

    def largest_px(self, move: np.ndarray) -> float:
        """The largest ray or point move of a vector of :meth:`move_px`."""
        n_rays = len(self.G)
        rays = move[:n_rays].reshape(-1, 2)
        points = move[n_rays:].reshape(-1, 3)
        return float(max(np.sqrt((rays ** 2).sum(axis=1)).max(initial=0.0),
                         np.sqrt((points ** 2).sum(axis=1)).max(initial=0.0)))

    def effects_px(self, index: np.ndarray, theta: np.ndarray, q_diag: np.ndarray) -> np.ndarray:
        """The largest move of a sampled ray (px, x and y together) or point (ground pixels) when each of
        ``index`` is held."""
        scale = theta[index] / q_diag[index]
        shift = self.G[:, index] * scale[None, :] * self.px[:, None]
        out = np.sqrt(shift[0::2] ** 2 + shift[1::2] ** 2).max(axis=0) if len(shift) else np.zeros(len(index))
        if self.G_p is not None and self.metres_per_px is not None and len(self.G_p):
            move = (self.G_p[:, index] * scale[None, :]).reshape(-1, 3, len(index))
            out = np.maximum(out, (np.linalg.norm(move, axis=1) / self.metres_per_px[:, None]).max(axis=0))
        return out


def effect_tracker(result, Q: np.ndarray) -> EffectTracker | None:
    """The tracker of ``result``'s sampled rays (None: no point with two rays)."""
    from ..adjust.folds import projected_rows
    problem = result.problem
    positions = sample_positions(problem)
    counts = np.diff(problem.point_start)
    positions = positions[counts[positions] >= 2]
    if not positions.size:
        return None
    rows, o, response, metres = projected_rows(problem, result.state, positions)
    block_obs = result.block.observations
    sigma_px = block_obs.sigma_px[problem.obs_order[o]]
    px = (problem.obs_sigma[o] / problem.obs_sigma_apriori[o]) * sigma_px[:, None]
    if getattr(result, "datum_null", None) is not None:        # a free network: the points' move is the datum's too
        return EffectTracker(rows, px.ravel(), Q)
    counts = problem.point_start[positions + 1] - problem.point_start[positions]
    first = np.cumsum(counts) - counts                         # (a point's rays: the sigma of its first)
    return EffectTracker(rows, px.ravel(), Q, response, metres / sigma_px[first])
