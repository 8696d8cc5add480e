"""Terrain heights from a DEM as observations of tie points (issue 42; DESIGN-NOTES "Terrain as observations").

Each observed tie point X (ECEF) has one row: its ellipsoidal height above the DEM's height at its own latitude and
longitude, observed as zero with the DEM's sigma,

    f(X) = h(X) - H(lat(X), lon(X)),    l = 0,    whitened residual (l - f) / sigma,

where H is the DEM's bilinear interpolation between cell centres (:class:`~selfcal.geometry.terrain.GridDem`). Its
Jacobian is (up - dH/dlat dlat/dX - dH/dlon dlon/dX) / sigma: the ellipsoid normal less the DEM's slope carried
through d(lat, lon)/dX (:func:`~selfcal.geometry.earth.geodetic_jacobian`), so a point on a slope is pulled along
the slope as well as up. The rows are the group "terrain" of the variance components and of the w-tests.
"""
from __future__ import annotations

import numpy as np

from ...block import Block
from ...errors import UsageError
from ...geometry.earth import geodetic_from_ecef, geodetic_jacobian
from .base import PointResiduals

__all__ = ["TerrainHeights", "from_block", "terrain_frame_problem", "terrain_candidates"]


class TerrainHeights(PointResiduals):
    """The DEM heights ``dem`` of the tie points ``index``, each with its sigma ``sigma_m`` (n,)."""

    group = "terrain"
    width = 1

    def __init__(self, index: np.ndarray, dem, sigma_m: "float | np.ndarray"):
        super().__init__(index)
        self.dem = dem
        self.sigma_m = np.broadcast_to(np.asarray(sigma_m, float), (len(self.index),)).copy()

    def heights(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points' ellipsoidal heights h and the DEM's H at their latitude and longitude (m)."""
        lat, lon, h = geodetic_from_ecef(np.atleast_2d(points))
        return h, self.dem(np.degrees(lat), np.degrees(lon))

    def whitened_rows(self, points: np.ndarray, sel=slice(None)) -> tuple[np.ndarray, np.ndarray]:
        sigma = self.sigma_m[sel]
        points = np.atleast_2d(points)
        lat, lon, h = geodetic_from_ecef(points)
        lat_deg, lon_deg = np.degrees(lat), np.degrees(lon)
        d_lat, d_lon = self.dem.gradient(lat_deg, lon_deg)               # m per degree
        G = geodetic_jacobian(points)                                    # rows d(lat, lon, h)/dX, radians
        dfdX = G[:, 2] - np.degrees(1.0) * (d_lat[:, None] * G[:, 0] + d_lon[:, None] * G[:, 1])
        r = (self.dem(lat_deg, lon_deg) - h) / sigma
        return r[:, None], (dfdX / sigma[:, None])[:, None, :]


def terrain_frame_problem(block: Block, object_frame: str) -> str | None:
    """Why the block's points cannot take terrain observations (None: they can): the DEM holds ellipsoidal heights
    over WGS 84 latitude and longitude, which only points in ECEF on the Earth have."""
    if object_frame != "ECEF":
        return (f"terrain observations need points in ECEF (pushbroom, RPC and satellite line sensors); this block's "
                f"points are in {block.crs} (frame cameras): not built")
    if block.crs == "body-fixed" or block.crs.upper().startswith("IAU"):
        return (f"terrain observations need heights over WGS 84; this block is on a planetary body (crs "
                f"{block.crs}): not built")
    return None


def terrain_candidates(block: Block, dem, xyz_m: np.ndarray) -> np.ndarray:
    """Indices of the block's tie points whose coordinates ``xyz_m`` (n_points, 3, ECEF; NaN unknown) are known
    and lie on the DEM (between its outermost cell centres)."""
    tie = np.flatnonzero((np.asarray(block.points.role) == "tie") & np.isfinite(xyz_m).all(axis=1))
    if not tie.size:
        return tie
    lat, lon, _ = geodetic_from_ecef(xyz_m[tie])
    return tie[dem.covers(np.degrees(lat), np.degrees(lon))]


def from_block(block: Block, problem, settings) -> list[PointResiduals]:
    """The block's terrain observations (:class:`~selfcal.block.TerrainObservations`) as one
    :class:`TerrainHeights` block; none without them. Only tie points take them (control and check points stay
    independent of the DEM); a point without a terrain row is one the tests rejected or one off the DEM."""
    terrain = block.terrain_observations
    if terrain is None:
        return []
    why = terrain_frame_problem(block, settings.object_frame)
    if why is not None:
        raise UsageError(why)
    ids = terrain.observed_ids()
    if ids is None:
        index = terrain_candidates(block, terrain.dem, block.points.xyz_m)
    else:
        index = np.flatnonzero(np.isin(block.points.point_id, list(ids)) & (np.asarray(block.points.role) == "tie"))
    return [TerrainHeights(index, terrain.dem, terrain.sigma_m)]
