"""A selfcal line camera from the physical model of a Pleiades DIMAP file (:mod:`selfcal.io.dimap`).

Conventions, fixed against the vendor's rational model of the same images (the rows agree to
0.001 px; tests/test_rpc_vs_rigorous.py):

* time: selfcal row r (the centre of the first pixel at 0.5) is DIMAP row r + 0.5 (1-based
  centres), recorded at START + (r - 0.5) line periods;
* look angles: PsiX, PsiY are polynomials in the 0-based detector index, DIMAP column minus
  ``FIRST_COL`` (the 1-based reading puts every column one pixel off);
* line of sight in the satellite frame: (tan PsiY, -tan PsiX, 1), x along track, z towards the
  scene: selfcal's telescope frame is the satellite frame (no boresight);
* attitude: the quaternion (Q0 scalar) rotates satellite-frame vectors into WGS 84 Earth-fixed ones;
  it is sampled every ATTITUDE_SAMPLING_S and refitted as roll, pitch, yaw in the orbit frame
  (:func:`~selfcal.sensors.pushbroom.fit_trajectory`, order 5), the ephemeris by order-7 polynomials.

The look angles become focal-plane positions f tan(Psi) with a nominal focal length, so that the
calibration parameter ``focal`` scales the tangents of all look angles together.
"""
from __future__ import annotations

import numpy as np

from ..geometry.rotation import matrix_from_quaternion, quaternion_from_matrix
from .pushbroom import LineCamera, LineImage, fit_focal_plane, fit_trajectory

__all__ = ["line_image_from_dimap", "dimap_quaternions", "NOMINAL_FOCAL_MM", "ATTITUDE_SAMPLING_S"]

#: the look angles are turned into focal-plane positions with this focal length (Pleiades: 12.9 m)
NOMINAL_FOCAL_MM = 12905.0
#: the attitude polynomials are sampled every ATTITUDE_SAMPLING_S (s) for the fit of roll, pitch and yaw
ATTITUDE_SAMPLING_S = 0.02


def dimap_quaternions(sensor, t_s: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4), scalar first, of the attitude polynomials at times t (s from START)."""
    tau = (np.asarray(t_s, float) - sensor.attitude_offset_s) / sensor.attitude_scale_s
    q = np.stack([np.polynomial.polynomial.polyval(tau, c) * np.ones_like(tau) for c in sensor.quaternion_polynomials],
                 -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def line_image_from_dimap(sensor, image_id: str = "PHR", orders: tuple[int, int, int] = (7, 7, 5)) -> LineImage:
    """The selfcal line camera of a :class:`~selfcal.io.dimap.DimapSensor` (module docstring)."""
    n = sensor.columns
    center_col = 0.5 * n

    def focal_plane(cols):
        index = cols + 0.5 - sensor.first_retina_col             # 0-based detector index of DIMAP column col + 0.5
        psi_x = np.polynomial.polynomial.polyval(index, sensor.psi_x) * np.ones_like(index)
        psi_y = np.polynomial.polynomial.polyval(index, sensor.psi_y) * np.ones_like(index)
        return NOMINAL_FOCAL_MM * np.tan(psi_y), -NOMINAL_FOCAL_MM * np.tan(psi_x)

    detector_line, _ = fit_focal_plane(focal_plane, n, center_col)
    duration = sensor.rows * sensor.line_period_s
    t_q = np.arange(-1.0, duration + 1.0, ATTITUDE_SAMPLING_S)
    q = quaternion_from_matrix(matrix_from_quaternion(dimap_quaternions(sensor, t_q)), scalar_first=False)
    camera = LineCamera(image_id, n, center_col, float(abs(detector_line[1][1]) / n), NOMINAL_FOCAL_MM,
                        sensor.line_period_s, focal_plane_mm=detector_line)
    trajectory = fit_trajectory("ECEF", sensor.start_utc, sensor.ephemeris_t_s, sensor.positions_m,
                                sensor.velocities_m_s, t_q, q, orders, t_ref=0.5 * duration)
    return LineImage.nominal(image_id, camera, trajectory, -0.5 * sensor.line_period_s, sensor.rows)
