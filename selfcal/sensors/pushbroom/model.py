"""The generic pushbroom (linear CCD) sensor model of seed 001, with analytic Jacobians.

Frames (DESIGN.md §3): a detector column gives the line of sight u = (0, ys, f) in the
telescope frame T (x along track, y across track, z towards the scene), ys = (col -
center_col) * pixel size. The chain to the Earth-fixed frame E is

    u_E = R_EF(t) R_FO(t) R_OB(t) R_BT u,

with R_BT = Ry(view_pitch + b_pitch) Rx(b_roll) Rz(b_yaw) (telescope -> body, boresight
angles b), R_OB = Ry(pitch) Rx(roll) Rz(yaw) (body -> orbit, Eq. 4), R_FO the orbit frame
of the fitted position and velocity in the ephemeris frame F, and R_EF = GCRS -> ITRS
(pyerfa) when F is ECI (the identity when F is ECEF).

Roll, pitch and yaw come from the attitude quaternions (Eqs. 2-3): R_OB = R_FO^T R(q).
Ephemeris and attitude are fitted by least-squares polynomials in time (Eq. 5), and
the attitude is corrected by a constant and a linear term in time (Eq. 6),

    roll(t) = roll_fit(t) + d_roll0 + d_roll1 (t - t_ref),   and the same for pitch and yaw,

t_ref being the scene centre. With the focal length and the three boresight angles these
are the ten calibration parameters of an image (:data:`PARAMETER_NAMES`).

An image point (row, col) was recorded at t = t_first + row * line_period. A ground point
P lies on that line when w = R_TE(t) (P - S(t)) points at the detector of column col; in
photo coordinates the collinearity condition is

    x = f w_x / w_z = x_d,     y = f w_y / w_z = y_d,

with (x_d, y_d) the detector's focal-plane position: (0, ys) on the ideal line, displaced by
the known offset of its chip when the virtual array is made of several chips
(:class:`LineCamera`). The adjustment uses this form (row residual (x_d - x) / p, column
residual (y_d - y) / p). Ground-to-image solves x(t) = x_d for t by Newton's method
(:data:`TIME_TOLERANCE_LINES`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from numba import njit
from numpy.typing import ArrayLike

from ...geometry.earth import ecef_from_geodetic, geodetic_from_ecef, itrs_from_gcrs, local_up, orbit_frame

__all__ = ["PARAMETER_NAMES", "PARAMETER_UNITS", "LineCamera", "fit_focal_plane", "Polynomial", "fit_polynomial", "Trajectory",
           "fit_trajectory", "LineImage", "rotation_x", "rotation_y", "rotation_z", "angles_from_body_to_orbit",
           "photo_coordinates", "image_scales", "image_residuals", "ground_to_image", "line_of_sight", "image_to_ground", "intersect",
           "track_frame", "ecef_of", "Track", "track",
           "TIME_TOLERANCE_LINES"]

#: calibration parameters of a pushbroom image, in the order of :attr:`LineImage.parameters`
PARAMETER_NAMES = ("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1", "focal",
                   "boresight_roll", "boresight_pitch", "boresight_yaw")
#: units in code (files and reports convert: deg, deg/s, mm)
PARAMETER_UNITS = ("rad", "rad/s", "rad", "rad/s", "rad", "rad/s", "mm", "rad", "rad", "rad")

#: ground-to-image stops when the time correction is below this fraction of a line period
TIME_TOLERANCE_LINES = 1e-7
_MAX_NEWTON = 30


# --- elementary rotations --------------------------------------------------------------------------

def rotation_x(angle: ArrayLike) -> np.ndarray:
    """Rx(a) (..., 3, 3): turns +y towards +z."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rotation_y(angle: ArrayLike) -> np.ndarray:
    """Ry(a) (..., 3, 3): turns +z towards +x (a positive view pitch looks forward)."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rotation_z(angle: ArrayLike) -> np.ndarray:
    """Rz(a) (..., 3, 3): turns +x towards +y."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


_GENERATORS = {  # dR/da = R(a) G
    "x": np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "y": np.array([[0.0, 0, 1], [0, 0, 0], [-1, 0, 0]]),
    "z": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 0]]),
}


def _chain(pitch, roll, yaw):
    """Ry(pitch) Rx(roll) Rz(yaw) and its derivatives with respect to (roll, pitch, yaw)."""
    Ry, Rx, Rz = rotation_y(pitch), rotation_x(roll), rotation_z(yaw)
    R = Ry @ Rx @ Rz
    d_roll = Ry @ Rx @ _GENERATORS["x"] @ Rz
    d_pitch = Ry @ _GENERATORS["y"] @ Rx @ Rz
    d_yaw = R @ _GENERATORS["z"]
    return R, (d_roll, d_pitch, d_yaw)


