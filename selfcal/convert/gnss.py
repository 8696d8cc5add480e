"""Camera GNSS into a block: the positions the images carry (EXIF/XMP, :mod:`selfcal.io.exif`) or an ODM geo.txt
(:func:`selfcal.io.odm.read_geo_txt`) become images.csv positions and ``[gnss]`` observations with each image's
own sigma, in the block's CRS, with strips found from time and heading (:mod:`selfcal.geometry.gnss`).

Nothing here reads files: the readers hand over plain data (:class:`CameraPositions`).
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..block import Block
from ..geometry.gnss import STRIP_GAP_FACTOR, STRIP_TURN_DEG, check_block_crs, detect_strips, positions_in_crs

if TYPE_CHECKING:
    from ..io.exif import ImageGnss
    from ..io.odm import GroundControl, ImagePositions

__all__ = ["CameraPositions", "positions_from_images", "positions_from_geo", "block_with_gnss", "GnssImport", "exif_cameras",
           "exposure_times", "match_images", "projected_control", "utm_crs"]


@dataclass(frozen=True)
class CameraPositions:
    """Positions of images in ``crs`` (x, y, z; geographic: longitude, latitude in degrees, height in metres).

    ``sigma_enu_m`` (n, 3) each position's own sigma east, north, up (NaN: none given); ``time_s`` (n,) the
    exposure times (NaN: none); ``where`` (n,) the file (and line) of each, for messages; ``gimbal_ypr_deg``
    (n, 3) the camera's yaw, pitch, roll in the gimbal convention of
    :func:`selfcal.geometry.gnss.opk_from_yaw_pitch_roll` (NaN: not given)."""

    names: np.ndarray
    xyz: np.ndarray
    crs: str
    sigma_enu_m: np.ndarray
    time_s: np.ndarray
    where: np.ndarray
    gimbal_ypr_deg: np.ndarray | None = None


@dataclass(frozen=True)
class GnssImport:
    """A block with camera GNSS, and what the import left out or changed (one message each)."""

    block: Block
    n_with_gnss: int
    n_own_sigma: int
    n_strips: int
    warnings: tuple[str, ...]
    n_with_attitude: int = 0


def positions_from_images(records: Sequence[ImageGnss]) -> tuple[CameraPositions, list[str]]:
    """CameraPositions (EPSG:4326 longitude, latitude, height) from :class:`selfcal.io.exif.ImageGnss` records;
    records without a position are left out with a warning naming the file. The time of every image comes from
    one clock: the GPS time stamps when every image has one, else the camera clock when every image has it,
    else none (strips then follow the file names' order)."""
    warnings = []
    kept = []
    for r in records:
        if r.has_position:
            kept.append(r)
        else:
            warnings.append(f"{r.path}: no GPS position in its EXIF or XMP tags; the image keeps no GNSS "
                            f"observation (it is oriented by resection)")
    time, note = exposure_times(kept)
    if note:
        warnings.append(note if np.isfinite(time).all() else f"{note}; strips follow the file names' order")
    positions = CameraPositions(
        names=np.array([r.name for r in kept], dtype=object),
        xyz=np.array([[r.longitude_deg, r.latitude_deg, r.height_m] for r in kept], float).reshape(-1, 3),
        crs="EPSG:4326",
        sigma_enu_m=np.array([r.sigma_enu_m for r in kept], float).reshape(-1, 3),
        time_s=time,
        where=np.array([r.path for r in kept], dtype=object),
        gimbal_ypr_deg=np.array([r.gimbal_ypr_deg for r in kept], float).reshape(-1, 3))
    return positions, warnings


def exposure_times(records: Sequence[ImageGnss]) -> tuple[np.ndarray, str]:
    """The exposure time of every record from one clock: the GPS time stamps when every record has one, else the
    camera clock when every record has it, else none (all NaN); and a note where it is not the GPS clock (which
    clock, or why none: the files without a time named)."""
    sources = {r.time_source for r in records}
    time = np.array([r.time_s for r in records], float)
    if not records or sources == {"gps"}:
        return time, ""
    if sources == {"camera"}:
        return time, "exposure times from the camera clock (DateTimeOriginal): no GPS time stamps"
    missing = [r.path for r in records if r.time_source == ""]
    mixed = "some images have GPS time stamps and others only the camera clock" if not missing else \
        f"{len(missing)} image(s) have no time ({', '.join(missing[:3])})"
    return np.full(len(records), np.nan), f"no exposure times used: {mixed}"


def positions_from_geo(geo: ImagePositions, path: str) -> CameraPositions:
    """CameraPositions from an ODM geo.txt (:class:`selfcal.io.odm.ImagePositions`): its horizontal and
    vertical accuracies become the sigmas east, north (both the horizontal one) and up; it has no times."""
    sigma = np.column_stack([geo.accuracy_m[:, 0], geo.accuracy_m[:, 0], geo.accuracy_m[:, 1]])
    return CameraPositions(geo.image_names, geo.xyz, geo.crs, sigma, np.full(len(geo.image_names), np.nan),
                           np.array([f"{path}, line {n}" for n in geo.line], dtype=object))


def match_images(block_ids: np.ndarray, names: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Block image index of each name (-1: not in the block): the same name, else the same name without its
    extension (image id ``S1_01`` for ``S1_01.JPG``)."""
    exact = {str(i): k for k, i in enumerate(block_ids)}
    stem: dict[str, int] = {}
    for k, i in enumerate(block_ids):
        stem.setdefault(os.path.splitext(str(i))[0], k)
    index = np.array([exact.get(str(n), stem.get(os.path.splitext(str(n))[0], -1)) for n in names], np.int64)
    return index, [k for k in range(len(names)) if index[k] < 0]


def exif_cameras(block: Block, records: Sequence[ImageGnss]) -> dict[str, tuple]:
    """Image id -> (EXIF Make, Model, width_px, height_px) of the block's images that ``records`` name (by file name,
    or by its stem); what :func:`selfcal.convert.rolling.with_rolling_shutter` takes."""
    names = np.array([r.name for r in records], dtype=object)
    index, _ = match_images(block.images.image_id, names)
    return {str(block.images.image_id[k]): (r.camera_make, r.camera_model, r.width_px or None, r.height_px or None)
            for r, k in zip(records, index) if k >= 0 and (r.camera_make or r.camera_model)}


def block_with_gnss(block: Block, positions: CameraPositions, sigma_m: Sequence[float] | None = None,
                    heights: str = "ellipsoidal", turn_deg: float = STRIP_TURN_DEG,
                    gap_factor: float = STRIP_GAP_FACTOR, imu_sigma_deg: Sequence[float] | None = None,
                    points_path: str = "points.csv", positions_path: str = "") -> GnssImport:
    """``block`` with the camera positions as its GNSS observations.

    * positions converted into the block's CRS (:func:`selfcal.geometry.gnss.positions_in_crs`, ``heights``);
    * each image's own sigma (east, north, up, taken as X, Y, Z: the grid convergence of the projection, a few
      degrees, turns an error ellipse that is not a circle; RTK's is nearly one) in images.csv, the block-wide
      ``sigma_m`` (default: the block's ``[gnss]``, else 3, 3, 5 m of a consumer receiver) for the others;
    * time_s the seconds since the first exposure (where the positions have times; else the block's);
    * strips found from time and heading, named ``S1``, ``S2``, ... in time order;
    * with ``imu_sigma_deg`` (three sigmas, degrees) and gimbal angles in the positions: the images' omega, phi,
      kappa in the block's grid (:func:`selfcal.geometry.gnss.opk_from_yaw_pitch_roll`) as ``[imu]``
      observations; the images without angles get none (NaN, oriented by resection). Without, the block's
      attitudes (its initial values) and its ``[imu]`` stay as they were.

    An image of the block without a position gets none (NaN, oriented by resection); a position of an image not
    in the block is left out. Both are warnings. Raises ValueError (the CLI's exit 2) when the block's CRS cannot
    take GNSS positions, pyproj cannot convert them, or no image of the block has one; a BlockError naming
    ``points_path`` (the block's points.csv) when the block's control looks swapped (X and Y) against the positions,
    or naming ``positions_path`` when the positions' longitude and latitude do
    (:func:`selfcal.convert.control.swapped_axes`).
    """
    reason = check_block_crs(block.crs)
    if reason:
        raise ValueError(reason)
    warnings = []
    index, unknown = match_images(block.images.image_id, positions.names)
    for k in unknown:
        warnings.append(f"{positions.where[k]}: image '{positions.names[k]}' is not in the block; left out")
    dup = np.flatnonzero(np.bincount(index[index >= 0], minlength=len(block.images)) > 1)
    if dup.size:
        names = [str(n) for n, i in zip(positions.names, index) if i == dup[0]]
        raise ValueError(f"image '{block.images.image_id[dup[0]]}' of the block matches {', '.join(names)}")
    ok = index >= 0
    if not ok.any():
        raise ValueError(f"none of the {len(positions.names)} positions is of an image of the block (image ids such "
                         f"as '{block.images.image_id[0]}', positions of '{positions.names[0]}')")
    _check_source_axes(block, positions, ok, positions_path)
    xyz = positions_in_crs(positions.xyz[ok], positions.crs, block.crs, heights)
    n = len(block.images)
    position = np.full((n, 3), np.nan)
    position[index[ok]] = xyz
    own = np.full((n, 3), np.nan)
    own[index[ok]] = positions.sigma_enu_m[ok]
    missing_z = index[ok][np.isnan(xyz[:, 2])]
    for i in missing_z:
        warnings.append(f"image '{block.images.image_id[i]}': no height; no GNSS observation")
    position[missing_z] = np.nan
    own[missing_z] = np.nan
    without = np.setdiff1d(np.arange(n), index[ok])
    for i in without:
        warnings.append(f"image '{block.images.image_id[i]}' of the block has no GNSS position; it is oriented by "
                        f"resection")
    time = block.images.time_s.copy()
    t = positions.time_s[ok]
    if np.isfinite(t).any():
        time = np.full(n, np.nan)
        time[index[ok]] = t - np.nanmin(t)
    has = np.isfinite(position).all(axis=1)
    if not has.any():
        raise ValueError("no image of the block has a complete GNSS position (longitude, latitude and height)")
    _check_control_axes(block, position, points_path, positions_path)
    strips = np.full(n, "", dtype=object)
    order_time = np.where(np.isfinite(time), time, np.nan)
    if not np.isfinite(order_time[has]).all():
        order_time = np.full(n, np.nan)             # the order given: the block's image order
    number = detect_strips(order_time[has], position[has], turn_deg, gap_factor)
    strips[has] = np.array([f"S{s + 1}" for s in number], dtype=object)
    strips[~has] = block.images.strip_id[~has]
    if sigma_m is None:
        sigma_m = block.gnss_sigma_m if block.gnss_sigma_m is not None else (3.0, 3.0, 5.0)
    images = replace(block.images, position_m=position, time_s=time, strip_id=strips,
                     gnss_sigma_m=own if np.isfinite(own).any() else None)
    new = replace(block, images=images, gnss_sigma_m=_three(sigma_m), datum="control")
    n_attitude = 0
    if imu_sigma_deg is not None:
        new, n_attitude = _with_attitude(new, positions, index, ok, imu_sigma_deg, warnings)
    return GnssImport(new, int(has.sum()), int(np.isfinite(own[has]).all(axis=1).sum()), int(number.max()) + 1,
                      tuple(warnings), n_attitude)


def _block_control(block: Block):
    """xyz, ids, lines of the block's control points (gcp, chk) with plan coordinates."""
    points = block.points
    k = np.flatnonzero(np.isin(points.role, ("gcp", "chk")) & np.isfinite(points.xyz_m[:, :2]).all(axis=1))
    return points.xyz_m[k], points.point_id[k], points.line[k]


def _check_source_axes(block: Block, positions: CameraPositions, ok, positions_path: str) -> None:
    """Geographic positions whose longitude and latitude look swapped against the block's control (both in the
    positions' CRS, before any conversion): a BlockError naming the positions' file."""
    from pyproj import CRS

    from ..errors import BlockError
    from .control import swapped_axes
    xyz, _, _ = _block_control(block)
    if not len(xyz) or not CRS.from_user_input(positions.crs).is_geographic:
        return
    try:
        control = positions_in_crs(xyz, block.crs, positions.crs, "orthometric")
    except ValueError:
        return
    reason = swapped_axes(positions.xyz[ok], control, geographic=True, point_ids=positions.names[ok],
                          what="GNSS positions", reference="control points of the block")
    if reason:
        raise BlockError(positions_path or str(positions.where[ok][0]), reason)


def _check_control_axes(block: Block, position, points_path: str, positions_path: str) -> None:
    """The block's control and the GNSS positions (both in the block's CRS) in other X, Y orders: a BlockError
    naming the positions' file when they are also swapped against the block's own image positions (images.csv),
    else naming points.csv (and, without image positions to tell, saying that it may be the positions' file)."""
    from ..errors import BlockError
    from .control import swapped_axes
    xyz, ids, lines = _block_control(block)
    reason = swapped_axes(xyz, position, point_ids=ids, lines=lines, reference="GNSS positions of the images")
    if not reason:
        return
    prior = block.images.position_m
    if np.isfinite(prior[:, :2]).all(axis=1).any():
        own = swapped_axes(position, prior, point_ids=block.images.image_id, what="GNSS positions",
                           reference="positions of the block's images.csv")
        if own:
            raise BlockError(positions_path or "the GNSS positions", own)
        raise BlockError(points_path, reason)
    raise BlockError(points_path, f"{reason}. If points.csv is right, {positions_path or 'the GNSS positions'} is "
                                  f"the file in northing, easting order (the block has no image positions to tell)")
def _three(values: Sequence[float]) -> tuple[float, float, float]:
    """Three sigmas (X, Y, Z or omega, phi, kappa) as floats."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def _with_attitude(block: Block, positions: CameraPositions, index, ok, imu_sigma_deg, warnings):
    """``block`` with the gimbal angles of ``positions`` as its IMU observations (see :func:`block_with_gnss`)."""
    from pyproj import CRS

    from ..geometry.gnss import grid_bearing_of_north, opk_from_yaw_pitch_roll
    ypr = positions.gimbal_ypr_deg
    if ypr is None or not np.isfinite(ypr[ok]).all(axis=1).any():
        raise ValueError("--imu-sigma-deg asks for attitudes, but no image gives its gimbal's yaw, pitch and roll")
    if not CRS.from_user_input(positions.crs).is_geographic:
        raise ValueError("attitudes are read only with geographic positions (the images' own tags)")
    given = ok & np.isfinite(ypr).all(axis=1)
    crs = CRS.from_user_input(block.crs)
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    beta = grid_bearing_of_north(positions.xyz[given, 0], positions.xyz[given, 1], horizontal.to_string())
    yaw, pitch, roll = np.radians(ypr[given].T)
    opk = opk_from_yaw_pitch_roll(yaw, pitch, roll, beta)
    attitude = np.full((len(block.images), 3), np.nan)
    attitude[index[given]] = opk
    for i in np.setdiff1d(np.arange(len(block.images)), index[given]):
        warnings.append(f"image '{block.images.image_id[i]}' has no gimbal angles; no IMU observation (it is "
                        f"oriented by resection)")
    images = replace(block.images, attitude_rad=attitude, imu_sigma_rad=None)
    return replace(block, images=images, imu_sigma_deg=_three(imu_sigma_deg),
                   imu_boresight_deg=None), int(given.sum())


def utm_crs(lon_deg: float, lat_deg: float) -> str:
    """The WGS 84 / UTM zone of a position (``EPSG:326zz`` north, ``EPSG:327zz`` south), as ODM picks it."""
    zone = int(np.floor((lon_deg + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{(32600 if lat_deg >= 0 else 32700) + zone}"


def projected_control(control: GroundControl) -> tuple[GroundControl, str]:
    """Ground control (:class:`selfcal.io.odm.GroundControl`) in a projected CRS: one in a geographic CRS
    (longitude, latitude, height) is converted into the UTM zone of its mean position (heights kept: a UTM
    CRS has no vertical datum); a NaN height stays NaN. Returns the control and a note ("" when unchanged)."""
    from pyproj import CRS
    if not CRS.from_user_input(control.crs).is_geographic:
        return control, ""
    lon, lat = np.mean(control.xyz[:, 0]), np.mean(control.xyz[:, 1])
    target = utm_crs(float(lon), float(lat))
    xyz = positions_in_crs(control.xyz, control.crs, target, "ellipsoidal")
    xyz[:, 2] = control.xyz[:, 2]
    name = CRS.from_user_input(target).name
    return replace(control, crs=target, crs_name=name, xyz=xyz), \
        f"ground control converted from {control.crs_name} (longitude, latitude) into {name}"
