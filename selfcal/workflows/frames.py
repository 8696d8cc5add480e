"""The object frame of an adjustment: a block's points in the frame its sensors work in.

Frame cameras work in the block's own coordinates (a projected CRS or a local frame). Satellite
sensors work in Earth-fixed Cartesian metres (ECEF, EPSG:4978): a block whose ``crs`` is another
CRS of the Earth (``EPSG:4979``: longitude, latitude, ellipsoidal height) has its points converted
with pyproj before the adjustment; the control points' sigmas stay east / north / up.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..block import Block
from ..errors import BlockError
from ..sensors import sensor_of

__all__ = ["object_frame_block", "ECEF_NAMES"]

#: crs names already in the ECEF (or body-fixed) Cartesian frame
ECEF_NAMES = ("EPSG:4978", "ECEF", "body-fixed")


def object_frame_block(block: Block) -> Block:
    """``block`` with its points in its sensors' object frame (see the module docstring)."""
    frames = {sensor_of(c).object_frame for c in block.cameras.values()}
    if frames != {"ECEF"} or block.crs in ECEF_NAMES or block.crs.upper().startswith("IAU"):
        return block
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError
    try:
        source = CRS.from_user_input(block.crs)
    except CRSError as exc:
        raise BlockError("block.toml", f"crs {block.crs!r} is not a coordinate reference system pyproj knows: {exc}",
                         None, "crs") from None
    transformer = Transformer.from_crs(source, "EPSG:4978", always_xy=True)
    xyz = block.points.xyz_m
    known = np.isfinite(xyz).all(axis=1)
    out = np.full_like(xyz, np.nan)
    if known.any():
        out[known] = np.column_stack(transformer.transform(xyz[known, 0], xyz[known, 1], xyz[known, 2]))
    return replace(block, crs="EPSG:4978", points=replace(block.points, xyz_m=out))
