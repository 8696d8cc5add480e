"""A-priori values of image and camera parameters as observations: seed 001's parameter weights, the interior
orientation's sigma in block.toml, an RPC's ``sigma_bias_px``, ``--ap-sigma-px``.

A free parameter with a finite a-priori sigma gets one row (value - prior) / sigma; a held one has none (its
correction is zero anyway). The rows follow the problem's current free masks, so screening, which holds
parameters, changes them.
"""
from __future__ import annotations

import numpy as np

from .base import ParameterResiduals, Triplets

__all__ = ["ParameterPriors", "from_block"]


class ParameterPriors(ParameterResiduals):
    """Priors on the free camera parameters (every camera, in order), then on the free image parameters."""

    group = "prior"

    def n_rows(self, problem) -> int:
        n = int(sum(np.sum(c.free & np.isfinite(c.prior_sigma)) for c in problem.cameras))
        return n + int(np.sum(problem.image_free & np.isfinite(problem.image_prior_sigma)))

    def labels(self, problem) -> list[str]:
        """"camera" for a-priori camera parameters, "image" for a-priori image parameters."""
        n_camera = int(sum(np.sum(c.free & np.isfinite(c.prior_sigma)) for c in problem.cameras))
        return ["camera"] * n_camera + ["image"] * (self.n_rows(problem) - n_camera)

    def triplets(self, problem, state, own_column: int, own_values: np.ndarray) -> Triplets:
        rows, cols, vals, res = [], [], [], []
        k = 0
        for cam, values, start in zip(problem.cameras, state.cameras, problem.d_offset):
            free_pos = np.cumsum(cam.free) - 1
            for i in np.flatnonzero(cam.free & np.isfinite(cam.prior_sigma)):
                sigma = cam.prior_sigma[i]
                rows.append(k)
                cols.append(start + free_pos[i])
                vals.append(1.0 / sigma)
                res.append((cam.prior_value[i] - values[i]) / sigma)
                k += 1
        weighted = np.flatnonzero((problem.image_free & np.isfinite(problem.image_prior_sigma)).ravel())
        if weighted.size:
            sigma = problem.image_prior_sigma.ravel()[weighted]
            rows += list(k + np.arange(weighted.size))
            cols += list(weighted)
            vals += list(1.0 / sigma)
            res += list((problem.image_prior_value.ravel()[weighted] - state.image.ravel()[weighted]) / sigma)
        return (np.array(rows, np.int64), np.array(cols, np.int64), np.array(vals, float), np.array(res, float))


def from_block(block, problem, settings) -> list[ParameterResiduals]:
    """One block of priors: the problem's a-priori sigmas decide which parameters have rows."""
    return [ParameterPriors()]
