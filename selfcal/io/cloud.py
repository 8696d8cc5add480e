"""Ground point clouds as CSV (issue 42, ``selfcal adjust --terrain-cloud``): ``lat_deg,lon_deg,h_m`` (WGS 84,
ellipsoidal heights) or ``X,Y,Z`` (ECEF, m), one point a line; every defect a BlockError naming file and line."""
from __future__ import annotations

import os

import numpy as np

from ..errors import BlockError
from .table import NUM, Column, read_table

__all__ = ["read_point_cloud"]

_GEOGRAPHIC = ("lat_deg", "lon_deg", "h_m")
_ECEF = ("X", "Y", "Z")


def read_point_cloud(path: str | os.PathLike) -> tuple[str, np.ndarray]:
    """The cloud's columns: ("geographic", (n, 3) lat_deg, lon_deg, h_m) or ("ECEF", (n, 3) X, Y, Z)."""
    path = str(path)
    table = read_table(path, [Column(name, NUM, required=False) for name in _GEOGRAPHIC + _ECEF])
    for kind, names in (("geographic", _GEOGRAPHIC), ("ECEF", _ECEF)):
        given = [n for n in names if n in table]
        if len(given) == 3 and not any(n in table for n in (_ECEF if kind == "geographic" else _GEOGRAPHIC)):
            values = np.column_stack([table[n] for n in names])
            if kind == "geographic":
                bad = np.flatnonzero((np.abs(values[:, 0]) > 90) | (np.abs(values[:, 1]) > 360))
                if bad.size:
                    raise BlockError(path, f"latitude {values[bad[0], 0]:g}, longitude {values[bad[0], 1]:g}: not "
                                           f"degrees", int(table.line[bad[0]]))
            return kind, values
    raise BlockError(path, f"a point cloud has the columns {','.join(_GEOGRAPHIC)} (WGS 84 degrees, ellipsoidal "
                           f"heights) or {','.join(_ECEF)} (ECEF metres), one set of them")