def angles_from_body_to_orbit(R_OB: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) (..., 3) of R_OB = Ry(pitch) Rx(roll) Rz(yaw)."""
    roll = np.arcsin(np.clip(-R_OB[..., 1, 2], -1.0, 1.0))
    pitch = np.arctan2(R_OB[..., 0, 2], R_OB[..., 2, 2])
    yaw = np.arctan2(R_OB[..., 1, 0], R_OB[..., 1, 1])
    return np.stack([roll, pitch, yaw], -1)


def fit_focal_plane(positions_mm: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], columns: int, center_col: float, tolerance_mm: float = 1e-10,
                    max_degree: int = 11) -> tuple[tuple[tuple[float, ...], tuple[float, ...]], float]:
    """The :attr:`LineCamera.focal_plane_mm` polynomials of a detector line given by ``positions_mm(col) ->
    (x, y)`` (mm, telescope frame), of the lowest degree that reproduces it within ``tolerance_mm`` on
    Chebyshev-Lobatto nodes over the line (or ``max_degree``); returns them and the largest misfit."""
    nodes = 4 * max_degree + 1
    cols = 0.5 * columns * (1.0 - np.cos(np.pi * np.arange(nodes) / (nodes - 1)))
    x, y = positions_mm(cols)
    s = (cols - center_col) / columns
    for degree in range(1, max_degree + 1):
        V = np.polynomial.polynomial.polyvander(s, degree)
        cx = np.linalg.lstsq(V, x, rcond=None)[0]
        cy = np.linalg.lstsq(V, y, rcond=None)[0]
        misfit = float(max(np.max(np.abs(V @ cx - x)), np.max(np.abs(V @ cy - y))))
        if misfit <= tolerance_mm:
            break
    return (tuple(map(float, cx)), tuple(map(float, cy))), misfit


# --- telemetry ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class LineCamera:
    """A linear CCD camera: one virtual array of ``columns`` detectors (several chips merged).

    The chips of the array (seed 001, Fig. 1) start at the columns ``chip_starts`` (the first
    chip at column 0 is implied); ``chip_offsets_px`` gives each chip's known displacement
    (along track, across track) in pixels from the ideal line, so that the detector of column
    col sits at x = along p, y = (col - center_col + across) p in the focal plane.

    A calibrated line (a sensor description that gives the detectors' look directions, or a
    lens distortion that bends the line) is given by ``focal_plane_mm``: the coefficients (power
    series, lowest first) of x(s) and y(s) in mm with s = (col - center_col) / columns; chip
    offsets are then added to that line. ``pixel_size_mm`` then only scales the offsets.
    """

    camera_id: str
    columns: int
    center_col: float
    pixel_size_mm: float
    focal_mm: float
    line_period_s: float
    view_pitch_deg: float = 0.0
    chip_starts: tuple[int, ...] = ()
    chip_offsets_px: tuple[tuple[float, float], ...] = ()
    focal_plane_mm: tuple[tuple[float, ...], ...] = ()      # (x coefficients, y coefficients); (): the ideal line

    def __post_init__(self):
        if self.chip_offsets_px and len(self.chip_offsets_px) != len(self.chip_starts) + 1:
            raise ValueError(f"{len(self.chip_starts) + 1} chips need as many (along, across) offsets, "
                             f"found {len(self.chip_offsets_px)}")
        if self.focal_plane_mm and len(self.focal_plane_mm) != 2:
            raise ValueError("focal_plane_mm is (x coefficients, y coefficients)")

    def offsets_px(self, col: ArrayLike) -> np.ndarray:
        """(along, across) offset in pixels of the chip of each column, (n, 2)."""
        col = np.atleast_1d(np.asarray(col, float))
        if not self.chip_offsets_px:
            return np.zeros((len(col), 2))
        chip = np.searchsorted(np.asarray(self.chip_starts, float), col, side="right")
        return np.asarray(self.chip_offsets_px, float)[chip]


@dataclass(frozen=True)
class Polynomial:
    """Least-squares polynomial in time, a0 + a1 tau + ... with tau = (t - t_ref) / t_scale."""

    t_ref: float
    t_scale: float
    coefficients: np.ndarray        # (order + 1, k)

    @property
    def order(self) -> int:
        return self.coefficients.shape[0] - 1

    def _tau(self, t):
        return (np.asarray(t, float) - self.t_ref) / self.t_scale

    def __call__(self, t) -> np.ndarray:
        tau = self._tau(t)
        return np.polynomial.polynomial.polyval(tau, self.coefficients).T if np.ndim(tau) else \
            np.polynomial.polynomial.polyval(tau, self.coefficients)

    def rate(self, t: ArrayLike) -> np.ndarray:
        """d/dt of the polynomial."""
        d = np.polynomial.polynomial.polyder(self.coefficients, axis=0) / self.t_scale
        tau = self._tau(t)
        return np.polynomial.polynomial.polyval(tau, d).T if np.ndim(tau) else np.polynomial.polynomial.polyval(tau, d)


def fit_polynomial(t: np.ndarray, values: np.ndarray, order: int, t_ref: float | None = None
                   ) -> tuple[Polynomial, np.ndarray]:
    """Fit ``values`` (n, k) at times ``t`` by a polynomial of ``order`` (Eq. 5 of seed 001).

    Returns the polynomial and the residuals values - fit (n, k). Needs more samples than
    coefficients.
    """
    t = np.asarray(t, float)
    values = np.asarray(values, float).reshape(len(t), -1)
    if len(t) <= order:
        raise ValueError(f"{len(t)} samples cannot determine a polynomial of order {order}")
    t_ref = float(np.mean(t)) if t_ref is None else float(t_ref)
    t_scale = float(max(np.max(np.abs(t - t_ref)), 1e-9))
    V = np.polynomial.polynomial.polyvander((t - t_ref) / t_scale, order)
    coefficients = np.linalg.lstsq(V, values, rcond=None)[0]
    return Polynomial(t_ref, t_scale, coefficients), values - V @ coefficients


#: a function of time: t (s from the epoch; a scalar or (n,)) -> values (n, k): a fitted :class:`Polynomial`, or
#: the interpolated or evaluated telemetry of a sensor description (usgscsm's Lagrange series, a vendor's model)
TimeFunction = Callable[[Any], np.ndarray]


@dataclass(frozen=True)
class Trajectory:
    """An image's telemetry: position and velocity (frame F), roll/pitch/yaw (orbit frame), each a function of
    time (fitted polynomials of the ephemeris and attitude, Eq. 5 of seed 001, or a sensor description's own)."""

    frame: str                   # "ECI" or "ECEF": the frame of position, velocity and quaternions
    epoch_utc: str               # times count from here
    position: TimeFunction       # m
    velocity: TimeFunction       # m/s
    attitude: TimeFunction       # rad: roll, pitch, yaw
    fit_rms: dict = field(default_factory=dict)   # residual RMS of each fit (m, m/s, rad)

    def frame_to_ecef(self, t: ArrayLike) -> np.ndarray:
        """R_EF (n, 3, 3) at times t."""
        t = np.atleast_1d(np.asarray(t, float))
        if self.frame == "ECEF":
            return np.broadcast_to(np.eye(3), (len(t), 3, 3))
        return itrs_from_gcrs(self.epoch_utc, t)


def fit_trajectory(frame: str, epoch_utc: str, ephemeris_t: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                   attitude_t: np.ndarray, quaternions: np.ndarray, orders: tuple[int, int, int] = (7, 7, 3),
                   t_ref: float | None = None, given_attitude: bool = True) -> Trajectory:
    """Fit an image's ephemeris and attitude (quaternions q1..q4, scalar last, body -> F).

    Roll, pitch and yaw are those of R_OB = R_FO^T R(q) with R_FO from the fitted
    position and velocity at the quaternion times. ``given_attitude=False`` ignores the
    quaternions (roll = pitch = yaw = 0 before the corrections of Eq. 6; seed 001, Table 5).
    """
    from ...geometry.rotation import matrix_from_quaternion

    if frame not in ("ECI", "ECEF"):
        raise ValueError(f"frame must be ECI or ECEF, not {frame!r}")
    pos, pos_res = fit_polynomial(ephemeris_t, position, orders[0], t_ref)
    vel, vel_res = fit_polynomial(ephemeris_t, velocity, orders[1], t_ref)
    attitude_t = np.asarray(attitude_t, float)
    if given_attitude:
        R_FB = matrix_from_quaternion(np.asarray(quaternions, float), scalar_first=False)
        R_FO = orbit_frame(pos(attitude_t), vel(attitude_t))
        angles = angles_from_body_to_orbit(np.swapaxes(R_FO, 1, 2) @ R_FB)
        order = np.argsort(attitude_t)
        angles[order] = np.unwrap(angles[order], axis=0)     # a yaw near +/-180 deg stays continuous
    else:
        angles = np.zeros((len(attitude_t), 3))
    att, att_res = fit_polynomial(attitude_t, angles, orders[2], t_ref)

    def rms(r):
        return np.sqrt(np.mean(r ** 2, axis=0))

    return Trajectory(frame, epoch_utc, pos, vel, att,
                      {"position_m": rms(pos_res), "velocity_m_s": rms(vel_res), "attitude_rad": rms(att_res)})


@dataclass(frozen=True)
class LineImage:
    """One pushbroom image: its camera, fitted trajectory, first-line time and calibration parameters."""

    image_id: str
    camera: LineCamera
    trajectory: Trajectory
    t_first_s: float
    rows: int
    parameters: np.ndarray        # (10,) in the order of PARAMETER_NAMES; focal in mm
    #: higher-order attitude corrections (3, m): roll, pitch, yaw coefficients (rad) of s^2 .. s^(m+1) with
    #: s = (t - t_ref) / half_duration_s, beyond Eq. 6's constant and linear terms (ISIS jigsaw's CKDEGREE 3)
    attitude_terms: np.ndarray | None = None
    #: attitude jitter (:mod:`.jitter`): a basis of tau = row / rows with ``basis.combine(tau, coefficients)`` -> (n, 3)
    #: (a :class:`~.jitter.TimeWaveletBasis`) and the roll, pitch, yaw coefficients (3, m) in rad
    jitter: tuple | None = None

    @classmethod
    def nominal(cls, image_id: str, camera: LineCamera, trajectory: Trajectory, t_first_s: float,
                rows: int) -> "LineImage":
        parameters = np.zeros(len(PARAMETER_NAMES))
        parameters[PARAMETER_NAMES.index("focal")] = camera.focal_mm
        return cls(image_id, camera, trajectory, float(t_first_s), int(rows), parameters)

    @property
    def t_ref(self) -> float:
        """Scene-centre time: the origin of the linear attitude corrections (Eq. 6)."""
        return self.t_first_s + 0.5 * self.rows * self.camera.line_period_s

    @property
    def half_duration_s(self) -> float:
        """Half the time of the image's lines: the unit of the higher-order attitude terms' time."""
        return 0.5 * self.rows * abs(self.camera.line_period_s)

    def with_parameters(self, parameters: np.ndarray, attitude_terms: np.ndarray | None = None,
                        jitter: tuple | None = None) -> "LineImage":
        return replace(self, parameters=np.asarray(parameters, float).copy(),
                       attitude_terms=self.attitude_terms if attitude_terms is None else attitude_terms,
                       jitter=self.jitter if jitter is None else jitter)

    def attitude_correction(self, t: ArrayLike) -> np.ndarray:
        """The corrections (n, 3) of roll, pitch, yaw at times t: Eq. 6, the higher-order terms and the jitter."""
        a = self.parameters
        tau = np.atleast_1d(np.asarray(t, float)) - self.t_ref
        out = np.stack([a[0] + a[1] * tau, a[2] + a[3] * tau, a[4] + a[5] * tau], -1)
        if self.attitude_terms is not None and np.size(self.attitude_terms):
            s = tau / self.half_duration_s
            powers = s[:, None] ** (2 + np.arange(self.attitude_terms.shape[1]))[None, :]
            out = out + powers @ np.asarray(self.attitude_terms, float).T
        if self.jitter is not None and np.any(self.jitter[1]):          # (all zero at the start values)
            basis, coefficients = self.jitter
            out = out + basis.combine(self.row_of_time(tau + self.t_ref) / self.rows, coefficients)
        return out

    def time_of_row(self, row: ArrayLike) -> np.ndarray:
        return self.t_first_s + np.asarray(row, float) * self.camera.line_period_s

    def row_of_time(self, t: ArrayLike) -> np.ndarray:
        return (np.asarray(t, float) - self.t_first_s) / self.camera.line_period_s

    def detector_mm(self, col: ArrayLike) -> np.ndarray:
        """Focal-plane position (x, y) in mm (n, 2) of the detector of each column: (0, ys) on the
        ideal line, displaced by its chip's offset."""
        col = np.atleast_1d(np.asarray(col, float))
        cam = self.camera
        p = cam.pixel_size_mm
        offset = cam.offsets_px(col)
        if cam.focal_plane_mm:
            s = (col - cam.center_col) / cam.columns
            line = np.stack([np.polynomial.polynomial.polyval(s, c) * np.ones_like(s) for c in cam.focal_plane_mm], -1)
            return line + offset * p
        return np.stack([offset[:, 0] * p, (col - cam.center_col + offset[:, 1]) * p], -1)

    def col_of_y(self, y_mm: ArrayLike) -> np.ndarray:
        """The column whose detector has the focal-plane y (its chip's across offset taken off)."""
        if self.camera.focal_plane_mm:
            y_mm = np.atleast_1d(np.asarray(y_mm, float))
            col = self._col_of_y_polynomial(y_mm)
            if self.camera.chip_offsets_px:
                p = self.camera.pixel_size_mm
                for _ in range(2):
                    col = self._col_of_y_polynomial(y_mm - self.camera.offsets_px(col)[:, 1] * p)
            return col
        p = self.camera.pixel_size_mm
        col = self.camera.center_col + np.atleast_1d(np.asarray(y_mm, float)) / p
        for _ in range(2):                       # the chip depends on the column; offsets are sub-chip
            col = self.camera.center_col + np.asarray(y_mm, float) / p - self.camera.offsets_px(col)[:, 1]
        return col

    def _col_of_y_polynomial(self, y_mm: np.ndarray) -> np.ndarray:
        """Newton's method on y(s) = y_mm (y is monotonic along a detector line), to 1e-12 of the line."""
        cam = self.camera
        cy = np.asarray(cam.focal_plane_mm[1], float)
        dcy = np.polynomial.polynomial.polyder(cy)
        s = (y_mm - cy[0]) / cy[1] if len(cy) > 1 else np.zeros_like(y_mm)
        for _ in range(_MAX_NEWTON):
            step = (np.polynomial.polynomial.polyval(s, cy) - y_mm) / np.polynomial.polynomial.polyval(s, dcy)
            s = s - step
            if np.all(np.abs(step) < 1e-12):
                break
        return cam.center_col + s * cam.columns


def _attitude(image: LineImage, t: np.ndarray):
    """Corrected roll, pitch, yaw (n, 3) at times t."""
    fitted = np.atleast_2d(image.trajectory.attitude(t))
    return fitted + image.attitude_correction(t)


def _frames(image: LineImage, t: np.ndarray):
    """S_F (n, 3), R_FE (n, 3, 3) (Earth-fixed -> ephemeris frame), R_FO, the attitude chain
    R_OB with its angle derivatives, and R_BT with its boresight derivatives."""
    traj = image.trajectory
    S = np.atleast_2d(traj.position(t))
    V = np.atleast_2d(traj.velocity(t))
    R_FE = np.swapaxes(traj.frame_to_ecef(t), 1, 2)
    R_FO = orbit_frame(S, V)
    roll, pitch, yaw = _attitude(image, t).T
    R_OB, d_OB = _chain(pitch, roll, yaw)
    a = image.parameters
    b_roll, b_pitch, b_yaw = a[7], a[8], a[9]
    R_BT, d_BT = _chain(np.radians(image.camera.view_pitch_deg) + b_pitch, b_roll, b_yaw)
    return S, R_FE, R_FO, R_OB, d_OB, R_BT, d_BT


@dataclass(frozen=True)
class Track:
    """An image's telemetry at given times: what the calibration parameters do not change (an adjustment
    evaluates it once per observation, :func:`track`)."""

    t: np.ndarray                 # (n,) s
    position: np.ndarray          # (n, 3) S in the ephemeris frame F
    orbit_frame: np.ndarray       # (n, 3, 3) R_FO
    frame_to_ecef: np.ndarray     # (n, 3, 3) R_EF; (0, 3, 3) when F is Earth-fixed
    attitude: np.ndarray          # (n, 3) fitted roll, pitch, yaw (before the corrections of Eq. 6)

    def take(self, index: np.ndarray) -> "Track":
        earth = self.frame_to_ecef if not len(self.frame_to_ecef) else self.frame_to_ecef[index]
        return Track(self.t[index], self.position[index], self.orbit_frame[index], earth, self.attitude[index])


def track(image: LineImage, t: ArrayLike) -> Track:
    """The telemetry of ``image`` at times ``t``."""
    traj = image.trajectory
    t = np.atleast_1d(np.asarray(t, float))
    S = np.ascontiguousarray(np.atleast_2d(traj.position(t)), dtype=float)
    R_FO = np.ascontiguousarray(orbit_frame(S, np.atleast_2d(traj.velocity(t))))
    R_EF = np.zeros((0, 3, 3)) if traj.frame == "ECEF" else np.ascontiguousarray(traj.frame_to_ecef(t))
    return Track(t, S, R_FO, R_EF, np.ascontiguousarray(np.atleast_2d(traj.attitude(t)), dtype=float))


def photo_coordinates(image: LineImage, points_ecef: np.ndarray, t: np.ndarray, jacobians: bool = False,
                      telemetry: Track | None = None):
    """Photo coordinates (x, y) in mm (n, 2) of ground points at the times ``t`` of their lines.

    x = f w_x / w_z is 0 for a point on the line recorded at t; y = f w_y / w_z is its ys.
    With ``jacobians`` also d(x, y)/d(parameters) (n, 2, 10) and d(x, y)/d(point) (n, 2, 3).
    ``telemetry``: :func:`track` of the image at ``t``, when the caller keeps it.
    """
    P = np.atleast_2d(np.asarray(points_ecef, float))
    t = np.broadcast_to(np.asarray(t, float), (len(P),))
    telemetry = track(image, t) if telemetry is None else telemetry
    a = image.parameters
    tau = t - image.t_ref
    angles = telemetry.attitude + image.attitude_correction(t)
    R_BT, d_BT = _chain(np.radians(image.camera.view_pitch_deg) + a[8], a[7], a[9])
    earth_fixed = not len(telemetry.frame_to_ecef)
    return _collinearity(np.ascontiguousarray(P), telemetry.position, telemetry.frame_to_ecef,
                         telemetry.orbit_frame, np.ascontiguousarray(angles), np.ascontiguousarray(tau), R_BT,
                         np.ascontiguousarray(np.stack(d_BT)), float(a[6]), earth_fixed, jacobians)


@njit(cache=True, nogil=True, inline="always")
def _tmul(A, v, out):
    """out = A^T v (3x3, 3)."""
    x, y, z = v[0], v[1], v[2]
    out[0] = A[0, 0] * x + A[1, 0] * y + A[2, 0] * z
    out[1] = A[0, 1] * x + A[1, 1] * y + A[2, 1] * z
    out[2] = A[0, 2] * x + A[1, 2] * y + A[2, 2] * z


@njit(cache=True, nogil=True)
def _collinearity_kernel(P, S, R_EF, R_FO, angles, tau, R_BT, d_BT, f, earth_fixed, jacobians):
    """The loop of :func:`photo_coordinates` (one observation at a time, no temporaries):

    D_O = R_FO^T (R_FE P - S), D_B = R_OB^T D_O, w = R_BT^T D_B, (x, y) = f (w_x, w_y) / w_z, with
    R_OB = Ry(pitch) Rx(roll) Rz(yaw) (Eq. 4). Its derivatives: dR_OB/droll = Ry Rx Gx Rz, /dpitch =
    Ry Gy Rx Rz, /dyaw = R_OB Gz (G the generators), applied to D_O from the right as transposes."""
    n = P.shape[0]
    xy = np.empty((n, 2))
    d_par = np.zeros((n, 2, 10)) if jacobians else np.zeros((0, 2, 10))
    d_pt = np.zeros((n, 2, 3)) if jacobians else np.zeros((0, 2, 3))
    Rx, Ry, Rz = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    P_F, D_O, u, v, D_B, w, dw, e, m = (np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3),
                                        np.empty(3), np.empty(3), np.empty(3), np.empty(3))
    Rx[0, 0] = Ry[1, 1] = Rz[2, 2] = 1.0
    for o in range(n):
        if earth_fixed:
            for i in range(3):
                P_F[i] = P[o, i] - S[o, i]
        else:
            for i in range(3):      # R_FE = R_EF^T
                P_F[i] = R_EF[o, 0, i] * P[o, 0] + R_EF[o, 1, i] * P[o, 1] + R_EF[o, 2, i] * P[o, 2] - S[o, i]
        _tmul(R_FO[o], P_F, D_O)
        c, s = np.cos(angles[o, 0]), np.sin(angles[o, 0])
        Rx[1, 1], Rx[1, 2], Rx[2, 1], Rx[2, 2] = c, -s, s, c
        c, s = np.cos(angles[o, 1]), np.sin(angles[o, 1])
        Ry[0, 0], Ry[0, 2], Ry[2, 0], Ry[2, 2] = c, s, -s, c
        c, s = np.cos(angles[o, 2]), np.sin(angles[o, 2])
        Rz[0, 0], Rz[0, 1], Rz[1, 0], Rz[1, 1] = c, -s, s, c
        _tmul(Ry, D_O, u)                   # Ry^T D_O
        _tmul(Rx, u, v)                     # Rx^T Ry^T D_O
        _tmul(Rz, v, D_B)                   # D_B = R_OB^T D_O
        _tmul(R_BT, D_B, w)
        iz = 1.0 / w[2]
        xy[o, 0] = f * w[0] * iz
        xy[o, 1] = f * w[1] * iz
        if not jacobians:
            continue
        # d(x, y)/dw = [[a0, 0, a2], [0, a0, b2]]
        a0, a2, b2 = f * iz, -f * w[0] * iz * iz, -f * w[1] * iz * iz
        for k in range(3):                  # roll, pitch, yaw of R_OB: dR^T D_O
            if k == 0:                      # Rz^T Gx^T (Rx^T Ry^T D_O), Gx^T x = (0, x2, -x1)
                e[0], e[1], e[2] = 0.0, v[2], -v[1]
                _tmul(Rz, e, m)
            elif k == 1:                    # Rz^T Rx^T Gy^T (Ry^T D_O), Gy^T x = (-x2, 0, x0)
                e[0], e[1], e[2] = -u[2], 0.0, u[0]
                _tmul(Rx, e, dw)
                _tmul(Rz, dw, m)
            else:                           # Gz^T D_B, Gz^T x = (x1, -x0, 0)
                m[0], m[1], m[2] = D_B[1], -D_B[0], 0.0
            _tmul(R_BT, m, dw)
            gx = a0 * dw[0] + a2 * dw[2]
            gy = a0 * dw[1] + b2 * dw[2]
            d_par[o, 0, 2 * k], d_par[o, 1, 2 * k] = gx, gy
            d_par[o, 0, 2 * k + 1], d_par[o, 1, 2 * k + 1] = gx * tau[o], gy * tau[o]
        d_par[o, 0, 6], d_par[o, 1, 6] = w[0] * iz, w[1] * iz
        for k in range(3):                  # boresight roll, pitch, yaw
            _tmul(d_BT[k], D_B, dw)
            d_par[o, 0, 7 + k] = a0 * dw[0] + a2 * dw[2]
            d_par[o, 1, 7 + k] = a0 * dw[1] + b2 * dw[2]
        # dw/dP = R_BT^T R_OB^T R_FO^T R_FE, column by column
        for j in range(3):
            if earth_fixed:
                e[0] = e[1] = e[2] = 0.0
                e[j] = 1.0
            else:
                for i in range(3):
                    e[i] = R_EF[o, j, i]
            _tmul(R_FO[o], e, m)
            _tmul(Ry, m, dw)
            _tmul(Rx, dw, m)
            _tmul(Rz, m, dw)
            _tmul(R_BT, dw, m)
            d_pt[o, 0, j] = a0 * m[0] + a2 * m[2]
            d_pt[o, 1, j] = a0 * m[1] + b2 * m[2]
    return xy, d_par, d_pt


