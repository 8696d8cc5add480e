"""Control coordinates checked against what a block knows of its own position, before any work.

A survey file in northing, easting order (or latitude, longitude in a geographic CRS) is read without a word as
X = northing: every coordinate is a valid number, and the adjustment stops much later on a point "1.26e+06 m
from the block's centre". The block's cameras know better: :func:`swapped_axes` compares the control points
with the extent of the camera positions (images.csv, the camera GNSS, an importer's orientations) in the order
given and with X and Y swapped, and says so when they lie far outside it as given and inside it swapped.

* **far**: the median distance of the control points from the cameras' plan extent (the bounding box of the
  positions) is more than :data:`FAR_SIZES` times the block's size; **inside**: it is at most
  :data:`NEAR_SIZES` times the size (a footprint reaches beyond the cameras). The size is the larger of the
  extent's diagonal and the height of the cameras above the control (a single image's footprint).
* **geographic CRS** (X the longitude, Y the latitude, degrees, as selfcal reads them): a latitude beyond +-90
  degrees is certain, whatever the cameras; otherwise the same test, in metres on a sphere around the cameras.
* **no position of its own** (a free network, no camera position, a geocentric CRS): nothing is said.

Nothing here reads files: the callers name the file in their :class:`~selfcal.errors.BlockError`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["swapped_axes", "block_control_swapped", "crs_kind", "FAR_SIZES", "NEAR_SIZES"]

#: control whose median distance from the cameras' extent exceeds this many block sizes lies far outside it
FAR_SIZES = 10.0
#: control whose median distance from the cameras' extent is within this many block sizes lies inside it
NEAR_SIZES = 1.0
#: metres per degree of a great circle (mean Earth radius 6371008.8 m)
_M_PER_DEG = 6371008.8 * np.pi / 180.0


def crs_kind(crs: str | None) -> str:
    """"geographic", "projected", "local" (no CRS: an arbitrary Cartesian frame) or "other" (geocentric, a CRS
    pyproj does not know)."""
    if crs in (None, "", "local"):
        return "local"
    from pyproj import CRS
    from pyproj.exceptions import CRSError
    try:
        parsed = CRS.from_user_input(crs)
    except CRSError:
        return "other"
    horizontal = parsed.sub_crs_list[0] if parsed.is_compound else parsed
    if horizontal.is_geographic:
        return "geographic"
    if horizontal.is_projected:
        return "projected"
    return "other"


def _distance_to_box(xy: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    outside = np.maximum(np.maximum(low - xy, xy - high), 0.0)
    return np.hypot(outside[:, 0], outside[:, 1])


def _local_metres(lon: np.ndarray, lat: np.ndarray, lon0: float, lat0: float) -> np.ndarray:
    dlon = (np.asarray(lon, float) - lon0 + 180.0) % 360.0 - 180.0
    return np.column_stack([dlon * np.cos(np.radians(lat0)) * _M_PER_DEG, (np.asarray(lat, float) - lat0) * _M_PER_DEG])


def _where(point_ids, lines, k: int) -> str:
    name = f"'{point_ids[k]}'" if point_ids is not None else f"number {k + 1}"
    return f"point {name}" + (f", line {int(lines[k])}" if lines is not None else "")


def swapped_axes(control_xyz, camera_xyz, *, geographic: bool = False, point_ids=None, lines=None,
                 what: str = "control points", reference: str = "camera positions") -> str | None:
    """The reason, one paragraph naming the columns and the distances, when the control's X and Y (longitude and
    latitude in a ``geographic`` CRS) look swapped against the camera positions ``camera_xyz`` (n, 3; NaN rows
    ignored); else None. See the module's docstring for the rule. ``point_ids``, ``lines``: of the control rows,
    for the message; ``what`` and ``reference`` name the two sets in it (the roles may be the other way round:
    camera GNSS positions checked against a block's control)."""
    control = np.asarray(control_xyz, float).reshape(-1, 3)
    keep = np.isfinite(control[:, :2]).all(axis=1)
    idx = np.flatnonzero(keep)
    if not idx.size:
        return None
    x, y, z = control[idx, 0], control[idx, 1], control[idx, 2]
    if geographic:
        beyond = np.flatnonzero(np.abs(y) > 90.0)
        if beyond.size:
            k = idx[beyond[np.argmax(np.abs(y[beyond]))]]
            value = f"Y (the latitude) is {control[k, 1]:.10g} ({_where(point_ids, lines, k)}), beyond +-90 degrees"
            if np.all(np.abs(x) <= 90.0):
                return (f"the {what}' longitude and latitude look swapped: selfcal reads X as the longitude "
                        f"and Y as the latitude of a geographic CRS, and {value}, while every X is a valid latitude. "
                        f"Swap the two columns (the file gives latitude, longitude)")
            return f"the {what} are not longitude, latitude: {value}"
    cameras = np.asarray(camera_xyz, float).reshape(-1, 3)
    cameras = cameras[np.isfinite(cameras[:, :2]).all(axis=1)]
    if not len(cameras):
        return None
    if geographic:
        if np.any(np.abs(cameras[:, 1]) > 90.0) or np.any(np.abs(x) > 90.0):
            return None                  # the cameras are no latitudes, or the control cannot be read swapped
        lon0, lat0 = float(np.median(cameras[:, 0])), float(np.median(cameras[:, 1]))
        camera_xy = _local_metres(cameras[:, 0], cameras[:, 1], lon0, lat0)
        given, swapped = _local_metres(x, y, lon0, lat0), _local_metres(y, x, lon0, lat0)
        names = ("longitude", "latitude")
    else:
        camera_xy = cameras[:, :2]
        given, swapped = np.column_stack([x, y]), np.column_stack([y, x])
        names = ("X", "Y")
    low, high = camera_xy.min(axis=0), camera_xy.max(axis=0)
    size = float(np.hypot(*(high - low)))
    zc, zp = cameras[:, 2], z
    if np.isfinite(zc).any() and np.isfinite(zp).any():
        size = max(size, abs(float(np.nanmedian(zc) - np.nanmedian(zp))))
    if not size > 0.0:
        return None
    far = float(np.median(_distance_to_box(given, low, high)))
    near = float(np.median(_distance_to_box(swapped, low, high)))
    if not (far > FAR_SIZES * size and near <= NEAR_SIZES * size):
        return None
    k = idx[0]
    first = (f"{_where(point_ids, lines, k)}: X {control[k, 0]:.10g}, Y {control[k, 1]:.10g}")
    order = "latitude, longitude" if geographic else "northing, easting"
    reads = "X as the longitude and Y as the latitude" if geographic else "X as the easting and Y as the northing"
    return (f"the {what}' {names[0]} and {names[1]} look swapped (the file in {order} order?): as given they "
            f"lie {far:.3g} m from the {len(cameras)} {reference} (the median distance from their extent, "
            f"{size:.3g} m across), with {names[0]} and {names[1]} swapped {near:.3g} m. selfcal reads {reads}; swap "
            f"the two columns ({first})")


def block_control_swapped(block) -> str | None:
    """The reason when the control points (gcp and chk) of a block look swapped against its images' positions
    (:func:`swapped_axes` in the block's ``crs``, X the longitude in a geographic one), else None. A block without
    a position of its own (a free network without GNSS, no image position, a geocentric or unknown CRS) is
    checked only for latitudes beyond +-90 degrees."""
    kind = crs_kind(block.crs)
    if kind == "other":
        return None
    points = block.points
    control = np.flatnonzero(np.isin(points.role, ("gcp", "chk")))
    if not control.size:
        return None
    positioned = not (block.datum == "free" and not block.has_trajectory)
    cameras = block.images.position_m if positioned else np.zeros((0, 3))
    return swapped_axes(points.xyz_m[control], cameras, geographic=kind == "geographic",
                        point_ids=points.point_id[control], lines=points.line[control])
