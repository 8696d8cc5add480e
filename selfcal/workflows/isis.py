"""``selfcal import isis``: an ISIS control network and its images' ISDs as a block folder, with jigsaw's options.

jigsaw's ``radius=no`` holds each Free point's radius where the a-priori point was put (on a DEM) and
estimates its latitude and longitude. A network whose Free points carry no a-priori coordinates (the LRO
NAC pair of ISIS's tests) gets them from the engine's initial values (the rays intersected, or, where they
meet at too small an angle, the first ray on the median radius of the points with coordinates); the points
then keep that radius within the given sigma.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..adjust import start_values
from ..block import Block
from ..convert import FREE_SIGMA_M

__all__ = ["hold_radii"]


def hold_radii(block: Block, sigma_m: float) -> Block:
    """``block`` (read, with its sensor descriptions) with every tie point a control point that keeps its start
    radius within ``sigma_m`` (m) and its latitude and longitude free (jigsaw's ``radius=no``)."""
    state = start_values(block)
    tie = block.points.role == "tie"
    xyz = np.where(tie[:, None], state.points, block.points.xyz_m)
    sigma = np.where(tie[:, None], np.array([FREE_SIGMA_M, FREE_SIGMA_M, sigma_m]), block.points.sigma_m)
    role = np.where(tie, "gcp", block.points.role).astype(object)
    return replace(block, points=replace(block.points, role=role, xyz_m=xyz, sigma_m=sigma))
