"""The Earth: inertial and Earth-fixed frames (pyerfa), the WGS 84 ellipsoid, the orbit frame.

Conventions of DESIGN.md §3: ECI is the GCRS, ECEF the ITRS; GCRS -> ITRS by the IAU
2006/2000A model (``erfa.c2t06a``) with UT1 = UTC and zero polar motion unless
given. The orbit frame of a satellite at position r and velocity v has
z_o = -r/|r| (towards the Earth's centre), y_o = -(r x v)/|r x v| and
x_o = y_o x z_o (about along track).
"""
from __future__ import annotations

import functools
from datetime import datetime, timezone

import erfa
import numpy as np

__all__ = ["horizon_covariance", "geodetic_jacobian", "WGS84_A_M", "WGS84_F", "utc_two_part", "itrs_from_gcrs", "orbit_frame",
           "ecef_from_geodetic", "geodetic_from_ecef", "local_up", "intersect_ellipsoid"]

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)

SECONDS_PER_DAY = 86400.0


def utc_two_part(epoch_utc: str) -> tuple[float, float]:
    """The two-part Julian date (UTC) of an ISO 8601 instant, e.g. ``2007-05-12T01:45:00Z``."""
    moment = datetime.fromisoformat(epoch_utc.replace("Z", "+00:00"))
    if moment.tzinfo is not None:
        moment = moment.astimezone(timezone.utc)
    seconds = moment.second + moment.microsecond * 1e-6
    return erfa.dtf2d("UTC", moment.year, moment.month, moment.day, moment.hour, moment.minute, seconds)


#: GCRS -> ITRS is computed at whole multiples of this (s) and interpolated between them (slerp): within a
#: second the rotation is the Earth's about a fixed axis at a constant rate, which slerp reproduces, and
#: precession-nutation moves by ~1e-11 rad (tests/test_geometry.py: 1e-12 rad against the direct value)
NODE_SPACING_S = 1.0


def itrs_from_gcrs(epoch_utc: str, time_s, dut1_s: float = 0.0, polar_motion_rad=(0.0, 0.0),
                   exact: bool = False) -> np.ndarray:
    """Rotation matrices (n, 3, 3) taking GCRS (ECI) vectors to the ITRS (ECEF) at ``epoch_utc + time_s``.

    IAU 2006/2000A, CIO based (``erfa.c2t06a``); UT1 = UTC + ``dut1_s``. Many instants (the lines of a
    pushbroom image) are interpolated between whole seconds (:data:`NODE_SPACING_S`); ``exact`` evaluates
    every instant.
    """
    t = np.atleast_1d(np.asarray(time_s, float))
    if exact or t.size <= 16 or not np.all(np.isfinite(t)):
        return _itrs_from_gcrs(epoch_utc, t, dut1_s, tuple(polar_motion_rad))
    from .rotation import matrix_from_quaternion, slerp
    first = int(np.floor(t.min() / NODE_SPACING_S)) - 1
    last = int(np.ceil(t.max() / NODE_SPACING_S)) + 1
    nodes, q = _itrs_nodes(epoch_utc, first, last, float(dut1_s), tuple(polar_motion_rad))
    return matrix_from_quaternion(slerp(nodes, q, t))


@functools.lru_cache(maxsize=128)
def _itrs_nodes(epoch_utc: str, first: int, last: int, dut1_s: float, polar_motion_rad: tuple):
    from .rotation import quaternion_from_matrix
    nodes = np.arange(first, last + 1) * NODE_SPACING_S
    return nodes, quaternion_from_matrix(_itrs_from_gcrs(epoch_utc, nodes, dut1_s, polar_motion_rad))


def _itrs_from_gcrs(epoch_utc: str, t: np.ndarray, dut1_s: float, polar_motion_rad: tuple) -> np.ndarray:
    u1, u2 = utc_two_part(epoch_utc)
    utc2 = u2 + t / SECONDS_PER_DAY
    tai1, tai2 = erfa.utctai(u1, utc2)
    tt1, tt2 = erfa.taitt(tai1, tai2)
    ut1_2 = utc2 + dut1_s / SECONDS_PER_DAY
    return erfa.c2t06a(tt1, tt2, u1, ut1_2, polar_motion_rad[0], polar_motion_rad[1])


def orbit_frame(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """R_FO (n, 3, 3): the orbit frame's axes x_o, y_o, z_o as columns, in the frame of r and v."""
    r = np.atleast_2d(position)
    v = np.atleast_2d(velocity)
    z = -r / np.linalg.norm(r, axis=1, keepdims=True)
    h = np.cross(r, v)
    y = -h / np.linalg.norm(h, axis=1, keepdims=True)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=2)


