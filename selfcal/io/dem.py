"""DEMs as GeoTIFF (rasterio): geographic grids (EPSG:4326) of ellipsoidal heights."""
from __future__ import annotations

import os

import numpy as np

from ..errors import BlockError
from ..geometry.terrain import GridDem
from .atomic import atomic_write

__all__ = ["read_dem", "write_dem"]


def read_dem(path: str | os.PathLike) -> GridDem:
    """The first band of a GeoTIFF in EPSG:4326 as a :class:`GridDem`."""
    import rasterio

    path = str(path)
    try:
        with rasterio.open(path) as source:
            if source.crs is None or source.crs.to_epsg() != 4326:
                raise BlockError(path, f"the DEM must be in EPSG:4326 (geographic degrees), found {source.crs}")
            heights = source.read(1).astype(float)
            nodata = source.nodata
            transform = tuple(source.transform)[:6]
    except rasterio.errors.RasterioIOError as exc:
        raise BlockError(path, f"cannot read the DEM: {exc}") from None
    if nodata is not None and np.any(heights == nodata):
        raise BlockError(path, "the DEM has no-data cells; fill them first")
    bad = ~np.isfinite(heights)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise BlockError(path, f"{int(bad.sum())} cells are NaN or infinite (the first at row {row}, column {col}); "
                               f"expected a finite height in every cell: fill them first")
    if heights.ndim != 2 or min(heights.shape) < 2:
        raise BlockError(path, f"the DEM is {' x '.join(map(str, heights.shape))} cells; at least 2 x 2 are needed "
                               f"to interpolate")
    if not all(np.isfinite(transform)):
        raise BlockError(path, f"the geotransform {transform} is not finite")
    try:
        return GridDem(heights, transform)
    except ValueError as exc:
        raise BlockError(path, str(exc)) from None


def write_dem(path: str | os.PathLike, dem: GridDem) -> None:
    """Write a :class:`GridDem` as a float32 GeoTIFF (atomically)."""
    import rasterio
    from rasterio.transform import Affine

    rows, cols = dem.heights_m.shape
    with atomic_write(str(path), mode="wb") as handle:
        with rasterio.open(handle, "w", driver="GTiff", width=cols, height=rows, count=1, dtype="float32",
                           crs="EPSG:4326", transform=Affine(*dem.transform)) as target:
            target.write(dem.heights_m.astype(np.float32), 1)
