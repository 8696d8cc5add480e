"""A selfcal line camera from a usgscsm line-scan description (ISD), and usgscsm's ground functions.

The frames of usgscsm's line scanner (``UsgsAstroLsSensorModel``), as selfcal reproduces them:

* time of an image point: t = t_i + rate (line - line_i + 0.5) (one entry of ``line_scan_rate``;
  the 0.5 makes it the line's centre of exposure), so selfcal's first-line time is the t of
  line 0;
* focal plane: the detector (starting line, sample x summing + starting sample) minus the
  detector centre, through the inverse of ``focal2pixel``, gives the distorted (x, y) in mm;
  the lens distortion is removed (``radial``: x (1 - k0 - k1 r² - k2 r⁴); ``lrolrocnac``:
  y / (1 + k y²));
* camera look vector (-x, -y, -f), turned into the target body's frame by the rotation
  sensor -> J2000 -> body (the ISD's quaternions, scalar first, with their constant
  rotations);
* telemetry as usgscsm builds it from an ISD (with ALE): the positions are resampled on at least
  25 equally spaced nodes by a cubic Hermite spline through the ISD's positions and velocities,
  rotated to the body frame, and interpolated by Lagrange polynomials of order 8 (lower near the
  ends); the sensor -> body quaternions are resampled equally spaced (slerp) over the merged
  times of pointing and body rotation and interpolated the same way, then normalised;
* ``imageToGround`` at height h meets the ellipsoid of semi-axes a + h, b + h: of the two
  intersections of the *line* it takes the one nearer the sensor, on either side of it, and a
  line that misses gives its point nearest the ellipsoid (usgscsm warns; selfcal's own
  :func:`~selfcal.geometry.earth.intersect_ellipsoid` returns NaN instead).

selfcal's telescope frame T looks along +z with (x_T, y_T) = (-x, y): R_cam,T = Rx(180°), folded
into the attitude, so the boresight angles stay zero and the detector line is ``focal_plane_mm``
of :class:`~selfcal.sensors.pushbroom.LineCamera`. The attitude is handed to the sensor model as
roll, pitch, yaw in the orbit frame of the interpolated position and velocity, computed from the
interpolated rotation at each time (no fit), so the lines of sight are usgscsm's and the
calibration parameters of seed 001 (Eq. 6) apply to it unchanged. Velocity aberration and light
time are not applied (usgscsm's ``imageToGround`` does not either).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ..geometry.earth import orbit_frame
from ..geometry.rotation import matrix_from_quaternion, quaternion_from_matrix, slerp
from .pushbroom import (LineCamera, LineImage, Trajectory, angles_from_body_to_orbit, fit_focal_plane, ground_to_image,
                        line_of_sight, rotation_x)

if TYPE_CHECKING:
    from ..io.usgscsm import LineScanIsd

__all__ = ["UsgscsmLineSensor", "SENSOR", "IMAGE_PARAMETERS", "LineScan", "line_scan_from_isd", "undistort", "LagrangeSeries", "hermite", "usgscsm_ellipsoid_point",
           "FOCAL_PLANE_TOLERANCE_MM", "DISTORTION_MODELS", "MIN_EPHEMERIS_NODES"]

#: the focal-plane polynomial reproduces the undistorted detector positions to this (mm)
FOCAL_PLANE_TOLERANCE_MM = 1e-10
DISTORTION_MODELS = ("radial", "lrolrocnac")
#: usgscsm resamples the ephemeris on at least this many equally spaced nodes
MIN_EPHEMERIS_NODES = 25


# --- interpolation as usgscsm and ALE do it ------------------------------------------------------

def hermite(times: np.ndarray, values: np.ndarray, rates: np.ndarray, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise cubic Hermite interpolation of ``values`` (n, k) with derivatives ``rates`` at increasing
    ``times``; returns the values and derivatives at ``t`` (the end intervals extend beyond the ends)."""
    t = np.atleast_1d(np.asarray(t, float))
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    h = (times[i + 1] - times[i])[:, None]
    u = ((t - times[i])[:, None]) / h
    p0, p1, v0, v1 = values[i], values[i + 1], rates[i] * h, rates[i + 1] * h
    u2, u3 = u * u, u * u * u
    value = (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * v0 + (-2 * u3 + 3 * u2) * p1 + (u3 - u2) * v1
    rate = ((6 * u2 - 6 * u) * p0 + (3 * u2 - 4 * u + 1) * v0 + (-6 * u2 + 6 * u) * p1 + (3 * u2 - 2 * u) * v1) / h
    exact = np.isin(t, times)                  # ALE returns a sample itself at its own time
    if exact.any():
        k = np.searchsorted(times, t[exact])
        value[exact], rate[exact] = values[k], rates[k]
    return value, rate


@dataclass(frozen=True)
class LagrangeSeries:
    """Equally spaced samples (n, k) from ``t0`` every ``dt`` s, interpolated as usgscsm's ``lagrangeInterp``:
    Lagrange polynomials through the 8 nodes around t, fewer (6, 4, 2) within 3 nodes of an end."""

    t0: float
    dt: float
    values: np.ndarray

    def __call__(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        n = len(self.values)
        position = (t - self.t0) / self.dt
        index = np.clip(np.trunc(position).astype(int), 0, n - 2)
        order = np.where((index >= 3) & (index < n - 4), 8, np.where((index >= 2) & (index < n - 3), 6,
                                                                       np.where((index >= 1) & (index < n - 2), 4, 2)))
        out = np.empty((len(t), self.values.shape[1]))
        for m in np.unique(order):
            sel = np.flatnonzero(order == m)
            offsets = np.arange(-(m // 2 - 1), m // 2 + 1)            # nodes index-3 .. index+4 for order 8
            u = (position[sel] - index[sel])[:, None]
            weights = np.ones((sel.size, m))
            for j, a in enumerate(offsets):
                for b in offsets:
                    if b != a:
                        weights[:, j] *= (u[:, 0] - b) / (a - b)
            out[sel] = np.einsum("nj,njk->nk", weights, self.values[index[sel, None] + offsets[None, :]])
        return out


def _equally_spaced(first: float, last: float, count: int) -> np.ndarray:
    step = (last - first) / (count - 1)
    return first + step * np.arange(count)


@dataclass(frozen=True)
class _OrbitAttitude:
    """Roll, pitch, yaw of the body (selfcal's telescope frame) in the orbit frame of the interpolated
    ephemeris, from the interpolated rotation telescope -> body-fixed frame: evaluated, not fitted."""

    position: LagrangeSeries
    velocity: LagrangeSeries
    quaternions: LagrangeSeries         # x, y, z, w of sensor -> body-fixed (usgscsm's order)

    def __call__(self, t) -> np.ndarray:
        q = self.quaternions(t)
        R_FT = matrix_from_quaternion(q, scalar_first=False) @ rotation_x(np.pi)
        R_FO = orbit_frame(self.position(t), self.velocity(t))
        return angles_from_body_to_orbit(np.swapaxes(R_FO, -1, -2) @ R_FT)


# --- focal plane ----------------------------------------------------------------------------------

def undistort(x_mm: np.ndarray, y_mm: np.ndarray, model: str, coefficients: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted focal-plane coordinates of usgscsm's ``radial`` and ``lrolrocnac`` models."""
    k = np.asarray(coefficients, float)
    if model == "radial":
        k = np.concatenate([k, np.zeros(3)])[:3]
        r2 = x_mm * x_mm + y_mm * y_mm
        dr = k[0] + r2 * (k[1] + r2 * k[2])
        return x_mm * (1.0 - dr), y_mm * (1.0 - dr)
    if model == "lrolrocnac":
        return x_mm, y_mm / (1.0 + k[0] * y_mm * y_mm)
    raise ValueError(f"lens distortion model '{model}' is not supported (known: {', '.join(DISTORTION_MODELS)})")


def _focal_plane(isd, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted (x, y) mm of the detectors of image samples (usgscsm: the detector line at line 0)."""
    l0, l1, l2 = isd.focal2pixel_lines
    s0, s1, s2 = isd.focal2pixel_samples
    t1 = isd.starting_detector_line - isd.detector_center_line - l0
    t2 = samples * isd.sample_summing + isd.starting_detector_sample - isd.detector_center_sample - s0
    det = l1 * s2 - l2 * s1
    x = (s2 * t1 - l2 * t2) / det
    y = (-s1 * t1 + l1 * t2) / det
    return undistort(x, y, isd.distortion_model, isd.distortion_coefficients)


# --- the model ------------------------------------------------------------------------------------

def usgscsm_ellipsoid_point(origins: np.ndarray, directions: np.ndarray, semi_major_m: float | np.ndarray,
                            semi_minor_m: float | np.ndarray) -> np.ndarray:
    """usgscsm's ``losEllipsoidIntersect``: of the two points where the *line* S + s d meets the
    ellipsoid, the one with the smaller |s| (it may lie behind the sensor); a line that misses gives
    s = -b / 2a, its point nearest the ellipsoid in the scaled metric. The semi-axes (m) may be one per line."""
    S, d = np.atleast_2d(origins), np.atleast_2d(directions)
    semi_major_m = np.asarray(semi_major_m, float)
    k = (semi_major_m / np.asarray(semi_minor_m, float)) ** 2
    w = np.stack(np.broadcast_arrays(np.ones_like(k), np.ones_like(k), k), -1)
    a = np.sum(d * d * w, -1)
    b = 2.0 * np.sum(d * S * w, -1)
    c = np.sum(S * S * w, -1) - semi_major_m ** 2
    root = np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))
    s1, s2 = -b - root, -b + root
    s = np.where(np.abs(s2) < np.abs(s1), s2, s1) / (2 * a)
    return S + s[:, None] * d


@dataclass(frozen=True)
class LineScan:
    """A line-scan image of a usgscsm ISD as a selfcal :class:`LineImage`, with its body's ellipsoid."""

    image: LineImage
    semi_major_m: float
    semi_minor_m: float
    focal_plane_misfit_mm: float           # largest misfit of the focal-plane polynomial
    #: (3, 3): columns the roll, pitch, yaw increments (orbit frame) of a unit rotation of the sensor's pointing
    #: about J2000 Z, the node line and the sensor's Z at the image centre: jigsaw's RA, DEC, TWIST increments
    jigsaw_axes: np.ndarray | None = None
    #: (3, 3) J2000 -> body-fixed at the image centre: a J2000 position offset in the body frame
    body_from_j2000: np.ndarray | None = None

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, height_m: float | np.ndarray = 0.0) -> np.ndarray:
        """Body-fixed points (n, 3) of image points at ``height_m`` above the ellipsoid, as usgscsm's
        ``imageToGround`` (:func:`usgscsm_ellipsoid_point` with a + h, b + h)."""
        S, d = line_of_sight(self.image, line, sample)
        return usgscsm_ellipsoid_point(S, d, self.semi_major_m + height_m, self.semi_minor_m + height_m)

    def ground_to_image(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(line, sample) of body-fixed points."""
        return ground_to_image(self.image, points_m)

    def sensor_position(self, line: ArrayLike) -> np.ndarray:
        line = np.atleast_1d(np.asarray(line, float))
        return line_of_sight(self.image, line, np.zeros_like(line))[0]


def _body_from_j2000(isd, t: np.ndarray) -> np.ndarray:
    return isd.body_constant @ matrix_from_quaternion(slerp(isd.body_times_s, isd.body_quaternions, t))


def _pointing_to_body(isd, t: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) of sensor -> body at times t (slerp of both ISD rotations)."""
    R_sj = isd.pointing_constant @ matrix_from_quaternion(slerp(isd.pointing_times_s, isd.pointing_quaternions, t))
    q = quaternion_from_matrix(_body_from_j2000(isd, t) @ np.swapaxes(R_sj, 1, 2), scalar_first=False)
    for k in range(1, len(q)):                 # one hemisphere: the components are interpolated
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    return q


def line_scan_from_isd(isd: LineScanIsd, image_id: str | None = None) -> LineScan:
    """Build the selfcal line camera of a :class:`~selfcal.io.usgscsm.LineScanIsd` (module docstring).
    Times are relative to the ISD's centre ephemeris time."""
    if len(isd.line_scan_rate) != 1:
        raise ValueError(f"{isd.path}: {len(isd.line_scan_rate)} line rates; a variable line rate is not supported")
    line_i, t_i, rate = isd.line_scan_rate[0]
    t_first = t_i + rate * (0.0 - line_i + 0.5)
    # the column of the principal point: where the distorted y is zero on the detector line
    s0, s1, _ = isd.focal2pixel_samples
    l0, l1, _ = isd.focal2pixel_lines
    t1 = isd.starting_detector_line - isd.detector_center_line - l0
    center_col = (s1 * t1 / l1 + isd.detector_center_sample + s0 - isd.starting_detector_sample) / isd.sample_summing
    def telescope_frame(cols):                 # (x_T, y_T) = (-x, y) of the undistorted detector positions
        x, y = _focal_plane(isd, cols)
        return -x, y

    focal_plane, misfit = fit_focal_plane(telescope_frame, isd.image_samples, center_col, FOCAL_PLANE_TOLERANCE_MM)
    pixel_mm = abs(focal_plane[1][1]) / isd.image_samples
    camera = LineCamera(isd.sensor_name or "csm", isd.image_samples, float(center_col), float(pixel_mm),
                        isd.focal_length_mm, float(rate), focal_plane_mm=focal_plane)
    # ephemeris: Hermite-resampled on >= 25 equally spaced nodes, rotated to the body frame
    tp = isd.position_times_s
    nodes = _equally_spaced(tp[0], tp[-1], max(len(tp), MIN_EPHEMERIS_NODES))
    position_j, velocity_j = hermite(tp, isd.positions_m, isd.velocities_m_s, nodes)
    R_bj = _body_from_j2000(isd, nodes)
    step = nodes[1] - nodes[0]
    position = LagrangeSeries(float(nodes[0]), float(step), np.einsum("nij,nj->ni", R_bj, position_j))
    velocity = LagrangeSeries(float(nodes[0]), float(step), np.einsum("nij,nj->ni", R_bj, velocity_j))
    # attitude: sensor -> body on the merged times, resampled equally spaced
    tq = np.union1d(isd.pointing_times_s, isd.body_times_s)
    quat_nodes = _equally_spaced(tq[0], tq[-1], len(tq))
    quaternions = LagrangeSeries(float(quat_nodes[0]), float(quat_nodes[1] - quat_nodes[0]),
                                 _pointing_to_body(isd, quat_nodes))
    attitude = _OrbitAttitude(position, velocity, quaternions)
    trajectory = Trajectory("ECEF", "", position, velocity, attitude)
    image = LineImage.nominal(image_id or camera.camera_id, camera, trajectory, t_first, isd.image_lines)
    axes = _jigsaw_axes(isd, attitude, float(image.t_ref))
    body = _body_from_j2000(isd, np.array([float(image.t_ref)]))[0]
    return LineScan(image, isd.semi_major_m, isd.semi_minor_m, misfit, axes, body)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """The active rotation by ``angle`` about the unit vector ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _jigsaw_axes(isd, attitude: "_OrbitAttitude", t: float, step_rad: float = 1e-6) -> np.ndarray:
    """The roll, pitch, yaw increments (columns, per rad) that turn the sensor's lines of sight about jigsaw's
    three axes at time t: ISIS writes the J2000 -> sensor rotation C = R3(TWIST) R1(DEC) R3(RA), so an increment
    of RA turns the lines of sight (in J2000) about J2000 Z, one of DEC about the node line N = Z x Z_C / |.|,
    one of TWIST about the sensor's Z_C. Central differences of the orbit-frame angles of the turned pointing."""
    R_bj = _body_from_j2000(isd, np.array([t]))[0]
    R_sj = isd.pointing_constant @ matrix_from_quaternion(slerp(isd.pointing_times_s, isd.pointing_quaternions,
                                                                np.array([t])))[0]
    z_j = R_bj @ np.array([0.0, 0.0, 1.0])
    z_c = R_bj @ R_sj.T @ np.array([0.0, 0.0, 1.0])
    node = np.cross(z_j, z_c)
    if np.linalg.norm(node) < 1e-9:             # Z_C along J2000 Z: RA and TWIST turn about one axis (as in ISIS)
        node = np.cross(R_bj @ np.array([1.0, 0.0, 0.0]), z_c)
    node /= np.linalg.norm(node)
    q = attitude.quaternions(np.array([t]))
    R_FT = matrix_from_quaternion(q, scalar_first=False)[0] @ rotation_x(np.pi)
    R_FO = orbit_frame(attitude.position(np.array([t])), attitude.velocity(np.array([t])))[0]
    out = np.zeros((3, 3))
    for k, axis in enumerate((z_j, node, z_c)):
        turned = [angles_from_body_to_orbit(R_FO.T @ _rotation(axis, sign * step_rad) @ R_FT) for sign in (1, -1)]
        out[:, k] = (np.ravel(turned[0]) - np.ravel(turned[1])) / (2 * step_rad)
    return out


# --- the sensor contract: usgscsm line-scan images in a block (model = "usgscsm", line-scan ISDs) -------------

from .base import Parameter  # noqa: E402
from .pushbroom.sensor import PushbroomBound, PushbroomSensor  # noqa: E402

#: the attitude corrections of a line-scan ISD image: jigsaw's RA, DEC, TWIST increments (rotations of the
#: pointing about J2000 Z, the node line and the sensor's Z, :func:`_jigsaw_axes`) as polynomials of degree up to
#: 3 in s = (t - t_ref) / half the image's duration, coefficients in rad (jigsaw's CKDEGREE)
ATTITUDE_DEGREE_MAX = 3
_AXES = ("ra", "dec", "twist")
#: then a constant offset of the trajectory, J2000 X, Y, Z in m (jigsaw's spsolve=position)
_ATTITUDE_WIDTH = 3 * (ATTITUDE_DEGREE_MAX + 1)
IMAGE_PARAMETERS = tuple(Parameter(f"{a}_{k}", "rad", "EOP", screened=True)
                         for a in _AXES for k in range(ATTITUDE_DEGREE_MAX + 1)) + \
    tuple(Parameter(f"d{axis}", "m", "EOP", screened=True) for axis in "XYZ")


class _Context(dict):
    """Line images by image index, and each image's trajectory offset in the body frame (m)."""

    offsets: dict


def _scan(block, k: int) -> LineScan:
    return line_scan_from_isd(block.image_models[block.images.image_id[k]], str(block.images.image_id[k]))


class UsgscsmLineBound(PushbroomBound):
    """Line-scan ISD images (:func:`line_scan_from_isd`) with attitude corrections of degree up to 3."""

    def line_images(self, block, images, options):
        scans = {int(k): _scan(block, k) for k in images}
        self.radii = {k: (scan.semi_major_m, scan.semi_minor_m) for k, scan in scans.items()}
        self.axes = {k: scan.jigsaw_axes for k, scan in scans.items()}
        self.body_from_j2000 = {k: scan.body_from_j2000 for k, scan in scans.items()}
        return {k: scan.image for k, scan in scans.items()}

    def context(self, state, jacobians: bool = True):
        out = _Context(super().context(state, jacobians))
        out.offsets = {i: self.body_from_j2000[i] @ state.image[i, _ATTITUDE_WIDTH:_ATTITUDE_WIDTH + 3] for i in self.images}
        return out

    def _shift(self, context, img):
        """The trajectory offsets (m, 3) of the images ``img``."""
        out = np.zeros((len(img), 3))
        for i in np.unique(img):
            out[img == i] = context.offsets[int(i)]
        return out

    def pixels(self, context, img, points):
        return super().pixels(context, img, points - self._shift(context, img))

    def rays(self, context, img, pixel):
        origin, direction = super().rays(context, img, pixel)
        return origin + self._shift(context, img), direction

    def height(self, points):
        """Heights above the body's ellipsoid of the ISDs (the Moon: radius - 1737.4 km; a sphere, as usgscsm)."""
        a, b = next(iter(self.radii.values()))
        lat = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
        surface = a * b / np.hypot(b * np.cos(lat), a * np.sin(lat))        # geocentric radius of the ellipsoid
        return np.linalg.norm(points, axis=1) - surface

    def ground(self, context, img, pixel, height):
        """usgscsm's imageToGround at heights above the ellipsoid (a + h, b + h): one, one per point, or a DEM
        ``height(lat_deg, lon_deg)`` (planetocentric; the ray is intersected again at the DEM's height until
        it moves less than 1 mm)."""
        out = np.full((len(img), 3), np.nan)
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            a, b = self.radii[int(i)]
            S, d = line_of_sight(context[int(i)], pixel[sel, 1], pixel[sel, 0])
            S = S + context.offsets[int(i)]
            if not callable(height):
                h = np.broadcast_to(np.asarray(height, float), img.shape)[sel]
                out[sel] = usgscsm_ellipsoid_point(S, d, a + h, b + h)
                continue
            h = np.zeros(sel.size)
            for _ in range(20):
                point = usgscsm_ellipsoid_point(S, d, a + h, b + h)
                lat = np.degrees(np.arctan2(point[:, 2], np.hypot(point[:, 0], point[:, 1])))
                h_new = np.asarray(height(lat, np.degrees(np.arctan2(point[:, 1], point[:, 0]))), float)
                done = np.all(np.abs(h_new - h) < 1e-3)
                h = h_new
                if done:
                    break
            out[sel] = usgscsm_ellipsoid_point(S, d, a + h, b + h)
        return out

    attitude_axes = _AXES
    attitude_constant_columns = tuple(a * (ATTITUDE_DEGREE_MAX + 1) for a in range(3))

    def roll_pitch_yaw(self, i: int) -> np.ndarray:
        """The roll, pitch, yaw increments of unit RA, DEC, TWIST increments of image ``i``."""
        axes = self.axes[i]
        assert axes is not None                 # (a line scan of an ISD has its jigsaw axes)
        return axes

    def polynomial_design(self, i, rows):
        """d(RA, DEC, TWIST increments)/d(coefficients) at ``rows``: the powers of s."""
        image = self.images[i]
        s = (image.time_of_row(rows) - image.t_ref) / image.half_duration_s
        powers = s[:, None] ** np.arange(ATTITUDE_DEGREE_MAX + 1)[None, :]
        out = np.zeros((len(rows), 3, self.problem.image_width))
        for a in range(3):
            out[:, a, a * (ATTITUDE_DEGREE_MAX + 1):(a + 1) * (ATTITUDE_DEGREE_MAX + 1)] = powers
        return out

    def _image(self, state, i: int) -> LineImage:
        """The image with its polynomial coefficients as roll, pitch, yaw (the RA, DEC, TWIST coefficients through
        the image's axes): c0 and c1 / half-duration are Eq. 6's d_0 and d_1 (per second); c2, c3 the higher terms."""
        k = self.problem.image_camera[i]
        image = self.images[i]
        c = self.axes[i] @ state.image[i, :_ATTITUDE_WIDTH].reshape(3, ATTITUDE_DEGREE_MAX + 1)
        T = image.half_duration_s
        standard = np.array([c[0, 0], c[0, 1] / T, c[1, 0], c[1, 1] / T, c[2, 0], c[2, 1] / T])
        return image.with_parameters(np.concatenate([standard, state.cameras[k][:4]]), c[:, 2:],
                                     jitter=self._with_jitter(state, i))

    def power_columns(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The own columns of the attitude polynomial (per axis the powers of s = (t - t_ref) / half_duration, which
        is the jitter's s times the sign of the line period)."""
        n = self.jitter.n_powers if self.jitter is not None else ATTITUDE_DEGREE_MAX + 1
        sign = float(np.sign(self.images[i].camera.line_period_s))
        columns = np.array([[a * (ATTITUDE_DEGREE_MAX + 1) + k for k in range(n)] for a in range(3)])
        return columns, sign ** np.arange(n)

    def _predict(self, context, o, img, cam, points, jacobians):
        out = super()._predict(context, o, img, cam, points - self._shift(context, img), jacobians)
        if not jacobians:
            return out
        f, j_e, j_p, j_c = out
        s = np.zeros(len(img))
        j_axes = np.zeros((len(img), 2, 3))
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            image = self.images[int(i)]
            s[sel] = (self.t[o[sel]] - image.t_ref) / image.half_duration_s
            j_axes[sel] = j_e[sel][:, :, [0, 2, 4]] @ self.axes[int(i)]                 # d/d(RA, DEC, TWIST)
        powers = s[:, None] ** np.arange(ATTITUDE_DEGREE_MAX + 1)[None, :]          # (m, degree + 1)
        j = np.einsum("mra,mk->mrak", j_axes, powers).reshape(len(img), 2, 3 * (ATTITUDE_DEGREE_MAX + 1))
        j_offset = np.zeros((len(img), 2, 3))                      # the photo coordinates see P - S - offset
        for i in np.unique(img):
            sel = img == i
            j_offset[sel] = -j_p[sel] @ self.body_from_j2000[int(i)]
        j_e = np.zeros_like(j_e)
        j_e[:, :, :_ATTITUDE_WIDTH + 3] = np.concatenate([j, j_offset], axis=2)
        return f, j_e, j_p, j_c


class UsgscsmLineSensor(PushbroomSensor):
    """usgscsm / ALE line-scan ISDs (LRO NAC, MRO CTX, ...): the ISD's own trajectory and pointing as usgscsm
    interpolates them (:func:`line_scan_from_isd`), attitude corrections of the camera's ``attitude_degree`` as
    jigsaw parametrises them (RA and DEC; TWIST, the rotation about the sensor's Z, unless ``twist = false``) and
    the focal length and boresight held unless weighted (``sigma_focal_mm``)."""

    name = "usgscsm-line"
    image_parameters = IMAGE_PARAMETERS
    polynomial_parameters = IMAGE_PARAMETERS
    attitude_axes = _AXES
    attitude_degree = ATTITUDE_DEGREE_MAX
    sensor_models = ()
    needs_telemetry = False
    bound_type = UsgscsmLineBound

    def line_image(self, block, k, given_attitude=True):
        """The line image of image ``k``'s ISD, as usgscsm interpolates it."""
        return _scan(block, k).image

    def polynomial_setup(self, block, image_index, options):
        free = np.zeros((len(image_index), len(IMAGE_PARAMETERS)), bool)
        sigma = np.full(free.shape, np.nan)
        for row, i in enumerate(image_index):
            camera = block.cameras[block.images.camera_id[i]]
            axes = _AXES if camera.twist else _AXES[:2]
            for a, axis in enumerate(_AXES):
                if axis in axes:
                    free[row, a * 4:a * 4 + camera.attitude_degree + 1] = True
                    if camera.sigma_attitude_deg is not None:
                        sigma[row, a * 4] = np.radians(camera.sigma_attitude_deg)
            if camera.position_offsets:
                free[row, _ATTITUDE_WIDTH:] = True
                if camera.sigma_position_m is not None:
                    sigma[row, _ATTITUDE_WIDTH:] = camera.sigma_position_m
        return free, sigma

    def image_geometry(self, block, k, image_parameters, camera_parameters):
        raise NotImplementedError("a usgscsm-line image (a planetary body's ISD, with jigsaw's attitude and "
                                  "position corrections) has no RPC hand-over yet")

    def camera_setup(self, camera, options):
        held = np.zeros(4, bool)
        sigma = np.full(4, np.nan)
        if camera.sigma_focal_mm:
            held[0], sigma[0] = True, camera.sigma_focal_mm
        return np.array([camera.focal_mm, 0.0, 0.0, 0.0]), held, sigma


SENSOR = UsgscsmLineSensor()
