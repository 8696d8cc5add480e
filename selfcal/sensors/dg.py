"""The rigorous line camera of a DigitalGlobe / Maxar XML file (:mod:`selfcal.io.dg`) as a selfcal
:class:`~selfcal.sensors.pushbroom.LineImage`, with NASA Ames Stereo Pipeline's conventions (``LinescanDGModel``,
which hands the file to usgscsm's line scanner):

* pixels: DigitalGlobe's image lines and samples (the TLC list, the RPB) put the centre of the first pixel at
  (0, 0); selfcal's (row, col) = (line, sample) + 0.5;
* time: the TLC list gives the time of listed lines; between them (and beyond, with the end rates) the time is
  linear in the line. One entry gets ASP's slope 1 / AVGLINERATE (negative for SCANDIRECTION Reverse). Times
  are seconds after EPH/STARTTIME;
* detector: the detector of sample s sits in the camera frame at (DETORIGINX + s p sin r, DETORIGINY - s p cos r)
  mm (pitch p, DETROTANGLE r), and its line of sight is (x, y, PD) (usgscsm's look vector (-x, -y, -f) is the
  negative one, as its ``imageToRemoteImagingLocus`` says). The camera frame is selfcal's telescope frame
  (z towards the scene), so the detector line is x = DETORIGINX + s p sin r, y = DETORIGINY - s p cos r (y falls
  as the column grows) with the focal length PD; the column under the optical axis is DETORIGINY / (p cos r) + 0.5;
* attitude: the ATT quaternion (q1 q2 q3 vector, q4 scalar) rotates body vectors into ECF; the camera's
  rotation into ECF is R(q_ATT) R(QCS), QCS (QCS4 scalar) the camera -> body rotation of GEO/CAMERA_ATTITUDE.
  Camera positions are the EPH positions plus R(q_ATT) (CX, CY, CZ);
* interpolation as usgscsm does it for ASP: positions, velocities and the quaternions (brought to one
  hemisphere) by Lagrange polynomials of order 8 on their equally spaced samples
  (:class:`~selfcal.sensors.usgscsm.LagrangeSeries`), the quaternion normalised afterwards;
* corrections (``corrections``, ASP's default both): ASP turns every attitude sample by the atmospheric
  refraction (Saastamoinen) and then the velocity aberration of the ray of the line's centre column, computed
  with a sphere of radius 6371 km and a mean terrain height of 0 m (ASP takes both from IMD/BAND_P corners when
  the file has them; these files do not). Light time is not applied (nor by ASP).

The attitude reaches the generic model as roll, pitch and yaw in the orbit frame (:class:`OrbitAttitude`),
evaluated at every call: the lines of sight are the ones above, and seed 001's attitude corrections and focal
length apply to them unchanged.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.rotation import matrix_from_quaternion, quaternion_from_matrix
from .pushbroom import LineCamera, LineImage, Trajectory, fit_focal_plane, line_of_sight
from .pushbroom.model import TimeFunction
from .usgscsm import LagrangeSeries
from .vendor import LineTimes, OnLineTime, OrbitAttitude

if TYPE_CHECKING:
    from ..io.dg import DgSensor

__all__ = ["line_image_from_dg", "dg_line_times", "CORRECTIONS", "ASP_EARTH_RADIUS_M", "ASP_TERRAIN_HEIGHT_M",
           "saastamoinen_rad", "refraction_rotation", "aberration_rotation", "R_CAMERA_FROM_TELESCOPE"]

#: the corrections ASP applies to a DigitalGlobe camera, in its order
CORRECTIONS = ("refraction", "aberration")
#: ASP's defaults when the XML has no IMD/BAND_P corners (vw::camera DEFAULT_EARTH_RADIUS, ..._SURFACE_ELEVATION)
ASP_EARTH_RADIUS_M = 6371000.0
ASP_TERRAIN_HEIGHT_M = 0.0
LIGHT_SPEED_M_S = 299792458.0
#: the Earth's rotation rate ASP uses for the aberration (2 pi / sidereal day of 86164.0905 s)
EARTH_RATE_RAD_S = 2.0 * np.pi / 86164.0905
#: selfcal's telescope frame (x, y, z) in the DigitalGlobe camera frame: the same axes
R_CAMERA_FROM_TELESCOPE = np.eye(3)


def dg_line_times(sensor: DgSensor) -> LineTimes:
    """selfcal rows and their times from the TLC list (module docstring)."""
    lines, times = np.asarray(sensor.tlc_lines, float), np.asarray(sensor.tlc_times_s, float)
    if len(lines) == 1:
        direction = 1.0 if sensor.scan_forward else -1.0
        lines = np.array([lines[0], lines[0] + sensor.average_line_rate])
        times = np.array([times[0], times[0] + direction])
    return LineTimes(lines + 0.5, times)


def _rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) about unit axes (n, 3) by angles (n,) (right hand)."""
    half = 0.5 * np.asarray(angle, float)
    q = np.concatenate([axis * np.sin(half)[:, None], np.cos(half)[:, None]], axis=1)
    return matrix_from_quaternion(q, scalar_first=False)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def saastamoinen_rad(camera_height_m: float | np.ndarray, terrain_height_m: float | np.ndarray,
                     off_nadir_rad: float | np.ndarray) -> np.ndarray:
    """The refraction angle (rad) of Saastamoinen (1972) as ASP evaluates it: K tan(alpha), with K from the
    camera and terrain heights in km."""
    H, h = np.asarray(camera_height_m, float) / 1000.0, terrain_height_m / 1000.0
    p1 = (2335.0 / (H - h)) * (1.0 - 0.02257 * h) ** 5.256
    p2 = 0.8540 ** (H - 11.0) * (82.2 - 521.0 / (H - h))
    return (p1 - p2) * 1e-6 * np.tan(off_nadir_rad)