def _collinearity(P, S, R_EF, R_FO, angles, tau, R_BT, d_BT, f, earth_fixed, jacobians):
    xy, d_par, d_pt = _collinearity_kernel(P, S, R_EF, np.ascontiguousarray(R_FO), angles, tau,
                                           np.ascontiguousarray(R_BT, dtype=float), d_BT, f, earth_fixed, jacobians)
    return (xy, d_par, d_pt) if jacobians else xy


def image_scales(image: LineImage, points_ecef: np.ndarray, row: ArrayLike, col: ArrayLike) -> np.ndarray:
    """(n, 2): the image motion per line along track dx/drow (central differences over one line) and
    the detector spacing dy/dcol across track, in mm, at image points of ground points."""
    P = np.atleast_2d(np.asarray(points_ecef, float))
    t = image.time_of_row(np.atleast_1d(np.asarray(row, float)))
    col = np.atleast_1d(np.asarray(col, float))
    across = image.detector_mm(col + 0.5)[:, 1] - image.detector_mm(col - 0.5)[:, 1]
    return np.stack([_along_per_line_mm(image, P, t), across], -1)


def _along_per_line_mm(image: LineImage, P: np.ndarray, t: np.ndarray) -> np.ndarray:
    """dx/drow (mm per line) of ground points at times t: central differences over one line period."""
    period = image.camera.line_period_s
    return (photo_coordinates(image, P, t + period)[:, 0] - photo_coordinates(image, P, t - period)[:, 0]) / 2


