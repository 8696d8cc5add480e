"""The kinds of observations of an adjustment, as residual blocks (:mod:`.base`), found in one registry.

:data:`RESIDUALS` maps a kind's name to its builder ``(block, problem, settings) -> list of blocks``; the
problem holds the blocks they return (``Problem.residuals``) in the registry's order, and the Schur assembly,
the cost, the reliability and the variance components iterate over them. A new kind of observation is one
module here and one line in :data:`RESIDUALS`. The image observations, which couple images, cameras and
points, are the structure itself (:mod:`.image`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..options import TrajectoryOptions
from . import control, priors, terrain, trajectory
from .base import ParameterResiduals, PointResiduals, Triplets

__all__ = ["RESIDUALS", "ResidualSettings", "PointResiduals", "ParameterResiduals", "Triplets", "build_residuals",
           "parameter_observations", "parameter_observation_groups"]


@dataclass(frozen=True)
class ResidualSettings:
    """What the builders are told of the adjustment: the object frame of the block's sensors ("block" or "ECEF")
    and the trajectory's options (the order of the GNSS/IMU shift/drift, whether the GNSS lever arm and the IMU
    boresight angles are estimated)."""

    object_frame: str = "block"
    trajectory: TrajectoryOptions = field(default_factory=TrajectoryOptions)


#: kind name -> builder (block, problem, settings) -> list of residual blocks, in the order of theta's x part
RESIDUALS: dict[str, Callable] = {
    "control": control.from_block,
    "terrain": terrain.from_block,
    "priors": priors.from_block,
    "trajectory": trajectory.from_block,
}


def build_residuals(block, problem, settings: ResidualSettings) -> list:
    """Every registered kind's blocks for ``problem``, in the registry's order."""
    return [b for build in RESIDUALS.values() for b in build(block, problem, settings)]


def parameter_observations(problem, state) -> tuple[sp.csr_matrix, np.ndarray]:
    """Whitened Jacobian (k, n_theta) and residuals l - f of every parameter block, stacked in the problem's
    order of the blocks."""
    rows, cols, vals, res = [], [], [], []
    k = 0
    x_col = problem.n_e + problem.n_d
    x_full = 0
    for block in problem.parameter_residuals:
        n_own = block.n_params
        n_free = int(np.sum(block.free)) if n_own else 0
        if block.n_rows(problem):
            r, c, v, e = block.triplets(problem, state, x_col, state.extra[x_full:x_full + n_own])
            rows.append(r + k)
            cols.append(c)
            vals.append(v)
            res.append(e)
            k += len(e)
        x_col += n_free
        x_full += n_own
    if k == 0:
        return sp.csr_matrix((0, problem.n_theta)), np.zeros(0)
    return (sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(k, problem.n_theta)), np.concatenate(res))


def parameter_observation_groups(problem) -> np.ndarray:
    """The group of each row of :func:`parameter_observations`: "camera" for a-priori camera parameters,
    "image" for a-priori image parameters, else the block's group (the trajectory sensor: "GNSS", "IMU")."""
    labels: list[str] = []
    for block in problem.parameter_residuals:
        labels += block.labels(problem)
    return np.array(labels, dtype=object)