def refraction_rotation(centre: np.ndarray, ray: np.ndarray, earth_radius_m: float, terrain_height_m: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """ASP's atmospheric refraction correction of rays (n, 3) from camera centres (n, 3): the rotation (n, 3, 3)
    turning each ray towards the nadir by the Saastamoinen angle, and the corrected rays."""
    ray = _unit(ray)
    down = -_unit(centre)
    alpha = np.arccos(np.clip(np.einsum("ni,ni->n", down, ray), -1.0, 1.0))
    delta = saastamoinen_rad(np.linalg.norm(centre, axis=1) - earth_radius_m, terrain_height_m, alpha)
    R = _rotation(_unit(np.cross(ray, down)), delta)
    return R, np.einsum("nij,nj->ni", R, ray)


def aberration_rotation(centre: np.ndarray, velocity: np.ndarray, ray: np.ndarray, earth_radius_m: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """ASP's velocity aberration correction: the camera velocity (Earth-fixed) less the surface's rotation
    velocity at the ray's range to the sphere, its part across the ray over c added to the ray; the rotation
    (n, 3, 3) doing that and the corrected rays."""
    ray = _unit(ray)
    r = np.linalg.norm(centre, axis=1)
    cos_angle = np.einsum("ni,ni->n", ray, -centre / r[:, None])
    along = r * cos_angle
    range_m = along - np.sqrt(earth_radius_m ** 2 + along ** 2 - r ** 2)
    omega = np.array([0.0, 0.0, EARTH_RATE_RAD_S])
    v = velocity - range_m[:, None] * np.cross(omega, ray)
    v = v - np.einsum("ni,ni->n", v, ray)[:, None] * ray
    correction = -v / LIGHT_SPEED_M_S
    angle = np.arctan(np.linalg.norm(correction, axis=1))
    R = _rotation(_unit(np.cross(ray, correction)), angle)
    return R, _unit(ray + correction)


def _same_hemisphere(q: np.ndarray) -> np.ndarray:
    q = np.array(q, float)
    for k in range(1, len(q)):
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    return q


def _build(sensor, image_id: str, quaternions: LagrangeSeries, line_times: LineTimes, camera: LineCamera,
           position: LagrangeSeries, velocity: LagrangeSeries) -> LineImage:
    """The LineImage of camera -> ECF quaternion samples (x, y, z, w; the camera attitude QCS included)."""

    def rotation(t):                      # telescope -> ECF at true times t
        return matrix_from_quaternion(quaternions(t), scalar_first=False) @ R_CAMERA_FROM_TELESCOPE

    tau0 = float(line_times.time(0.0))
    pos: TimeFunction
    vel: TimeFunction
    rot: TimeFunction
    if line_times.linear:
        pos, vel, rot = position, velocity, rotation
    else:
        pos, vel, rot = (OnLineTime(f, line_times, tau0) for f in (position, velocity, rotation))
    trajectory = Trajectory("ECEF", sensor.epoch_utc, pos, vel, OrbitAttitude(pos, vel, rot))
    return LineImage.nominal(image_id, camera, trajectory, tau0, sensor.rows)


def line_image_from_dg(sensor: DgSensor, image_id: str | None = None, corrections: Iterable[str] = CORRECTIONS,
                       earth_radius_m: float = ASP_EARTH_RADIUS_M,
                       terrain_height_m: float = ASP_TERRAIN_HEIGHT_M) -> LineImage:
    """The selfcal line camera of a :class:`~selfcal.io.dg.DgSensor` (module docstring). ``corrections`` is a
    subset of :data:`CORRECTIONS` (``()`` for the uncorrected camera)."""
    unknown = set(corrections) - set(CORRECTIONS)
    if unknown:
        raise ValueError(f"unknown corrections {sorted(unknown)}; known: {', '.join(CORRECTIONS)}")
    image_id = image_id or sensor.satellite
    p, pd = sensor.detector_pitch_mm, sensor.principal_distance_mm
    ox, oy = sensor.detector_origin_mm
    rot = np.radians(sensor.detector_rotation_deg)
    center_col = oy / (p * np.cos(rot)) + 0.5

    def detector_line(cols):                      # telescope frame, mm
        s = cols - 0.5
        return ox + s * p * np.sin(rot), oy - s * p * np.cos(rot)

    focal_plane, _ = fit_focal_plane(detector_line, sensor.columns, center_col)
    line_times = dg_line_times(sensor)
    camera = LineCamera(image_id, sensor.columns, float(center_col), p, pd, line_times.period_s,
                        focal_plane_mm=focal_plane)

    # ephemeris and attitude samples as ASP hands them to usgscsm
    R_body = matrix_from_quaternion(sensor.quaternions, scalar_first=False)
    offset = np.einsum("nij,j->ni", R_body, np.asarray(sensor.perspective_center_m, float))
    position = LagrangeSeries(sensor.ephemeris_t0_s, sensor.ephemeris_dt_s, sensor.positions_m + offset)
    velocity = LagrangeSeries(sensor.ephemeris_t0_s, sensor.ephemeris_dt_s, np.asarray(sensor.velocities_m_s, float))
    R_cam = R_body @ matrix_from_quaternion(np.asarray(sensor.camera_attitude, float), scalar_first=False)
    q_cam = _same_hemisphere(quaternion_from_matrix(R_cam, scalar_first=False))
    t_q = sensor.attitude_t0_s + sensor.attitude_dt_s * np.arange(len(q_cam))
    plain = _build(sensor, image_id, LagrangeSeries(sensor.attitude_t0_s, sensor.attitude_dt_s, q_cam),
                   line_times, camera, position, velocity)
    if not corrections:
        return plain

    # ASP: at each attitude sample, the ray of the centre column of the line of that time (the line by a
    # straight fit of the first and last line times), corrected; the sample turned with it
    first, last = line_times.time(0.5), line_times.time(sensor.rows - 0.5)
    row = 0.5 + (sensor.rows - 1.0) * (t_q - first) / (last - first)
    _, ray = line_of_sight(plain, row, np.full_like(row, sensor.columns / 2.0 + 0.5))
    centre, velocity_t = position(t_q), velocity(t_q)
    R_total = np.broadcast_to(np.eye(3), (len(t_q), 3, 3))
    for name in CORRECTIONS:
        if name not in corrections:
            continue
        if name == "refraction":
            R, ray = refraction_rotation(centre, ray, earth_radius_m, terrain_height_m)
        else:
            R, ray = aberration_rotation(centre, velocity_t, ray, earth_radius_m)
        R_total = R @ R_total
    q_corrected = _same_hemisphere(quaternion_from_matrix(R_total @ R_cam, scalar_first=False))
    return _build(sensor, image_id, LagrangeSeries(sensor.attitude_t0_s, sensor.attitude_dt_s, q_corrected),
                  line_times, camera, position, velocity)
