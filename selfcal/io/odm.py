"""OpenDroneMap ``gcp_list.txt`` (ground control and its image measurements) and ``geo.txt`` (image positions).

gcp_list.txt (https://docs.opendronemap.org/gcp/): the first line names the
coordinate reference system (a PROJ string, ``EPSG:<code>``, or ``WGS84 UTM
<zone><hemisphere>``); every other line is

    geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extra fields ...]

separated by spaces or tabs. ``im_x, im_y`` are the column and row in pixels
from the upper-left corner of the image, read here with selfcal's convention
(the upper-left corner of the first pixel is (0, 0)). Without a gcp name,
points with identical coordinates are one point. In a geographic CRS
(``EPSG:4326``) ``geo_x`` is the longitude and ``geo_y`` the latitude (ODM's
order: it hands x, y to GDAL in the traditional GIS order, and its docs'
examples give the longitude first), in degrees. ``geo_z`` may be ``NaN``: a
control point known in plan only (it is kept as NaN here; the block holds it
with a loose height, see :func:`selfcal.convert.block_from_colmap`).

geo.txt ("Image Geolocation Files", https://docs.opendronemap.org/geo/): the
first line names the CRS as above; every other line is

    image_name geo_x geo_y [geo_z] [yaw pitch roll] [horz_accuracy vert_accuracy] [extras ...]

(angles in degrees, accuracies in metres; the angles come as a triple and the
accuracies as a pair, as ODM's ``opendm/geo.py`` reads them).
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .text import is_number, read_text

__all__ = ["GroundControl", "read_gcp_list", "ImagePositions", "read_geo_txt"]


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
    path: str = "gcp_list.txt"     # the file read


def _crs(path: str, text: str, geographic: bool = False) -> tuple[str, str]:
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
    if not crs.is_projected and not (geographic and crs.is_geographic):
        raise BlockError(path, f"the CRS '{crs.name}' is neither projected nor geographic (longitude, latitude)", 1)
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
    crs, crs_name = _crs(path, header[1], geographic=True)
    geographic = _is_geographic(crs)
    names: list[str] = []
    xyz: list[np.ndarray] = []
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
            bad = next(f for f in fields[:5] if not is_number(f))
            column = ["geo_x", "geo_y", "geo_z", "im_x", "im_y"][fields[:5].index(bad)]
            raise BlockError(path, f"'{bad}' is not a number", number, column) from None
        if not np.all(np.isfinite(values[:2] + values[3:])) or np.isinf(values[2]):
            raise BlockError(path, "NaN or infinite value (only geo_z may be NaN: a point known in plan only)", number)
        if geographic:
            _check_lon_lat(path, values[0], values[1], number)
        if values[3] < 0 or values[4] < 0:
            raise BlockError(path, "negative pixel coordinate", number, "im_x" if values[3] < 0 else "im_y")
        point = np.array(values[:3])
        plan = ".9f" if geographic else ".3f"
        name = fields[6] if len(fields) > 6 else f"{values[0]:{plan}}_{values[1]:{plan}}_{values[2]:.3f}"
        if name in by_name:
            k = by_name[name]
            if not np.allclose(xyz[k], point, atol=1e-6 if not geographic else 1e-11, equal_nan=True):
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
                         np.array(o_line, np.int64), path)



def _is_geographic(crs: str) -> bool:
    from pyproj import CRS
    return CRS.from_user_input(crs).is_geographic


def _check_lon_lat(path: str, lon: float, lat: float, line: int) -> None:
    if not -90.0 <= lat <= 90.0:
        swapped = (f": geo_x and geo_y look swapped (geo_x {lon:g} would be a latitude); swap the two columns"
                   if -90.0 <= lon <= 90.0 else "")
        raise BlockError(path, f"latitude {lat:g} is outside -90..90 degrees; in a geographic CRS geo_x is the "
                               f"longitude and geo_y the latitude (ODM's order){swapped}", line, "geo_y")
    if not -180.0 <= lon <= 360.0:
        raise BlockError(path, f"longitude {lon:g} is outside -180..360 degrees", line, "geo_x")


@dataclass(frozen=True)
class ImagePositions:
    """An ODM geo.txt: the position of each image (NaN where not given) in ``crs``."""

    crs: str
    crs_name: str
    image_names: np.ndarray        # (n,)
    xyz: np.ndarray                # (n, 3); z NaN where the line has none
    ypr_deg: np.ndarray            # (n, 3) yaw, pitch, roll; NaN where not given
    accuracy_m: np.ndarray         # (n, 2) horizontal, vertical; NaN where not given
    line: np.ndarray               # (n,) line in the file


def read_geo_txt(path: str | os.PathLike) -> ImagePositions:
    """Read an ODM geo.txt; defects (a field that is not a number, too few fields, an image twice) are
    BlockErrors naming the line and the field."""
    path = str(path)
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    lines = read_text(path, "geo file").splitlines()
    if not lines or not lines[0].strip():
        raise BlockError(path, "the first line must name the CRS", 1)
    crs, crs_name = _crs(path, lines[0], geographic=True)
    geographic = _is_geographic(crs)
    names, xyz, ypr, acc, where = [], [], [], [], []
    seen: dict[str, int] = {}
    header = ["image_name", "geo_x", "geo_y", "geo_z", "yaw", "pitch", "roll", "horz_accuracy", "vert_accuracy"]
    for number, text in enumerate(lines[1:], start=2):
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        fields = text.split()
        if len(fields) < 3:
            raise BlockError(path, "expected image_name geo_x geo_y [geo_z] [yaw pitch roll] "
                                   "[horz_accuracy vert_accuracy]", number)
        n_numbers = 9 if len(fields) >= 9 else 7 if len(fields) >= 7 else min(len(fields), 4)
        values = []
        for k in range(1, n_numbers):
            try:
                value = float(fields[k])
            except ValueError:
                raise BlockError(path, f"'{fields[k]}' is not a number", number, header[k]) from None
            if not math.isfinite(value):
                raise BlockError(path, f"'{fields[k]}' is not a finite number", number, header[k])
            values.append(value)
        values += [math.nan] * (8 - len(values))
        if geographic:
            _check_lon_lat(path, values[0], values[1], number)
        if fields[0] in seen:
            raise BlockError(path, f"image '{fields[0]}' is given twice (first on line {seen[fields[0]]})", number,
                             "image_name")
        seen[fields[0]] = number
        if values[6] <= 0 or values[7] <= 0:
            raise BlockError(path, "an accuracy must be positive", number,
                             "horz_accuracy" if values[6] <= 0 else "vert_accuracy")
        names.append(fields[0])
        xyz.append(values[:3])
        ypr.append(values[3:6])
        acc.append(values[6:8])
        where.append(number)
    if not names:
        raise BlockError(path, "no image position in the file")
    return ImagePositions(crs, crs_name, np.array(names, dtype=object), np.array(xyz, float), np.array(ypr, float),
                          np.array(acc, float), np.array(where, np.int64))
