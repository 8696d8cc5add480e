"""The line camera of a SPOT 5 DIMAP file (:mod:`selfcal.io.spot`) as a selfcal
:class:`~selfcal.sensors.pushbroom.LineImage`, with the frames of the SPOT 1-5 geometry handbook
(GAEL-P135-DOC-001) as NASA Ames Stereo Pipeline implements them (``LinescanSpotModel``, ``SPOT_XML``):

* pixels: DIMAP rows and columns are 1-based at pixel centres (``PIXEL_ORIGIN`` 1); selfcal's
  (row, col) = (ROW, COL) - PIXEL_ORIGIN + 0.5. Column COL is detector DETECTOR_ID = COL;
* time: t(ROW) = SCENE_CENTER_TIME + (ROW - SCENE_CENTER_LINE) LINE_PERIOD;
* look direction of a detector in the navigation frame O1: u1 = (-tan PSI_Y, tan PSI_X, -1);
* O1 -> local orbital frame O2: M = Mp Mr My of the corrected yaw, pitch, roll (handbook Eq. 11, ASP's
  ``get_look_rotation_matrix``); O2 -> Earth-fixed: the columns X2 = (V x Z2)/|.|, Y2 = Z2 x X2, Z2 = P/|P|;
* interpolation: positions and velocities by Lagrange polynomials of order 8 (4 samples on either side,
  as the handbook and ASP do), the yaw, pitch and roll linearly between their samples (the handbook's
  prescription) and held at the first / last sample beyond them (ASP pads the same way); no aberration or
  refraction correction (nor in ASP's SPOT 5 model).

In selfcal's axes (x along track, y, z towards the scene) the orbit frame O2 is selfcal's orbit frame
exactly: x_o = Y2, y_o = X2, z_o = -Z2 (P = [[0,1,0],[1,0,0],[0,0,-1]]). The body frame takes the same
permutation of O1, so R_OB = P M P and the detector looks along (tan PSI_X, -tan PSI_Y, 1) in the body. The
telescope is the body pitched forward by the look angle PSI_X of the middle detector (``view_pitch_deg``: HRS
looks +-20 degrees along track), so that the detector line lies near the focal plane's y axis; the focal length
makes the mean detector spacing :data:`DETECTOR_PITCH_MM` (the look angles fix only the angles). The look angles
between the detectors are a least-squares polynomial in the detector index (:func:`look_angle_polynomials`),
whose degree ``look_angle_degree`` also decides how a line longer than the table is extrapolated
(``columns``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .pushbroom import LineCamera, LineImage, Trajectory, angles_from_body_to_orbit, fit_focal_plane, rotation_y
from .usgscsm import LagrangeSeries

__all__ = ["line_image_from_spot5", "look_angle_polynomials", "look_rotation", "SpotAttitude", "DETECTOR_PITCH_MM",
           "LOOK_ANGLE_TOLERANCE_RAD", "P_ORBIT"]

#: SPOT 5 HRS / HRG detector pitch (mm): sets the nominal focal length, f = pitch / (mean d tan PSI_Y / d detector)
DETECTOR_PITCH_MM = 0.0065
#: the look-angle polynomial's degree grows until it fits the table within this (rad; the file gives 1e-11)
LOOK_ANGLE_TOLERANCE_RAD = 2e-10
#: SPOT's orbital (and navigation) axes -> selfcal's: x = Y2, y = X2, z = -Z2
P_ORBIT = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def look_rotation(yaw, pitch, roll) -> np.ndarray:
    """M = Mp Mr My (n, 3, 3): navigation frame O1 -> local orbital frame O2 (handbook Eq. 11a-e)."""
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, float)) for a in (yaw, pitch, roll))
    cp, sp, cr, sr, cy, sy = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll), np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([cr * cy, -cr * sy, -sr], -1),
                     np.stack([cp * sy + sp * sr * cy, cp * cy - sp * sr * sy, sp * cr], -1),
                     np.stack([-sp * sy + cp * sr * cy, -sp * cy - cp * sr * sy, cp * cr], -1)], -2)


@dataclass(frozen=True)
class SpotAttitude:
    """selfcal's roll, pitch, yaw (n, 3) of the body in the orbit frame at times t: the corrected yaw, pitch,
    roll interpolated linearly (held beyond the ends), R_OB = P M P."""

    times_s: np.ndarray
    yaw_pitch_roll: np.ndarray

    def __call__(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        ypr = [np.interp(t, self.times_s, self.yaw_pitch_roll[:, k]) for k in range(3)]
        return angles_from_body_to_orbit(P_ORBIT @ look_rotation(*ypr) @ P_ORBIT)


def look_angle_polynomials(sensor, degree: int | None = None, tolerance_rad: float = LOOK_ANGLE_TOLERANCE_RAD):
    """Least-squares polynomials (coefficients, lowest first) of tan PSI_X and tan PSI_Y in the detector
    index; ``degree`` None: the lowest (up to 5) that fits the table within ``tolerance_rad``. Returns
    (cx, cy, degree, largest misfit in tan)."""
    index = sensor.detector_ids.astype(float)
    tx, ty = np.tan(sensor.psi_x_rad), np.tan(sensor.psi_y_rad)
    degrees = [degree] if degree is not None else range(1, 6)
    for d in degrees:
        d = min(d, len(index) - 1)
        cx = np.polynomial.polynomial.polyfit(index, tx, d)
        cy = np.polynomial.polynomial.polyfit(index, ty, d)
        misfit = float(max(np.abs(np.polynomial.polynomial.polyval(index, cx) - tx).max(),
                           np.abs(np.polynomial.polynomial.polyval(index, cy) - ty).max()))
        if misfit <= tolerance_rad:
            break
    return cx, cy, d, misfit


def line_image_from_spot5(sensor, image_id: str | None = None, columns: int | None = None,
                          look_angle_degree: int | None = None) -> LineImage:
    """The selfcal line camera of a :class:`~selfcal.io.spot.Spot5Sensor` (module docstring).

    ``columns`` (default the file's NCOLS) extends the detector line beyond the look-angle table by the
    polynomial of ``look_angle_degree`` (an extrapolation: a truncated file keeps the full scene's corners)."""
    image_id = image_id or sensor.mission.replace(" ", "")
    columns = int(columns or sensor.columns)
    origin = sensor.pixel_origin
    cx, cy, _, _ = look_angle_polynomials(sensor, look_angle_degree)
    center_col = 0.5 * columns
    middle = center_col - 0.5 + origin                               # DIMAP column (= detector) of the middle
    view_pitch = float(np.arctan(np.polynomial.polynomial.polyval(middle, cx)))
    slope = abs(np.polynomial.polynomial.polyval(middle, np.polynomial.polynomial.polyder(cy)))
    focal = DETECTOR_PITCH_MM / slope
    R_TB = rotation_y(-view_pitch)                                     # body -> telescope

    def detector_line(cols):
        index = cols - 0.5 + origin
        u_body = np.stack([np.polynomial.polynomial.polyval(index, cx) * np.ones_like(index),
                           -np.polynomial.polynomial.polyval(index, cy) * np.ones_like(index),
                           np.ones_like(index)], -1)
        u = u_body @ R_TB.T
        return focal * u[:, 0] / u[:, 2], focal * u[:, 1] / u[:, 2]

    focal_plane, _ = fit_focal_plane(detector_line, columns, center_col)
    camera = LineCamera(image_id, columns, center_col, DETECTOR_PITCH_MM, float(focal), sensor.line_period_s,
                        view_pitch_deg=float(np.degrees(view_pitch)), focal_plane_mm=focal_plane)
    t_eph = sensor.ephemeris_t_s
    step = (t_eph[-1] - t_eph[0]) / (len(t_eph) - 1)
    if np.any(np.abs(np.diff(t_eph) - step) > 1e-3 * step):
        raise ValueError(f"{sensor.path}: the ephemeris must be equally spaced for the Lagrange interpolation")
    position = LagrangeSeries(float(t_eph[0]), float(step), np.asarray(sensor.positions_m, float))
    velocity = LagrangeSeries(float(t_eph[0]), float(step), np.asarray(sensor.velocities_m_s, float))
    attitude = SpotAttitude(np.asarray(sensor.attitude_t_s, float), np.asarray(sensor.yaw_pitch_roll_rad, float))
    trajectory = Trajectory("ECEF", sensor.epoch_utc, position, velocity, attitude)
    t_first = sensor.center_time_s + (origin - 0.5 - sensor.center_line) * sensor.line_period_s
    return LineImage.nominal(image_id, camera, trajectory, t_first, sensor.rows)
