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
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .jsonfields import array, found, integer, mapping, need, number
from .text import read_json

__all__ = ["LineScanIsd", "read_usgscsm_isd", "LINE_SCANNER_MODEL", "target_naif_code"]

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
    target_naif_code: int | None = None    # the target body's NAIF code (301: the Moon), None if not named


def target_naif_code(isd: dict) -> int | None:
    """The NAIF code of the ISD's target body (301: the Moon, 499: Mars), from the body constants ALE copies
    into ``naif_keywords`` (``BODY<code>_RADII``); None when they name no body, or more than one."""
    keywords = isd.get("naif_keywords")
    if not isinstance(keywords, dict):
        return None
    codes = {int(m.group(1)) for m in map(re.compile(r"BODY([0-9]{1,9})_RADII$").match, keywords) if m}
    return codes.pop() if len(codes) == 1 else None


def _need(isd: dict, key: str, path: str, parent: str = ""):
    where = isd if not parent else need(path, isd, parent)
    return need(path, where, key, parent)


def _array(value, shape_tail, path: str, key: str) -> np.ndarray:
    return array(path, value, key, (None,) + tuple(shape_tail))


def _times(isd: dict, section: str, count: int, path: str, t0_key: str, dt_key: str) -> np.ndarray:
    block = mapping(path, isd[section], section)
    if "ephemeris_times" in block:
        t = array(path, block["ephemeris_times"], f"{section}.ephemeris_times", (None,))
    elif t0_key in isd and dt_key in isd:
        t = number(path, _need(isd, "center_ephemeris_time", path), "center_ephemeris_time") \
            + number(path, isd[t0_key], t0_key) + number(path, isd[dt_key], dt_key, positive=True) * np.arange(count)
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
    if "constant_rotation" not in isd[section]:
        return times, quaternions, np.eye(3)
    constant = array(path, isd[section]["constant_rotation"], f"{section}.constant_rotation", (9,))
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
    center = number(path, _need(isd, "center_ephemeris_time", path), "center_ephemeris_time")
    position = mapping(path, _need(isd, "instrument_position", path), "instrument_position")
    unit = _UNIT_TO_M.get(position.get("unit", "km"))
    if unit is None:
        raise BlockError(path, f"'instrument_position.unit' must be 'km' or 'm', found {found(position['unit'])}")
    positions = _array(_need(isd, "positions", path, "instrument_position"), (3,), path,
                       "instrument_position.positions")
    velocities = _array(_need(isd, "velocities", path, "instrument_position"), (3,), path,
                        "instrument_position.velocities")
    if len(velocities) != len(positions):
        raise BlockError(path, f"{len(positions)} positions but {len(velocities)} velocities")
    position_times = _times(isd, "instrument_position", len(positions), path, "t0_ephemeris", "dt_ephemeris")
    pointing = _rotation(isd, "instrument_pointing", path)
    body = _rotation(isd, "body_rotation", path)
    radii = mapping(path, _need(isd, "radii", path), "radii")
    radius_unit = _UNIT_TO_M.get(radii.get("unit", "km"))
    if radius_unit is None:
        raise BlockError(path, f"'radii.unit' must be 'km' or 'm', found {found(radii['unit'])}")
    distortion = mapping(path, _need(isd, "optical_distortion", path), "optical_distortion")
    if len(distortion) != 1:
        raise BlockError(path, "'optical_distortion' must name one distortion model")
    (distortion_model, parameters), = distortion.items()
    parameters = mapping(path, parameters, f"optical_distortion.{distortion_model}")
    coefficients = parameters.get("coefficients", [])
    if not isinstance(coefficients, list):              # one coefficient may be written as a number
        coefficients = [coefficients]
    if coefficients:
        coefficients = array(path, coefficients, f"optical_distortion.{distortion_model}.coefficients", (None,))
    rate = _array(_need(isd, "line_scan_rate", path), (3,), path, "line_scan_rate")
    center_pixel = _need(isd, "detector_center", path)

    def num(key: str, parent: str = "", positive: bool = False) -> float:
        where = isd if not parent else need(path, isd, parent)
        return number(path, need(path, where, key, parent), f"{parent}.{key}" if parent else key, positive)

    def whole(key: str) -> int:
        return integer(path, _need(isd, key, path), key)

    return LineScanIsd(
        path=path, sensor_name=str(isd.get("name_sensor", "")), image_lines=whole("image_lines"),
        image_samples=whole("image_samples"), center_time_s=center, line_scan_rate=rate,
        line_summing=num("detector_line_summing", positive=True),
        sample_summing=num("detector_sample_summing", positive=True),
        starting_detector_line=num("starting_detector_line"),
        starting_detector_sample=num("starting_detector_sample"),
        detector_center_line=num("line", "detector_center"), detector_center_sample=num("sample", "detector_center"),
        focal2pixel_lines=array(path, _need(isd, "focal2pixel_lines", path), "focal2pixel_lines", (3,)),
        focal2pixel_samples=array(path, _need(isd, "focal2pixel_samples", path), "focal2pixel_samples", (3,)),
        focal_length_mm=num("focal_length", "focal_length_model", positive=True),
        distortion_model=str(distortion_model),
        distortion_coefficients=np.atleast_1d(np.asarray(coefficients, float)),
        semi_major_m=num("semimajor", "radii", positive=True) * radius_unit,
        semi_minor_m=num("semiminor", "radii", positive=True) * radius_unit,
        position_times_s=position_times - center, positions_m=positions * unit, velocities_m_s=velocities * unit,
        pointing_times_s=pointing[0] - center, pointing_quaternions=pointing[1], pointing_constant=pointing[2],
        body_times_s=body[0] - center, body_quaternions=body[1], body_constant=body[2],
        target_naif_code=target_naif_code(isd))
