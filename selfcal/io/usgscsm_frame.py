"""usgscsm / ALE image support data (ISD, JSON) of frame cameras (``USGS_ASTRO_FRAME_SENSOR_MODEL``).

The reader checks and converts units (ALE writes km; selfcal works in m) and returns the description in
its own frames: instrument positions in J2000 (m), the rotations J2000 -> camera (``instrument_pointing``)
and J2000 -> target body (``body_rotation``) as unit quaternions, scalar first (w, x, y, z, as ISIS's
``J2000Q0..Q3`` tables and ALE store them), each with its constant rotation. The camera itself is read from
``naif_keywords``, as ISIS reads its kernels: ``INS<code>_FOCAL_LENGTH``, ``_PIXEL_PITCH``, ``_TRANSX``/
``_TRANSY`` (detector -> focal plane), ``_ITRANSS``/``_ITRANSL`` (focal plane -> detector), and for the
Apollo Metric camera ``_PP`` (principal point, mm), ``_OD_K`` (radial) and ``_DECENTER`` (decentering). The
ISD's own usgscsm keys (``focal2pixel_*``, ``optical_distortion``, ``detector_center``) are not used: in the
Apollo ISDs they hold no distortion (``radial`` with zero coefficients) and no detector centre (null).

The ISD does not know that its cube may be a reduced copy of the scanned frame: that is the ISIS label's
``AlphaCube`` group (:class:`selfcal.io.isis.AlphaCube`), passed in as ``alpha_cube`` (without it the cube is
taken as the full detector). The geometry is :mod:`selfcal.sensors.usgscsm_frame`.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .jsonfields import integer, mapping, number
from .text import read_json
from .isis import AlphaCube
from .usgscsm import target_naif_code

__all__ = ["FrameIsd", "read_frame_isd", "FRAME_MODEL", "APOLLO_METRIC_CODES"]

FRAME_MODEL = "USGS_ASTRO_FRAME_SENSOR_MODEL"
#: NAIF instrument codes of the Apollo 15, 16 and 17 Metric cameras (ISIS ApolloMetricCamera)
APOLLO_METRIC_CODES = (-915240, -916240, -917240)
_UNIT_TO_M = {"km": 1000.0, "m": 1.0}


@dataclass(frozen=True)
class FrameIsd:
    path: str
    sensor_name: str
    platform_name: str
    naif_code: int                          # the camera's NAIF instrument code (-915240: Apollo 15 Metric)
    image_samples: int
    image_lines: int
    center_time_s: float                    # ephemeris time (s past J2000) of the exposure centre
    position_times_s: np.ndarray            # (n,) ephemeris times
    positions_m: np.ndarray                 # (n, 3) J2000, relative to the target body
    velocities_m_s: np.ndarray              # (n, 3) J2000
    pointing_times_s: np.ndarray
    pointing_quaternions: np.ndarray        # (m, 4) J2000 -> camera, w x y z
    pointing_constant: np.ndarray           # (3, 3) applied after the time-dependent rotation
    body_times_s: np.ndarray
    body_quaternions: np.ndarray            # (k, 4) J2000 -> body-fixed, w x y z
    body_constant: np.ndarray
    focal_length_mm: float
    pixel_pitch_mm: float                   # of the detector (full-resolution) pixel
    trans_x: np.ndarray                     # (3,): x = t0 + t1 sample + t2 line (centred detector pixels -> mm)
    trans_y: np.ndarray
    itrans_s: np.ndarray                    # (3,): sample = i0 + i1 x + i2 y (mm -> centred detector pixels)
    itrans_l: np.ndarray
    principal_point_mm: np.ndarray          # (2,) INS_PP
    radial_k: np.ndarray                    # (3,) INS_OD_K: k1 (mm^-2), k2 (mm^-4), k3 (mm^-6)
    decentering: np.ndarray                 # (3,) INS_DECENTER: j1 (mm^-1), j2 (mm^-3), t0 (radians)
    semi_major_m: float
    semi_minor_m: float
    alpha_cube: AlphaCube
    target_naif_code: int | None = None     # the target body's NAIF code (301: the Moon), None if not named


def _need(d: dict, key: str, path: str, where: str = ""):
    if not isinstance(d, dict) or key not in d or d[key] is None:
        raise BlockError(path, f"missing key '{where}{key}'", column=f"{where}{key}")
    return d[key]


def _vector(value, n: int, path: str, key: str) -> np.ndarray:
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise BlockError(path, f"'{key}' must be numbers", column=key) from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise BlockError(path, f"'{key}' must be {n} finite numbers, found {value!r}", column=key)
    return a


def _rows(value, n: int, path: str, key: str) -> np.ndarray:
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise BlockError(path, f"'{key}' must be numbers", column=key) from None
    if a.ndim != 2 or a.shape[1] != n or len(a) == 0 or not np.all(np.isfinite(a)):
        raise BlockError(path, f"'{key}' must be finite numbers of shape (k, {n}), found shape {a.shape}", column=key)
    return a


def _times(section: dict, count: int, path: str, name: str) -> np.ndarray:
    t = _vector(_need(section, "ephemeris_times", path, name + "."), count, path, f"{name}.ephemeris_times")
    if np.any(np.diff(t) <= 0):
        raise BlockError(path, f"'{name}.ephemeris_times' must increase", column=f"{name}.ephemeris_times")
    return t


def _rotation(isd: dict, name: str, path: str):
    section = mapping(path, _need(isd, name, path), name)
    q = _rows(_need(section, "quaternions", path, name + "."), 4, path, f"{name}.quaternions")
    norms = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-6):
        k = int(np.argmax(np.abs(norms - 1.0)))
        raise BlockError(path, f"'{name}.quaternions' #{k} is not a unit quaternion (norm {norms[k]:.9f})",
                         column=f"{name}.quaternions")
    constant = _vector(section.get("constant_rotation", np.eye(3).ravel().tolist()), 9, path,
                       f"{name}.constant_rotation").reshape(3, 3)
    if np.abs(constant @ constant.T - np.eye(3)).max() > 1e-6:
        raise BlockError(path, f"'{name}.constant_rotation' is not a rotation matrix",
                         column=f"{name}.constant_rotation")
    return _times(section, len(q), path, name), q, constant


def read_frame_isd(path: str | os.PathLike, alpha_cube: AlphaCube | None = None) -> FrameIsd:
    """Read a usgscsm/ALE frame ISD (module docstring); errors name the file and the key. ``alpha_cube``
    (from the image's ISIS label) places the ISD's cube in the full detector; it must be as large as the
    ISD's image."""
    path = str(path)
    isd = read_json(path, "ISD")
    if not isinstance(isd, dict):
        raise BlockError(path, "not an ISD (a JSON object is expected)")
    model = _need(isd, "name_model", path)
    if model != FRAME_MODEL:
        raise BlockError(path, f"name_model is '{model}'; only {FRAME_MODEL} is read here", column="name_model")
    samples, lines = (integer(path, _need(isd, key, path), key) for key in ("image_samples", "image_lines"))
    if alpha_cube is None:
        alpha_cube = AlphaCube.identity(samples, lines)
    elif (alpha_cube.beta_samples, alpha_cube.beta_lines) != (samples, lines):
        raise BlockError(path, f"the image is {samples} x {lines} but its label's AlphaCube has "
                               f"{alpha_cube.beta_samples} x {alpha_cube.beta_lines}", column="image_samples")
    position = mapping(path, _need(isd, "instrument_position", path), "instrument_position")
    unit = _UNIT_TO_M.get(position.get("unit", "km"))
    if unit is None:
        raise BlockError(path, f"instrument_position.unit '{position['unit']}' is neither km nor m",
                         column="instrument_position.unit")
    positions = _rows(_need(position, "positions", path, "instrument_position."), 3, path,
                      "instrument_position.positions")
    velocities = _rows(_need(position, "velocities", path, "instrument_position."), 3, path,
                       "instrument_position.velocities")
    if len(velocities) != len(positions):
        raise BlockError(path, f"{len(positions)} positions but {len(velocities)} velocities",
                         column="instrument_position.velocities")
    position_times = _times(position, len(positions), path, "instrument_position")
    pointing = _rotation(isd, "instrument_pointing", path)
    body = _rotation(isd, "body_rotation", path)
    radii = mapping(path, _need(isd, "radii", path), "radii")
    radius_unit = _UNIT_TO_M.get(radii.get("unit", "km"))
    if radius_unit is None:
        raise BlockError(path, f"radii.unit '{radii['unit']}' is neither km nor m", column="radii.unit")
    naif = mapping(path, _need(isd, "naif_keywords", path), "naif_keywords")
    codes = {int(m.group(1)) for m in map(re.compile(r"INS(-[0-9]{1,12})_").match, naif) if m}
    if len(codes) != 1:
        raise BlockError(path, f"naif_keywords name {len(codes)} instruments (INS<code>_...); one is expected",
                         column="naif_keywords")
    code = codes.pop()

    def ins(name: str, n: int) -> np.ndarray:
        key = f"INS{code}_{name}"
        return _vector(_need(naif, key, path, "naif_keywords."), n, path, f"naif_keywords.{key}")

    if code not in APOLLO_METRIC_CODES:
        raise BlockError(path, f"naif_keywords are of instrument {code}; the frame model reads the Apollo Metric "
                               f"cameras ({', '.join(map(str, APOLLO_METRIC_CODES))}), whose distortion ISIS "
                               "defines (INS_OD_K, INS_DECENTER)", column="naif_keywords")
    def scalar(name: str) -> float:
        key = f"INS{code}_{name}"
        return float(_vector(np.ravel(_need(naif, key, path, "naif_keywords.")), 1, path, f"naif_keywords.{key}")[0])

    focal, pitch = scalar("FOCAL_LENGTH"), scalar("PIXEL_PITCH")
    if focal <= 0:
        raise BlockError(path, f"INS{code}_FOCAL_LENGTH must be positive, found {focal}",
                         column=f"naif_keywords.INS{code}_FOCAL_LENGTH")
    return FrameIsd(
        path=path, sensor_name=str(isd.get("name_sensor", "")), platform_name=str(isd.get("name_platform", "")),
        naif_code=code, image_samples=samples, image_lines=lines,
        center_time_s=number(path, _need(isd, "center_ephemeris_time", path), "center_ephemeris_time"),
        position_times_s=position_times, positions_m=positions * unit, velocities_m_s=velocities * unit,
        pointing_times_s=pointing[0], pointing_quaternions=pointing[1], pointing_constant=pointing[2],
        body_times_s=body[0], body_quaternions=body[1], body_constant=body[2],
        focal_length_mm=focal, pixel_pitch_mm=pitch,
        trans_x=ins("TRANSX", 3), trans_y=ins("TRANSY", 3), itrans_s=ins("ITRANSS", 3), itrans_l=ins("ITRANSL", 3),
        principal_point_mm=ins("PP", 2), radial_k=ins("OD_K", 3), decentering=ins("DECENTER", 3),
        semi_major_m=number(path, _need(radii, "semimajor", path, "radii."), "radii.semimajor", True) * radius_unit,
        semi_minor_m=number(path, _need(radii, "semiminor", path, "radii."), "radii.semiminor", True) * radius_unit,
        alpha_cube=alpha_cube, target_naif_code=target_naif_code(isd))