def image_residuals(image: LineImage, points_ecef: np.ndarray, row: ArrayLike, col: ArrayLike, jacobians: bool = False,
                    scales: np.ndarray | None = None, detector_offset_mm: np.ndarray | None = None):
    """Residuals (n, 2) of image points in image units, observed minus computed row and column, to
    first order: the along-track misfit x - x_d over the image motion per line, the across-track
    misfit y_d - y over the detector spacing (:func:`image_scales`; pass them to reuse them: they
    hardly change with the calibration parameters). With square pixels and a straight line both
    scales are the pixel size; a sensor whose lines are longer or shorter on the ground than its
    detectors (usgscsm's LRO NAC ISD: 19 m per line, 1 m per detector) needs them. With ``jacobians``
    also d(row, col)/d(parameters) (n, 2, 10) and d(row, col)/d(point) (n, 2, 3) of the computed
    image point. ``detector_offset_mm`` (n, 2) displaces the detectors (additional parameters of the line)."""
    P = np.atleast_2d(np.asarray(points_ecef, float))
    row, col = np.atleast_1d(np.asarray(row, float)), np.atleast_1d(np.asarray(col, float))
    scales = image_scales(image, P, row, col) if scales is None else scales
    out = photo_coordinates(image, P, image.time_of_row(row), jacobians=jacobians)
    xy = out[0] if jacobians else out
    detector = image.detector_mm(col)
    if detector_offset_mm is not None:
        detector = detector + detector_offset_mm
    res = np.stack([(xy[:, 0] - detector[:, 0]) / scales[:, 0], (detector[:, 1] - xy[:, 1]) / scales[:, 1]], -1)
    if not jacobians:
        return res
    _, d_par, d_pt = out
    factor = np.stack([-1.0 / scales[:, 0], 1.0 / scales[:, 1]], -1)[:, :, None]
    return res, d_par * factor, d_pt * factor