def ecef_from_geodetic(lat_rad, lon_rad, height_m, semi_major_m: float = WGS84_A_M,
                       flattening: float = WGS84_F) -> np.ndarray:
    """Geodetic latitude, longitude (radians) and ellipsoidal height (m) to Earth-centred Cartesian metres
    (n, 3), on WGS 84 or the ellipsoid of ``semi_major_m`` and ``flattening``."""
    lat, lon, h = np.broadcast_arrays(np.asarray(lat_rad, float), np.asarray(lon_rad, float),
                                      np.asarray(height_m, float))
    e2 = flattening * (2.0 - flattening)
    n = semi_major_m / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - e2) + h) * np.sin(lat)], axis=-1)


def geodetic_from_ecef(xyz: np.ndarray, semi_major_m: float = WGS84_A_M,
                       flattening: float = WGS84_F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Earth-centred metres (..., 3) to latitude, longitude (radians) and height (m) on WGS 84 or the
    ellipsoid of ``semi_major_m`` and ``flattening``.

    Bowring's iteration on the parametric latitude; four iterations reach 1e-12 rad
    anywhere near the Earth's surface.
    """
    xyz = np.asarray(xyz, float)
    e2 = flattening * (2.0 - flattening)
    b = semi_major_m * (1.0 - flattening)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    ep2 = e2 / (1.0 - e2)
    beta = np.arctan2(z, (1.0 - flattening) * p)
    for _ in range(4):
        lat = np.arctan2(z + ep2 * b * np.sin(beta) ** 3, p - e2 * semi_major_m * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - flattening) * np.sin(lat), np.cos(lat))
    n = semi_major_m / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    cos_lat, sin_lat = np.cos(lat), np.sin(lat)
    # height from the better conditioned of the two forms (near the poles: from z)
    near_pole = np.abs(cos_lat) < 1e-3
    h = np.where(near_pole, z / np.where(near_pole, sin_lat, 1.0) - n * (1.0 - e2),
                 p / np.where(near_pole, 1.0, cos_lat) - n)
    return lat, lon, h


def local_up(lat_rad, lon_rad) -> np.ndarray:
    """Unit ellipsoid normals (n, 3) in ECEF."""
    lat, lon = np.asarray(lat_rad, float), np.asarray(lon_rad, float)
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def intersect_ellipsoid(origins: np.ndarray, directions: np.ndarray, semi_major_m: float, semi_minor_m: float
                        ) -> np.ndarray:
    """The first point (n, 3) where rays S + s d (s > 0) meet the ellipsoid of revolution
    (x² + y²)/a² + z²/b² = 1 (any body: usgscsm's ``imageToGround`` at height h uses a + h, b + h);
    NaN where a ray misses it."""
    S = np.atleast_2d(np.asarray(origins, float))
    d = np.atleast_2d(np.asarray(directions, float))
    scale = np.array([1.0 / semi_major_m, 1.0 / semi_major_m, 1.0 / semi_minor_m])
    Ss, ds = S * scale, d * scale                      # the ellipsoid becomes the unit sphere
    a = np.einsum("ni,ni->n", ds, ds)
    b = np.einsum("ni,ni->n", Ss, ds)
    c = np.einsum("ni,ni->n", Ss, Ss) - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        s = (-b - np.sqrt(disc)) / a
    s[(disc < 0) | (s < 0)] = np.nan
    return S + s[:, None] * d


def horizon_covariance(ecef: np.ndarray, sigma_enu: np.ndarray) -> np.ndarray:
    """Covariances (n, 3, 3) in ECEF (m²) of points whose standard deviations are given along east,
    north and up of the local horizon (n, 3)."""
    lat, lon, _ = geodetic_from_ecef(np.atleast_2d(ecef))
    up = local_up(lat, lon)
    east = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], -1)
    north = np.cross(up, east)
    R = np.stack([east, north, up], -1)                       # columns: east, north, up
    return np.einsum("nij,nj,nkj->nik", R, np.atleast_2d(sigma_enu) ** 2, R)


def geodetic_jacobian(xyz: np.ndarray) -> np.ndarray:
    """d(lat, lon, h)/d(X, Y, Z) (n, 3, 3) at ECEF points (latitude and longitude in radians): the rows are
    north / (M + h), east / ((N + h) cos lat) and up, with M and N the meridian and prime-vertical radii of
    curvature of WGS 84 (the unit vectors are orthonormal, so the inverse of dECEF/d(lat, lon, h) is this)."""
    lat, lon, h = geodetic_from_ecef(np.atleast_2d(xyz))
    s, c = np.sin(lat), np.cos(lat)
    w = np.sqrt(1.0 - _E2 * s * s)
    n = WGS84_A_M / w
    m = WGS84_A_M * (1.0 - _E2) / w ** 3
    north = np.stack([-s * np.cos(lon), -s * np.sin(lon), c], -1)
    east = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], -1)
    up = local_up(lat, lon)
    return np.stack([north / (m + h)[:, None], east / ((n + h) * c)[:, None], up], axis=1)
