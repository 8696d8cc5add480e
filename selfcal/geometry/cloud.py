"""A ground point cloud (lidar, a survey) as a terrain surface: the height at a place from a plane fitted to the
nearest cloud points (issue 42; DESIGN-NOTES "Terrain as observations").

:class:`CloudSurface` answers as :class:`~selfcal.geometry.terrain.GridDem` does (heights, their slope, whether a
place is covered), so the terrain observations take either. Neighbours are searched in a local east/north frame
(metres, equirectangular about the cloud's centre: within a scene the scale error is far below a cloud's spacing).
"""
from __future__ import annotations

import numpy as np

__all__ = ["CloudSurface", "NEIGHBOURS"]

#: cloud points in each local plane fit
NEIGHBOURS = 8
_R_M = 6_371_000.0          # (the local frame's scale: m per radian; only the neighbour search and slopes use it)


class CloudSurface:
    """Ellipsoidal heights ``h_m`` at ``lat_deg``, ``lon_deg`` (n,) of ground points; the height at a place is the
    value there of the least-squares plane through its ``k`` nearest points. A place is covered where its nearest
    point lies within ``max_gap_m`` (default: five times the median distance between neighbouring points: a
    random cloud of that density leaves a gap that wide at one place in ten million)."""

    def __init__(self, lat_deg, lon_deg, h_m, k: int = NEIGHBOURS, max_gap_m: float | None = None):
        from scipy.spatial import cKDTree
        self.lat_deg, self.lon_deg, self.h_m = (np.asarray(v, float).ravel() for v in (lat_deg, lon_deg, h_m))
        if not len(self.h_m) >= max(k, 3):
            raise ValueError(f"a point cloud of {len(self.h_m)} points: at least {max(k, 3)} are needed for its "
                             f"plane fits")
        self.k = int(k)
        self.lat0, self.lon0 = float(np.mean(self.lat_deg)), float(np.mean(self.lon_deg))
        self._scale = np.array([np.radians(1.0) * _R_M * np.cos(np.radians(self.lat0)), np.radians(1.0) * _R_M])
        self._tree = cKDTree(self._local(self.lat_deg, self.lon_deg))
        if max_gap_m is None:
            spacing = np.asarray(self._tree.query(self._tree.data, k=2)[0])
            max_gap_m = 5.0 * float(np.median(spacing[:, 1]))
        self.max_gap_m = float(max_gap_m)

    @classmethod
    def from_ecef(cls, xyz_m: np.ndarray, **kwargs) -> "CloudSurface":
        """The surface of ground points given in ECEF (n, 3), m (WGS 84)."""
        from .earth import geodetic_from_ecef
        lat, lon, h = geodetic_from_ecef(np.asarray(xyz_m, float).reshape(-1, 3))
        return cls(np.degrees(lat), np.degrees(lon), h, **kwargs)

    def _local(self, lat_deg, lon_deg) -> np.ndarray:
        """East, north (m) about the cloud's centre, (n, 2)."""
        return np.column_stack([(np.ravel(lon_deg) - self.lon0) * self._scale[0],
                                (np.ravel(lat_deg) - self.lat0) * self._scale[1]])

    def _planes(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The plane at each place: height there and slopes dh/deast, dh/dnorth (m per m)."""
        shape = np.shape(lat_deg)
        at = self._local(lat_deg, lon_deg)
        _, near = self._tree.query(at, k=self.k)
        d = self._tree.data[near] - at[:, None, :]                  # (n, k, 2) neighbours about the place
        A = np.concatenate([np.ones(d.shape[:2] + (1,)), d], axis=2)
        rhs = np.einsum("nki,nk->ni", A, self.h_m[near])
        coef = np.linalg.solve(np.einsum("nki,nkj->nij", A, A), rhs[..., None])[..., 0]
        return coef[:, 0].reshape(shape), coef[:, 1].reshape(shape), coef[:, 2].reshape(shape)

    def __call__(self, lat_deg, lon_deg) -> np.ndarray:
        return self._planes(lat_deg, lon_deg)[0]

    def gradient(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        """(dh/dlat, dh/dlon) in m per degree: the fitted plane's slope (the neighbours held)."""
        _, east, north = self._planes(lat_deg, lon_deg)
        return north * self._scale[1], east * self._scale[0]

    def covers(self, lat_deg, lon_deg) -> np.ndarray:
        """Whether the nearest cloud point lies within ``max_gap_m`` of each place."""
        distance, _ = self._tree.query(self._local(lat_deg, lon_deg), k=1)
        return np.reshape(distance <= self.max_gap_m, np.shape(lat_deg))