def ground_to_image(image: LineImage, points_ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) of ground points: Newton's method on x(t) = x of the detector, with dx/dt by central differences
    over one line period. Points that do not converge (far outside the strip) are NaN."""
    P = np.atleast_2d(np.asarray(points_ecef, float))
    period = image.camera.line_period_s
    t = np.full(len(P), image.t_ref)
    active = np.ones(len(P), bool)
    for _ in range(_MAX_NEWTON):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        tt = t[idx]
        xy = photo_coordinates(image, P[idx], tt)
        target = image.detector_mm(image.col_of_y(xy[:, 1]))[:, 0]      # the along-track offset of its chip
        step = (xy[:, 0] - target) / _along_per_line_mm(image, P[idx], tt) * period
        t[idx] = tt - step
        active[idx] = np.abs(step) > TIME_TOLERANCE_LINES * period
    y = photo_coordinates(image, P, t)[:, 1]
    row, col = image.row_of_time(t), image.col_of_y(y)
    row[active] = np.nan
    col[active] = np.nan
    return row, col


def line_of_sight(image: LineImage, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Perspective centre (n, 3) and unit line-of-sight direction (n, 3), ECEF, of image points."""
    row, col = np.broadcast_arrays(np.atleast_1d(np.asarray(row, float)), np.atleast_1d(np.asarray(col, float)))
    t = image.time_of_row(row)
    S, R_FE, R_FO, R_OB, _, R_BT, _ = _frames(image, t)
    detector = image.detector_mm(col)
    u = np.stack([detector[:, 0], detector[:, 1], np.full_like(t, image.parameters[6])], -1)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    d_F = (R_FO @ (R_OB @ (R_BT @ u[:, :, None])))[:, :, 0]
    R_EF = np.swapaxes(R_FE, 1, 2)
    return (R_EF @ S[:, :, None])[:, :, 0], (R_EF @ d_F[:, :, None])[:, :, 0]


