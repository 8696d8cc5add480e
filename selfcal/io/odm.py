"""OpenDroneMap ``gcp_list.txt``: ground control points and their image measurements.

Format (https://docs.opendronemap.org/gcp/): the first line names the
coordinate reference system (a PROJ string, ``EPSG:<code>``, or ``WGS84 UTM
<zone><hemisphere>``); every other line is

    geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extra fields ...]

separated by spaces or tabs. ``im_x, im_y`` are the column and row in pixels
from the upper-left corner of the image, read here with selfcal's convention
(the upper-left corner of the first pixel is (0, 0)). Without a gcp name,
points with identical coordinates are one point.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .text import read_text

__all__ = ["GroundControl", "read_gcp_list"]


@dataclass(frozen=True)
class GroundControl:
    crs: str                       # normalised ("EPSG:32611") where pyproj recognises it
    crs_name: str
    point_names: np.ndarray        # (k,) unique point names
    xyz: np.ndarray                # (k, 3)
    obs_point: np.ndarray          # (m,) index into point_names
    obs_image: np.ndarray          # (m,) image file name
    obs_pixel: np.ndarray          # (m, 2) col, row
    obs_line: np.ndarray           # (m,) line in the file


def _crs(path: str, text: str) -> tuple[str, str]:
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    spec = text.strip()
    match = re.fullmatch(r"WGS84\s+UTM\s+(\d{1,2})\s*([NS])", spec, re.IGNORECASE)
    if match:
        zone, hemi = int(match.group(1)), match.group(2).upper()
        spec = f"EPSG:{(32600 if hemi == 'N' else 32700) + zone}"
    try:
        crs = CRS.from_user_input(spec)
    except CRSError as exc:
        raise BlockError(path, f"the first line is not a coordinate reference system pyproj knows: {exc}", 1) from None
    if not crs.is_projected:
        raise BlockError(path, f"the CRS '{crs.name}' is not projected; give GCPs in a projected CRS (e.g. UTM)", 1)
    epsg = crs.to_epsg()
    if epsg:
        return f"EPSG:{epsg}", CRS.from_epsg(epsg).name
    return crs.to_string(), crs.name


def read_gcp_list(path: str | os.PathLike) -> GroundControl:
    """Read an ODM gcp_list.txt; defects are BlockErrors naming the line."""
    path = str(path)
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    lines = read_text(path, "gcp list").splitlines()
    header = next(((n, line) for n, line in enumerate(lines, start=1) if line.strip()), None)
    if header is None:
        raise BlockError(path, "empty file: the first line must name the CRS", 1)
    if header[0] != 1:
        raise BlockError(path, "the first line must name the CRS", 1)
    crs, crs_name = _crs(path, header[1])
    names, xyz = [], []
    by_name: dict[str, int] = {}
    o_pt, o_img, o_pix, o_line = [], [], [], []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split()
        if len(fields) < 6:
            raise BlockError(path, "expected geo_x geo_y geo_z im_x im_y image_name [gcp_name]", number)
        try:
            values = [float(f) for f in fields[:5]]
        except ValueError:
            bad = next(f for f in fields[:5] if not _is_number(f))
            column = ["geo_x", "geo_y", "geo_z", "im_x", "im_y"][fields[:5].index(bad)]
            raise BlockError(path, f"'{bad}' is not a number", number, column) from None
        if not np.all(np.isfinite(values)):
            raise BlockError(path, "NaN or infinite value", number)
        if values[3] < 0 or values[4] < 0:
            raise BlockError(path, "negative pixel coordinate", number, "im_x" if values[3] < 0 else "im_y")
        point = np.array(values[:3])
        name = fields[6] if len(fields) > 6 else f"{values[0]:.3f}_{values[1]:.3f}_{values[2]:.3f}"
        if name in by_name:
            k = by_name[name]
            if not np.allclose(xyz[k], point, atol=1e-6):
                raise BlockError(path, f"gcp '{name}' appears with other coordinates on an earlier line", number)
        else:
            k = by_name[name] = len(names)
            names.append(name)
            xyz.append(point)
        o_pt.append(k)
        o_img.append(fields[5])
        o_pix.append(values[3:5])
        o_line.append(number)
    if not names:
        raise BlockError(path, "no ground control point in the file")
    pairs = list(zip(o_img, o_pt))
    if len(set(pairs)) != len(pairs):
        dup = next(p for p in pairs if pairs.count(p) > 1)
        raise BlockError(path, f"gcp '{names[dup[1]]}' is measured twice in image '{dup[0]}'",
                         o_line[len(pairs) - 1 - pairs[::-1].index(dup)])
    return GroundControl(crs, crs_name, np.array(names, dtype=object), np.array(xyz),
                         np.array(o_pt, np.int64), np.array(o_img, dtype=object), np.array(o_pix, float),
                         np.array(o_line, np.int64))


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False
