"""Planetocentric coordinates of a body (the Moon as ISIS and usgscsm use it) and their covariances.

Body-fixed X, Y, Z in metres; planetocentric latitude and longitude (radians; longitude positive east,
as ``atan2(Y, X)``) and the local radius ``|X|``. ISIS states a point's a-priori precision as sigmas of
latitude and longitude *in metres on the surface* and of the radius: the latitude sigma is along the
local north (``R dlat``), the longitude sigma along the local east (``R cos(lat) dlon``), the radius sigma
along the radial direction (ISIS ``SurfacePoint``, with the local radius since 2018). Its
``AprioriCovarianceMatrix`` is that covariance turned into X, Y, Z (m²): C_xyz = A diag(σN², σE², σR²) Aᵀ
with A = [north, east, radial] as columns.
"""
from __future__ import annotations

import numpy as np

__all__ = ["is_body_fixed", "latlon_radius_from_xyz", "xyz_from_latlon_radius", "north_east_radial", "covariance_from_sigmas",
           "sigmas_from_covariance"]


def is_body_fixed(crs: str) -> bool:
    """Whether a block's ``crs`` names a body-fixed frame of a planetary body: ``body-fixed`` (ISIS imports)
    or an IAU CRS (``IAU_2015:30100``) of a block whose sensors work in Cartesian body-fixed metres."""
    return crs.strip() == "body-fixed" or crs.strip().upper().startswith("IAU")


def latlon_radius_from_xyz(xyz_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planetocentric latitude, longitude (radians, longitude in (-pi, pi]) and radius (m) of points (..., 3)."""
    xyz = np.asarray(xyz_m, float)
    radius = np.linalg.norm(xyz, axis=-1)
    lat = np.arcsin(np.clip(xyz[..., 2] / radius, -1.0, 1.0))
    lon = np.arctan2(xyz[..., 1], xyz[..., 0])
    return lat, lon, radius


def xyz_from_latlon_radius(lat_rad, lon_rad, radius_m) -> np.ndarray:
    """Body-fixed points (..., 3) of planetocentric latitude, longitude (radians) and radius (m)."""
    lat, lon, r = np.broadcast_arrays(np.asarray(lat_rad, float), np.asarray(lon_rad, float),
                                      np.asarray(radius_m, float))
    return np.stack([r * np.cos(lat) * np.cos(lon), r * np.cos(lat) * np.sin(lon), r * np.sin(lat)], axis=-1)


def north_east_radial(lat_rad, lon_rad) -> np.ndarray:
    """Matrices (..., 3, 3) whose *columns* are the local north, east and radial unit vectors."""
    lat, lon = np.broadcast_arrays(np.asarray(lat_rad, float), np.asarray(lon_rad, float))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    north = np.stack([-sl * co, -sl * so, cl], -1)
    east = np.stack([-so, co, np.zeros_like(lat)], -1)
    radial = np.stack([cl * co, cl * so, sl], -1)
    return np.stack([north, east, radial], axis=-1)


def covariance_from_sigmas(xyz_m, sigma_lat_m, sigma_lon_m, sigma_radius_m) -> np.ndarray:
    """Body-fixed covariance (..., 3, 3), m², of ISIS's latitude, longitude and radius sigmas (m) at points."""
    lat, lon, _ = latlon_radius_from_xyz(xyz_m)
    A = north_east_radial(lat, lon)
    s = np.stack(np.broadcast_arrays(np.asarray(sigma_lat_m, float), np.asarray(sigma_lon_m, float),
                                     np.asarray(sigma_radius_m, float)), -1)
    return np.einsum("...ik,...k,...jk->...ij", A, s * s, A)


def sigmas_from_covariance(xyz_m, covariance_m2) -> np.ndarray:
    """ISIS's latitude, longitude and radius sigmas (..., 3), m, of a body-fixed covariance at points: the
    square roots of the diagonal of the covariance turned into north, east, radial."""
    lat, lon, _ = latlon_radius_from_xyz(xyz_m)
    A = north_east_radial(lat, lon)
    local = np.einsum("...ki,...kl,...lj->...ij", A, np.asarray(covariance_m2, float), A)
    return np.sqrt(np.einsum("...ii->...i", local))

