"""usgscsm / ALE image support data (ISD, JSON) of line-scan cameras.

The reader checks and converts units (ALE writes km; selfcal works in m) and returns the
description as it is, in its own frames: positions and velocities in J2000, the rotations
J2000 -> sensor (``instrument_pointing``) and J2000 -> target body (``body_rotation``) as
unit quaternions, scalar first (w, x, y, z), with their constant rotations. Building a
selfcal line camera from it is :func:`selfcal.sensors.usgscsm.line_scan_from_isd`.

Image coordinates are usgscsm's (line, sample) with the centre of the first pixel at
(0.5, 0.5): the continuous (row, col) of selfcal (DESIGN.md §2) without a shift.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .text import read_json

__all__ = ["LineScanIsd", "read_usgscsm_isd", "LINE_SCANNER_MODEL"]

LINE_SCANNER_MODEL = "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"
_UNIT_TO_M = {"km": 1000.0, "m": 1.0}


@dataclass(frozen=True)
class LineScanIsd:
    path: str
    sensor_name: str
    image_lines: int
    image_samples: int
    center_time_s: float                   # ephemeris time every time below is relative to (seconds)
    line_scan_rate: np.ndarray             # (k, 3): line, time (relative), seconds per line
    line_summing: float
    sample_summing: float
    starting_detector_line: float
    starting_detector_sample: float
    detector_center_line: float
    detector_center_sample: float
    focal2pixel_lines: np.ndarray          # (3,): line = l0 + l1 x + l2 y, x and y in mm
    focal2pixel_samples: np.ndarray        # (3,)
    focal_length_mm: float
    distortion_model: str                  # "radial" or "lrolrocnac"
    distortion_coefficients: np.ndarray
    semi_major_m: float
    semi_minor_m: float
    position_times_s: np.ndarray           # relative
    positions_m: np.ndarray                # (n, 3) J2000
    velocities_m_s: np.ndarray             # (n, 3) J2000
    pointing_times_s: np.ndarray
    pointing_quaternions: np.ndarray       # (m, 4) J2000 -> sensor (time-dependent part), w x y z
    pointing_constant: np.ndarray          # (3, 3) applied after the time-dependent rotation
    body_times_s: np.ndarray
    body_quaternions: np.ndarray           # J2000 -> target body, w x y z
    body_constant: np.ndarray


def _need(isd: dict, key: str, path: str, parent: str = ""):
    where = isd if not parent else isd.get(parent, {})
    if not isinstance(where, dict) or key not in where:
        raise BlockError(path, f"missing key '{parent + '.' if parent else ''}{key}'")
    return where[key]


def _array(value, shape_tail, path: str, key: str) -> np.ndarray:
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise BlockError(path, f"'{key}' must be numbers") from None
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != tuple(shape_tail) or not np.all(np.isfinite(a)):
        raise BlockError(path, f"'{key}' must be finite numbers of shape (n, {', '.join(map(str, shape_tail))}), "
                               f"found shape {a.shape}")
    return a


def _times(isd: dict, section: str, count: int, path: str, t0_key: str, dt_key: str) -> np.ndarray:
    block = isd[section]
    if "ephemeris_times" in block:
        t = np.asarray(block["ephemeris_times"], float)
    elif t0_key in isd and dt_key in isd:
        t = float(_need(isd, "center_ephemeris_time", path)) + isd[t0_key] + isd[dt_key] * np.arange(count)
    else:
        raise BlockError(path, f"missing key '{section}.ephemeris_times' (or {t0_key}/{dt_key})")
    if len(t) != count:
        raise BlockError(path, f"'{section}': {len(t)} times for {count} samples")
    if np.any(np.diff(t) <= 0):
        raise BlockError(path, f"'{section}.ephemeris_times' must increase")
    return t


def _rotation(isd: dict, section: str, path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    quaternions = _array(_need(isd, "quaternions", path, section), (4,), path, f"{section}.quaternions")
    norms = np.linalg.norm(quaternions, axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-6):
        k = int(np.argmax(np.abs(norms - 1.0)))
        raise BlockError(path, f"'{section}.quaternions' #{k} is not a unit quaternion (norm {norms[k]:.9f})")
    times = _times(isd, section, len(quaternions), path, "t0_quaternion", "dt_quaternion")
    constant = np.asarray(isd[section].get("constant_rotation", np.eye(3).ravel()), float)
    if constant.size != 9:
        raise BlockError(path, f"'{section}.constant_rotation' must have 9 elements")
    return times, quaternions, constant.reshape(3, 3)


def read_usgscsm_isd(path: str | os.PathLike) -> LineScanIsd:
    """Read a usgscsm line-scan ISD (see the module docstring); errors name the file and the key."""
    path = str(path)
    isd = read_json(path, "ISD")
    if not isinstance(isd, dict):
        raise BlockError(path, "not an ISD (a JSON object is expected)")
    model = _need(isd, "name_model", path)
    if model != LINE_SCANNER_MODEL:
        raise BlockError(path, f"name_model is '{model}'; only {LINE_SCANNER_MODEL} is read", column="name_model")
    center = float(_need(isd, "center_ephemeris_time", path))
    position = _need(isd, "instrument_position", path)
    unit = _UNIT_TO_M.get(position.get("unit", "km"))
    if unit is None:
        raise BlockError(path, f"instrument_position.unit '{position['unit']}' is neither km nor m")
    positions = _array(_need(isd, "positions", path, "instrument_position"), (3,), path,
                       "instrument_position.positions")
    velocities = _array(_need(isd, "velocities", path, "instrument_position"), (3,), path,
                        "instrument_position.velocities")
    if len(velocities) != len(positions):
        raise BlockError(path, f"{len(positions)} positions but {len(velocities)} velocities")
    position_times = _times(isd, "instrument_position", len(positions), path, "t0_ephemeris", "dt_ephemeris")
    pointing = _rotation(isd, "instrument_pointing", path)
    body = _rotation(isd, "body_rotation", path)
    radii = _need(isd, "radii", path)
    radius_unit = _UNIT_TO_M.get(radii.get("unit", "km"))
    if radius_unit is None:
        raise BlockError(path, f"radii.unit '{radii['unit']}' is neither km nor m")
    distortion = _need(isd, "optical_distortion", path)
    if len(distortion) != 1:
        raise BlockError(path, "optical_distortion must name one model")
    (distortion_model, parameters), = distortion.items()
    rate = _array(_need(isd, "line_scan_rate", path), (3,), path, "line_scan_rate")
    center_pixel = _need(isd, "detector_center", path)
    return LineScanIsd(
        path=path, sensor_name=str(isd.get("name_sensor", "")), image_lines=int(_need(isd, "image_lines", path)),
        image_samples=int(_need(isd, "image_samples", path)), center_time_s=center, line_scan_rate=rate,
        line_summing=float(_need(isd, "detector_line_summing", path)),
        sample_summing=float(_need(isd, "detector_sample_summing", path)),
        starting_detector_line=float(_need(isd, "starting_detector_line", path)),
        starting_detector_sample=float(_need(isd, "starting_detector_sample", path)),
        detector_center_line=float(center_pixel["line"]), detector_center_sample=float(center_pixel["sample"]),
        focal2pixel_lines=np.asarray(_need(isd, "focal2pixel_lines", path), float),
        focal2pixel_samples=np.asarray(_need(isd, "focal2pixel_samples", path), float),
        focal_length_mm=float(_need(isd, "focal_length_model", path)["focal_length"]),
        distortion_model=str(distortion_model),
        distortion_coefficients=np.atleast_1d(np.asarray(parameters.get("coefficients", []), float)),
        semi_major_m=float(radii["semimajor"]) * radius_unit, semi_minor_m=float(radii["semiminor"]) * radius_unit,
        position_times_s=position_times - center, positions_m=positions * unit, velocities_m_s=velocities * unit,
        pointing_times_s=pointing[0] - center, pointing_quaternions=pointing[1], pointing_constant=pointing[2],
        body_times_s=body[0] - center, body_quaternions=body[1], body_constant=body[2])
