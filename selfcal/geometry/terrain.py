"""Terrain heights on a regular grid (a DEM), interpolated bilinearly."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GridDem", "VERTICAL_DATUMS", "ellipsoidal_dem"]


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

    def _cells(self, lat_deg, lon_deg):
        """Column and row positions (between cell centres, clamped to the grid), the cell's corner and the
        fractions within it."""
        a, _, c, _, e, f = self.transform
        rows, cols = self.heights_m.shape
        x = np.clip((np.asarray(lon_deg, float) - c) / a - 0.5, 0.0, cols - 1.0)
        y = np.clip((np.asarray(lat_deg, float) - f) / e - 0.5, 0.0, rows - 1.0)
        x0 = np.minimum(np.floor(x).astype(int), cols - 2)
        y0 = np.minimum(np.floor(y).astype(int), rows - 2)
        return x0, y0, x - x0, y - y0

    def __call__(self, lat_deg, lon_deg) -> np.ndarray:
        x0, y0, fx, fy = self._cells(lat_deg, lon_deg)
        h = self.heights_m
        return ((1 - fy) * ((1 - fx) * h[y0, x0] + fx * h[y0, x0 + 1])
                + fy * ((1 - fx) * h[y0 + 1, x0] + fx * h[y0 + 1, x0 + 1]))

    def gradient(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        """The slope of the interpolated heights: (dh/dlat, dh/dlon) in m per degree, the derivative of
        :meth:`__call__` (within a cell; 0 across an edge where the heights are clamped)."""
        a, _, c, _, e, f = self.transform
        rows, cols = self.heights_m.shape
        x0, y0, fx, fy = self._cells(lat_deg, lon_deg)
        h = self.heights_m
        d_col = (1 - fy) * (h[y0, x0 + 1] - h[y0, x0]) + fy * (h[y0 + 1, x0 + 1] - h[y0 + 1, x0])
        d_row = (1 - fx) * (h[y0 + 1, x0] - h[y0, x0]) + fx * (h[y0 + 1, x0 + 1] - h[y0, x0 + 1])
        x = (np.asarray(lon_deg, float) - c) / a - 0.5
        y = (np.asarray(lat_deg, float) - f) / e - 0.5
        d_col = np.where((x < 0) | (x > cols - 1), 0.0, d_col)
        d_row = np.where((y < 0) | (y > rows - 1), 0.0, d_row)
        return d_row / e, d_col / a

    def covers(self, lat_deg, lon_deg) -> np.ndarray:
        """Whether each position lies between the outermost cell centres (where the heights are interpolated,
        not the edge's carried on)."""
        a, _, c, _, e, f = self.transform
        rows, cols = self.heights_m.shape
        x = (np.asarray(lon_deg, float) - c) / a - 0.5
        y = (np.asarray(lat_deg, float) - f) / e - 0.5
        return (x >= 0) & (x <= cols - 1) & (y >= 0) & (y <= rows - 1)


#: the vertical datums a DEM's heights may be given in (``selfcal adjust --terrain-datum``): the EPSG code of the
#: geoid's height, None for ellipsoidal heights
VERTICAL_DATUMS = {"ellipsoid": None, "egm96": 5773, "egm2008": 3855}


def ellipsoidal_dem(dem: GridDem, datum: str) -> GridDem:
    """``dem`` with its heights over the geoid ``datum`` (a key of :data:`VERTICAL_DATUMS`) made ellipsoidal (WGS 84)
    with PROJ's geoid grid, cell by cell; ``dem`` itself for "ellipsoid". ValueError, naming the grid, where PROJ
    has no grid for the geoid (offline without it, PROJ falls back to a "ballpark" transformation that adds
    nothing, which would be a silent error of tens of metres)."""
    if datum not in VERTICAL_DATUMS:
        raise ValueError(f"unknown vertical datum '{datum}' (one of {', '.join(VERTICAL_DATUMS)})")
    code = VERTICAL_DATUMS[datum]
    if code is None:
        return dem
    from pyproj.transformer import TransformerGroup
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        group = TransformerGroup(f"EPSG:4326+{code}", "EPSG:4979", always_xy=True)
    usable = [t for t in group.transformers if "ballpark" not in t.description.lower()]
    if not usable:
        grids = sorted({g.short_name for op in group.unavailable_operations for g in op.grids if not g.available})
        raise ValueError(f"PROJ has no grid for {datum} heights ({', '.join(grids) or 'none found'}; not in PROJ's "
                         f"data directory and the network is off): install it (projsync --file "
                         f"{grids[0] if grids else 'GRID'}, or set PROJ_DATA to a directory that holds it) or give the "
                         f"DEM in ellipsoidal heights")
    a, _, c, _, e, f = dem.transform
    rows, cols = dem.heights_m.shape
    lon = np.broadcast_to(c + a * (np.arange(cols) + 0.5), (rows, cols))
    lat = np.broadcast_to((f + e * (np.arange(rows) + 0.5))[:, None], (rows, cols))
    _, _, h = usable[0].transform(lon.ravel(), lat.ravel(), dem.heights_m.ravel())
    return GridDem(np.asarray(h, float).reshape(rows, cols), dem.transform)