def image_to_ground(image: LineImage, row: ArrayLike, col: ArrayLike,
                    height: ArrayLike | Callable[[np.ndarray, np.ndarray], np.ndarray], tolerance_m: float = 1e-4,
                    max_iterations: int = 30) -> np.ndarray:
    """Mono restitution: the ECEF point (n, 3) where the line of sight of (row, col) meets a height.

    ``height`` is an ellipsoidal height in metres (scalar or per point) or a callable
    ``height(lat_deg, lon_deg) -> m`` (a DEM). Newton's method along the ray on
    h(S + s d) - height = 0; it stops when the height misfit is below ``tolerance_m``.
    """
    S, d = line_of_sight(image, row, col)
    dem = height if callable(height) else None
    target = None if dem else np.broadcast_to(np.asarray(height, float), (len(S),))
    # start: the range to a sphere of the mean Earth radius
    radius = 6371000.0 + (0.0 if target is None else float(np.mean(target)))
    b = np.einsum("ni,ni->n", S, d)
    c = np.einsum("ni,ni->n", S, S) - radius ** 2
    s = -b - np.sqrt(np.maximum(b * b - c, 0.0))
    for _ in range(max_iterations):
        X = S + s[:, None] * d
        lat, lon, h = geodetic_from_ecef(X)
        goal = dem(np.degrees(lat), np.degrees(lon)) if dem else target
        misfit = h - goal
        if np.all(np.abs(misfit) < tolerance_m):
            break
        up = local_up(lat, lon)
        s -= misfit / np.einsum("ni,ni->n", d, up)           # dh/ds = d . up (the DEM slope is left out)
    return S + s[:, None] * d


