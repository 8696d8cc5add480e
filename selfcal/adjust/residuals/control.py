"""Surveyed control coordinates as observations of their object points (weighted, not fixed).

Each ground control point's reference coordinates are three observations of its point with the survey's
covariance C: rows W (l - X) with W^T W = C^-1 (:func:`control_weights`). Their normal-equation terms go into
the point's 3x3 block before the points are eliminated.
"""
from __future__ import annotations

import numpy as np

from ...block import Block
from .base import PointResiduals

__all__ = ["ControlCoordinates", "control_weights", "from_block"]


class ControlCoordinates(PointResiduals):
    """The reference coordinates ``xyz`` (n, 3) of the control points ``index`` with their weights ``W``
    (n, 3, 3)."""

    group = "GCP"
    width = 3

    def __init__(self, index: np.ndarray, xyz: np.ndarray, W: np.ndarray):
        super().__init__(index)
        self.xyz = np.asarray(xyz, float)
        self.W = np.asarray(W, float)

    def whitened_rows(self, points: np.ndarray, sel=slice(None)) -> tuple[np.ndarray, np.ndarray]:
        W = self.W[sel]
        return np.einsum("nij,nj->ni", W, self.xyz[sel] - points), W


def from_block(block: Block, problem, settings) -> list[PointResiduals]:
    """The block's ``gcp`` points as one :class:`ControlCoordinates` block (empty without control)."""
    control = np.flatnonzero(block.points.role == "gcp")
    frame = settings.object_frame
    return [ControlCoordinates(control, block.points.xyz_m[control], control_weights(block, control, frame))]


def control_weights(block: Block, control: np.ndarray, object_frame: str) -> np.ndarray:
    """W (n, 3, 3) with W^T W the inverse covariance of each control point: diagonal in the block's axes (or in
    the axes ``Points.sigma_axes`` gives: rows diag(1 / sigma) times them), or,
    for points in an Earth- or body-fixed frame, diag(1 / sigma) times the local east, north and up (the WGS 84
    normal on the Earth, the radial direction of a body: ``crs = "body-fixed"``) at the point, so that a
    coordinate held loosely (sigma 1e6 m) and one held tightly do not meet in one inverted covariance."""
    sigma = block.points.sigma_m[control]
    if object_frame != "ECEF":
        axes = block.points.sigma_axes
        if axes is not None:        # sigma along other axes (a block in its CRS's tangent plane: the CRS's)
            return np.einsum("ni,nij->nij", 1.0 / sigma, axes[control])
        return np.einsum("ni,ij->nij", 1.0 / sigma, np.eye(3))
    xyz = block.points.xyz_m[control]
    if block.crs == "body-fixed":
        from ...geometry.body import latlon_radius_from_xyz, north_east_radial
        lat, lon, _ = latlon_radius_from_xyz(xyz)
        frame = north_east_radial(lat, lon)[:, :, [1, 0, 2]]          # columns east, north, radial
    else:
        from ...geometry.earth import geodetic_from_ecef, local_up
        lat, lon, _ = geodetic_from_ecef(xyz)
        up = local_up(lat, lon)
        east = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], -1)
        frame = np.stack([east, np.cross(up, east), up], -1)
    return np.einsum("ni,nki->nik", 1.0 / sigma, frame)

