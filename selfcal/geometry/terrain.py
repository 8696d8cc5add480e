"""Terrain heights on a regular grid (a DEM), interpolated bilinearly."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GridDem"]


@dataclass(frozen=True)
class GridDem:
    """Ellipsoidal heights (m) on a north-up grid of geographic coordinates (EPSG:4326).

    ``transform`` is the affine (a, b, c, d, e, f) of GDAL/rasterio: lon = c + a (col + 0.5)
    and lat = f + e (row + 0.5) at the centre of cell (row, col); no rotation (b = d = 0).
    Heights are interpolated bilinearly between cell centres; outside the grid the nearest
    edge value is used.
    """

    heights_m: np.ndarray
    transform: tuple[float, float, float, float, float, float]

    def __post_init__(self):
        a, b, c, d, e, f = self.transform
        if b != 0 or d != 0:
            raise ValueError("a rotated DEM grid is not supported")
        if a <= 0 or e >= 0:
            raise ValueError("the DEM grid must be north-up (pixel width > 0, height < 0)")

    def __call__(self, lat_deg, lon_deg) -> np.ndarray:
        a, _, c, _, e, f = self.transform
        rows, cols = self.heights_m.shape
        x = np.clip((np.asarray(lon_deg, float) - c) / a - 0.5, 0.0, cols - 1.0)
        y = np.clip((np.asarray(lat_deg, float) - f) / e - 0.5, 0.0, rows - 1.0)
        x0 = np.minimum(np.floor(x).astype(int), cols - 2)
        y0 = np.minimum(np.floor(y).astype(int), rows - 2)
        fx, fy = x - x0, y - y0
        h = self.heights_m
        return ((1 - fy) * ((1 - fx) * h[y0, x0] + fx * h[y0, x0 + 1])
                + fy * ((1 - fx) * h[y0 + 1, x0] + fx * h[y0 + 1, x0 + 1]))