def intersect(images: list[LineImage], image_index: np.ndarray, rows: np.ndarray, cols: np.ndarray,
              sigma_px: float = 1.0, iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Multi-image (stereo) intersection of one ground point from its image points.

    Least squares on the photo coordinates of all its observations (Gauss-Newton from
    the closest point of the rays). Returns the ECEF point (3,) and its covariance (3, 3)
    in m², for image coordinates of standard deviation ``sigma_px``.
    """
    image_index = np.asarray(image_index)
    origin_rows, direction_rows = [], []
    for k, r, c in zip(image_index, rows, cols):
        S, d = line_of_sight(images[k], r, c)
        origin_rows.append(S[0])
        direction_rows.append(d[0])
    origins, directions = np.array(origin_rows), np.array(direction_rows)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for S, d in zip(origins, directions):
        proj = np.eye(3) - np.outer(d, d)
        A += proj
        b += proj @ S
    X = np.linalg.solve(A, b)
    scales: list[np.ndarray] = []
    for _ in range(iterations):
        N = np.zeros((3, 3))
        g = np.zeros(3)
        if not scales:
            scales = [image_scales(images[k], X[None], r, c) for k, r, c in zip(image_index, rows, cols)]
        for k, r, c, sc in zip(image_index, rows, cols, scales):
            res, _, dP = image_residuals(images[k], X[None], r, c, True, sc)
            N += dP[0].T @ dP[0]
            g += dP[0].T @ res[0]
        dX = np.linalg.solve(N, g)
        X = X + dX
        if np.max(np.abs(dX)) < 1e-6:
            break
    return X, sigma_px ** 2 * np.linalg.inv(N)


def track_frame(image: LineImage) -> tuple[np.ndarray, np.ndarray]:
    """The scene centre (ECEF, on a sphere of the mean Earth radius) and R (3, 3) whose rows are the
    across-track (X), along-track (Y) and up (Z) unit vectors there: check-point errors are reported in it."""
    row = image.rows / 2
    col = image.camera.center_col
    S, d = line_of_sight(image, [row - 1000, row + 1000], [col, col])
    b = np.einsum("ni,ni->n", S, d)
    c = np.einsum("ni,ni->n", S, S) - 6371000.0 ** 2
    ground = S + (-b - np.sqrt(b * b - c))[:, None] * d
    lat, lon, _ = geodetic_from_ecef(ground.mean(axis=0))
    up = local_up(lat, lon)
    along = ground[1] - ground[0]
    along -= (along @ up) * up
    along /= np.linalg.norm(along)
    across = np.cross(along, up)
    return ground.mean(axis=0), np.stack([across, along, up])


def ecef_of(lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike) -> np.ndarray:
    """ECEF metres of geodetic degrees and ellipsoidal metres (a shorthand for callers in degrees)."""
    return ecef_from_geodetic(np.radians(lat_deg), np.radians(lon_deg), height_m)
