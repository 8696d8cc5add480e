"""The Apollo Metric frame camera of a usgscsm/ALE frame ISD, as ISIS's ``ApolloMetricCamera`` computes it,
and the same image as an ordinary selfcal frame image.

The chain from a cube pixel to the body-fixed frame (ISIS ``Camera``: AlphaCube -> ``CameraDetectorMap``
-> ``CameraFocalPlaneMap`` -> ``ApolloMetricDistortionMap`` -> ``CameraGroundMap``):

1. **pixel -> detector**: selfcal's (col, row) (corner origin) is ISIS's cube (sample, line) = (col + 0.5,
   row + 0.5); the AlphaCube puts it in the scanned frame, alpha = slope (beta - 0.5) + alpha_start with
   slope = (alpha_end - alpha_start) / beta_count (4 for the Apollo cubes, 22900 -> 5725), so detector
   sample = slope col + alpha_start (no summing, first detector 1, as ISIS's default detector map).
2. **detector -> focal plane** (distorted, mm): centred on ISIS's detector origin (AlphaSamples / 2,
   AlphaLines / 2) = (11450, 11450) - half a scan pixel from the geometric centre 11450.5, ISIS's choice
   kept - then x = TRANSX · (1, s, l), y = TRANSY · (1, s, l). For Apollo x = -0.005 s, y = +0.005 l: the
   focal-plane x grows to the *left* of the image and y *down* it (the photograph is looked at through the
   film). The inverse uses ITRANSS / ITRANSL, as ISIS does.
3. **distortion** (``ApolloMetricDistortionMap::SetFocalPlane``): relative to the principal point
   (x, y) = (xd - xp, yd - yp), r² = x² + y², the undistorted point is
   u = x (1 + k1 r² + k2 r⁴ + k3 r⁶) - (j1 r² + j2 r⁴) sin t0, v = y (1 + ...) + (j1 r² + j2 r⁴) cos t0
   (radial ``OD_K``, decentering ``DECENTER`` = (j1, j2, t0 in radians)). The undistorted coordinates are
   *relative to the principal point*. Distorting is ISIS's fixed-point iteration on the same formula,
   iterated here to 1e-12 mm instead of ISIS's 1e-6 mm (ISIS stops up to 5e-5 cube pixels early).
4. **camera -> body**: ISIS's Apollo distortion map flips the focal plane's z: the look vector in the
   camera frame is (u, v, -f) (``CameraDistortionMap(parent, -1)``), and the camera's +z (the CK frame
   -915240) points away from the Moon (checked: cos = -1.0000 with the nadir for images 1-5). The camera
   frame is C = Rc · Rj: Rj = J2000 -> camera from ``instrument_pointing`` (``pointing_constant`` ·
   R(q)), and body-fixed -> camera is C · B⁻¹ with B = J2000 -> body from ``body_rotation``
   (``body_constant`` · R(q)); R(q) of a scalar-first quaternion is the active Hamilton matrix
   (:func:`~selfcal.geometry.rotation.matrix_from_quaternion`, as ``sensors.usgscsm`` documents for the line
   scanner). The sensor position is the J2000 ``instrument_position`` (km -> m; relative to the body)
   turned by B.
5. **time**: the Apollo ISDs hold one sample of each (position, pointing, body rotation), which ISIS and
   usgscsm's frame model use as they are (at any time). With several samples the position is
   Hermite-interpolated and the rotations slerped at ``center_ephemeris_time``.

usgscsm's own frame model (``UsgsAstroFrameSensorModel``) would not reproduce ISIS on these ISDs: it looks
along (x, y, +f) - away from the Moon with this CK frame -, reads the distortion from ``optical_distortion``
(``radial``, all zero here) and needs a ``detector_center`` (null here), and knows nothing of the 4x reduced
cube. So this module follows ISIS, the peer of the jigsaw results.

**As a selfcal frame image** (:func:`frame_form`): selfcal's photo coordinates (DESIGN.md §2) are
x = (col - W/2) p, y = (H/2 - row) p with the cube's size W x H and its pixel p = 0.02 mm (0.005 mm x 4);
they relate to ISIS's distorted focal plane by a rotation J (photo -> focal, here J = -I: the 180° turn
between "x left, y down" and "x right, y up") and an offset b (the focal-plane point of the photo origin;
(-0.0025, +0.0025) mm, ISIS's half-pixel detector origin): photo = Jᵀ (focal - b). With
M = diag(Jᵀ, 1) · (body -> camera), c = f and (x0, y0) = Jᵀ (pp - b), selfcal's collinearity gives
``frame.project(X) = (x0, y0) + Jᵀ (u, v)``: ISIS's undistorted focal-plane point, in selfcal's photo axes.
The camera's distortion is then Δ = observed - ideal = Jᵀ (focal_distorted - pp - (u, v)) in photo mm
(:func:`ideal_photo_from_pixel` gives the ideal point of a measured pixel).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ..geometry.earth import intersect_ellipsoid
from ..geometry.rotation import matrix_from_opk, matrix_from_opk_with_derivatives
from .base import Parameter
from .frame import FrameBound, FrameSensor
from ..geometry.rotation import matrix_from_quaternion, opk_from_matrix, slerp
from .usgscsm import hermite

if TYPE_CHECKING:
    from ..io.usgscsm_frame import FrameIsd

__all__ = ["UsgscsmCamera", "UsgscsmFrameSensor", "SENSOR", "FrameForm", "sensor_position_m", "body_from_j2000", "camera_from_j2000", "camera_from_body",
           "isis_angles_deg", "detector_from_pixel", "pixel_from_detector", "focal_plane_from_pixel",
           "pixel_from_focal_plane", "undistort", "distort", "ground_to_focal_plane", "ground_to_image",
           "look_directions", "image_to_ground", "frame_form", "photo_from_focal_plane", "focal_plane_from_photo",
           "ideal_photo_from_pixel", "isis_residuals_px", "DISTORT_TOLERANCE_MM"]

#: the distorting iteration stops when a step moves the point less than this (ISIS: 1e-6 mm)
DISTORT_TOLERANCE_MM = 1e-12
_MAX_ITERATIONS = 50


# --- position and rotations ------------------------------------------------------------------------

def _rotation_at(times, quaternions, constant, t) -> np.ndarray:
    q = quaternions[0] if len(quaternions) == 1 else slerp(times, quaternions, t)[0]
    return constant @ matrix_from_quaternion(q)


def body_from_j2000(isd: FrameIsd) -> np.ndarray:
    """B (3, 3): J2000 vectors -> body-fixed vectors at the image time."""
    return _rotation_at(isd.body_times_s, isd.body_quaternions, isd.body_constant, isd.center_time_s)


def camera_from_j2000(isd: FrameIsd) -> np.ndarray:
    """C (3, 3): J2000 vectors -> camera-frame vectors (ISIS's instrument rotation, the CK C-matrix)."""
    return _rotation_at(isd.pointing_times_s, isd.pointing_quaternions, isd.pointing_constant, isd.center_time_s)


def camera_from_body(isd: FrameIsd) -> np.ndarray:
    """R (3, 3): body-fixed vectors -> camera-frame vectors, R = C Bᵀ."""
    return camera_from_j2000(isd) @ body_from_j2000(isd).T


def sensor_position_m(isd: FrameIsd) -> np.ndarray:
    """Perspective centre (3,) in the body-fixed frame, metres."""
    if len(isd.positions_m) == 1:
        p = isd.positions_m[0]
    else:
        p = hermite(isd.position_times_s, isd.positions_m, isd.velocities_m_s, isd.center_time_s)[0][0]
    return body_from_j2000(isd) @ p


def isis_angles_deg(isd: FrameIsd) -> np.ndarray:
    """(RA, DEC, TWIST) in degrees as jigsaw reports a frame camera's pointing: the z-x-z Euler angles of
    C (J2000 -> camera), C = R3(TWIST) R1(DEC) R3(RA) with passive elementary rotations (SPICE ``m2eul``
    with axes 3, 1, 3). RA - 90° and 90° - DEC are right ascension and declination of the camera's +z."""
    C = camera_from_j2000(isd)
    dec = np.arccos(np.clip(C[2, 2], -1.0, 1.0))
    ra = np.arctan2(C[2, 0], -C[2, 1])
    twist = np.arctan2(C[0, 2], C[1, 2])
    return np.degrees([ra, dec, twist])


# --- pixel <-> detector <-> focal plane ------------------------------------------------------------

def _slopes(isd) -> tuple[float, float]:
    a = isd.alpha_cube
    return ((a.alpha_ending_sample - a.alpha_starting_sample) / a.beta_samples,
            (a.alpha_ending_line - a.alpha_starting_line) / a.beta_lines)


def detector_from_pixel(isd: FrameIsd, col: ArrayLike, row: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """ISIS detector (sample, line) of the full frame (1-based, pixel centres) of selfcal cube pixels."""
    ss, sl = _slopes(isd)
    a = isd.alpha_cube
    return (ss * np.asarray(col, float) + a.alpha_starting_sample,
            sl * np.asarray(row, float) + a.alpha_starting_line)


def pixel_from_detector(isd: FrameIsd, sample: ArrayLike, line: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`detector_from_pixel`."""
    ss, sl = _slopes(isd)
    a = isd.alpha_cube
    return ((np.asarray(sample, float) - a.alpha_starting_sample) / ss,
            (np.asarray(line, float) - a.alpha_starting_line) / sl)


def focal_plane_from_pixel(isd: FrameIsd, col: ArrayLike, row: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """ISIS's distorted focal-plane (x, y), mm, of selfcal cube pixels (TRANSX / TRANSY)."""
    s, l = detector_from_pixel(isd, col, row)
    cs, cl = s - isd.alpha_cube.alpha_samples / 2.0, l - isd.alpha_cube.alpha_lines / 2.0
    tx, ty = isd.trans_x, isd.trans_y
    return tx[0] + tx[1] * cs + tx[2] * cl, ty[0] + ty[1] * cs + ty[2] * cl


def pixel_from_focal_plane(isd: FrameIsd, x_mm: ArrayLike, y_mm: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """selfcal cube pixels (col, row) of distorted focal-plane points (ITRANSS / ITRANSL, as ISIS)."""
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    i_s, i_l = isd.itrans_s, isd.itrans_l
    cs, cl = i_s[0] + i_s[1] * x + i_s[2] * y, i_l[0] + i_l[1] * x + i_l[2] * y
    return pixel_from_detector(isd, cs + isd.alpha_cube.alpha_samples / 2.0, cl + isd.alpha_cube.alpha_lines / 2.0)


# --- distortion ---------------------------------------------------------------------------------------

def _distortion(isd, x, y):
    """The radial factor minus one and the decentering offsets at centred focal-plane points (x, y)."""
    k1, k2, k3 = isd.radial_k
    j1, j2, t0 = isd.decentering
    rr = x * x + y * y
    radial = rr * (k1 + rr * (k2 + rr * k3))
    dt = rr * (j1 + rr * j2)
    return radial, -dt * np.sin(t0), dt * np.cos(t0)


def undistort(isd: FrameIsd, x_mm: ArrayLike, y_mm: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted focal-plane (u, v), mm *relative to the principal point*, of distorted (x, y) mm
    (ISIS ``ApolloMetricDistortionMap::SetFocalPlane``)."""
    x = np.asarray(x_mm, float) - isd.principal_point_mm[0]
    y = np.asarray(y_mm, float) - isd.principal_point_mm[1]
    radial, ex, ey = _distortion(isd, x, y)
    return x * (1.0 + radial) + ex, y * (1.0 + radial) + ey


def distort(isd: FrameIsd, u_mm: ArrayLike, v_mm: ArrayLike, tolerance_mm: float = DISTORT_TOLERANCE_MM
            ) -> tuple[np.ndarray, np.ndarray]:
    """Distorted focal-plane (x, y), mm, of undistorted (u, v) relative to the principal point: the inverse
    of :func:`undistort` by ISIS's fixed-point iteration (``SetUndistortedFocalPlane``), to ``tolerance_mm``;
    NaN where it does not converge in 50 steps (ISIS fails there too)."""
    u, v = np.broadcast_arrays(np.asarray(u_mm, float), np.asarray(v_mm, float))
    x, y = u.copy(), v.copy()
    done = np.zeros(u.shape, bool)
    for _ in range(_MAX_ITERATIONS):
        radial, ex, ey = _distortion(isd, x, y)
        x_new, y_new = u - (x * radial + ex), v - (y * radial + ey)
        step = np.maximum(np.abs(x_new - x), np.abs(y_new - y))
        x, y = np.where(done, x, x_new), np.where(done, y, y_new)
        done |= step <= tolerance_mm
        if done.all():
            break
    x, y = np.where(done, x, np.nan), np.where(done, y, np.nan)
    return x + isd.principal_point_mm[0], y + isd.principal_point_mm[1]


# --- ground <-> image ------------------------------------------------------------------------------

def ground_to_focal_plane(isd: FrameIsd, points_m: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """ISIS's undistorted focal-plane (u, v), mm relative to the principal point, of body-fixed points (n, 3)
    (``CameraGroundMap::GetXY``: the look vector in the camera frame scaled to z = -f). NaN for points behind
    the camera."""
    d = np.atleast_2d(np.asarray(points_m, float)) - sensor_position_m(isd)
    look = d @ camera_from_body(isd).T
    f = isd.focal_length_mm
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = -f * look[:, 0] / look[:, 2], -f * look[:, 1] / look[:, 2]
    behind = look[:, 2] >= 0
    return np.where(behind, np.nan, u), np.where(behind, np.nan, v)


def ground_to_image(isd: FrameIsd, points_m: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """selfcal cube pixels (col, row) of body-fixed points (n, 3); NaN behind the camera."""
    u, v = ground_to_focal_plane(isd, points_m)
    return pixel_from_focal_plane(isd, *distort(isd, u, v))


def look_directions(isd: FrameIsd, col: ArrayLike, row: ArrayLike) -> np.ndarray:
    """Unit look vectors (n, 3) in the body-fixed frame of selfcal cube pixels."""
    u, v = undistort(isd, *focal_plane_from_pixel(isd, np.atleast_1d(col), np.atleast_1d(row)))
    look = np.stack([u, v, np.full_like(u, -isd.focal_length_mm)], axis=-1)
    d = look @ camera_from_body(isd)                   # Rᵀ look, row-wise
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def image_to_ground(isd: FrameIsd, col: ArrayLike, row: ArrayLike, radius_m: ArrayLike | None = None) -> np.ndarray:
    """Body-fixed points (n, 3) where the rays of selfcal cube pixels first meet a sphere of ``radius_m``
    about the body's centre (a number or one per pixel), or without it the ISD's ellipsoid (the Moon: a
    sphere of 1737.4 km). NaN where a ray misses."""
    d = look_directions(isd, col, row)
    S = np.broadcast_to(sensor_position_m(isd), d.shape)
    if radius_m is None:
        return intersect_ellipsoid(S, d, isd.semi_major_m, isd.semi_minor_m)
    r = np.broadcast_to(np.asarray(radius_m, float), (len(d),))
    out = np.empty_like(d)
    for value in np.unique(r):                          # intersect_ellipsoid takes one pair of radii
        sel = r == value
        out[sel] = intersect_ellipsoid(S[sel], d[sel], value, value)
    return out


# --- the image as a selfcal frame image ---------------------------------------------------------------

@dataclass(frozen=True)
class FrameForm:
    """A frame ISD as a selfcal frame image (module docstring): exterior orientation in the body-fixed
    frame, interior orientation and the photo axes' relation to ISIS's focal plane."""

    position_m: np.ndarray                  # X0, Y0, Z0 body-fixed
    opk_rad: np.ndarray                     # omega, phi, kappa of M = R3(kappa) R2(phi) R1(omega)
    rotation: np.ndarray                    # M (3, 3): body-fixed -> selfcal image axes
    c_mm: float
    x0_mm: float
    y0_mm: float
    width_px: int                           # of the cube
    height_px: int
    pixel_size_mm: float                    # of a cube pixel in the focal plane
    focal_from_photo: np.ndarray            # J (2, 2): ISIS focal-plane mm per photo mm (a rotation)
    focal_offset_mm: np.ndarray             # b (2,): ISIS focal-plane point of the photo origin

    @property
    def eop(self) -> np.ndarray:
        """(X0, Y0, Z0, omega, phi, kappa) as selfcal's frame functions take them."""
        return np.concatenate([self.position_m, self.opk_rad])

    @property
    def iop(self) -> np.ndarray:
        """(c, x0, y0) in mm."""
        return np.array([self.c_mm, self.x0_mm, self.y0_mm])


def frame_form(isd: FrameIsd) -> FrameForm:
    """The image as a selfcal frame image: ``frame.project(X, eop, iop)`` is ISIS's undistorted focal-plane
    point of X in selfcal's photo axes, (x0, y0) + Jᵀ (u, v). Raises ValueError when the ISD's TRANSX/
    TRANSY mirror the image (photo axes then cannot be reached by a rotation)."""
    ss, sl = _slopes(isd)
    T = np.array([[isd.trans_x[1], isd.trans_x[2]], [isd.trans_y[1], isd.trans_y[2]]]) * np.array([ss, sl])
    pixel = float(np.sqrt(abs(np.linalg.det(T))))       # focal-plane mm per cube pixel
    J = T @ np.diag([1.0 / pixel, -1.0 / pixel])        # d(focal)/d(photo): photo x = col p, y = -row p
    if np.abs(J.T @ J - np.eye(2)).max() > 1e-9 or np.linalg.det(J) < 0:
        raise ValueError(f"{isd.path}: TRANSX/TRANSY {isd.trans_x}, {isd.trans_y} are no rotation of selfcal's "
                         "photo axes (a mirrored or sheared focal plane)")
    W, H = isd.image_samples, isd.image_lines
    b = np.array(focal_plane_from_pixel(isd, W / 2.0, H / 2.0), float)
    Q = np.eye(3)
    Q[:2, :2] = J.T
    M = Q @ camera_from_body(isd)
    x0, y0 = J.T @ (np.asarray(isd.principal_point_mm, float) - b)
    return FrameForm(position_m=sensor_position_m(isd), opk_rad=opk_from_matrix(M), rotation=M,
                     c_mm=float(isd.focal_length_mm), x0_mm=float(x0), y0_mm=float(y0), width_px=W, height_px=H,
                     pixel_size_mm=pixel, focal_from_photo=J, focal_offset_mm=b)


def photo_from_focal_plane(form: FrameForm, x_mm: ArrayLike, y_mm: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """selfcal photo coordinates (mm) of ISIS focal-plane points (absolute, not relative to the principal
    point): Jᵀ (focal - b)."""
    dx = np.asarray(x_mm, float) - form.focal_offset_mm[0]
    dy = np.asarray(y_mm, float) - form.focal_offset_mm[1]
    J = form.focal_from_photo
    return J[0, 0] * dx + J[1, 0] * dy, J[0, 1] * dx + J[1, 1] * dy


def focal_plane_from_photo(form: FrameForm, x_mm: ArrayLike, y_mm: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`photo_from_focal_plane`: b + J photo."""
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    J = form.focal_from_photo
    return form.focal_offset_mm[0] + J[0, 0] * x + J[0, 1] * y, form.focal_offset_mm[1] + J[1, 0] * x + J[1, 1] * y


def ideal_photo_from_pixel(isd: FrameIsd, form: FrameForm, col: ArrayLike, row: ArrayLike
                           ) -> tuple[np.ndarray, np.ndarray]:
    """The ideal (undistorted) photo coordinates (mm) of measured cube pixels: what ``frame.project`` of the
    imaged point gives with :func:`frame_form`'s orientation. The observed photo coordinates are selfcal's
    x = (col - W/2) p, y = (H/2 - row) p; their difference is the camera's Δ (observed - ideal)."""
    u, v = undistort(isd, *focal_plane_from_pixel(isd, col, row))
    pp = np.asarray(isd.principal_point_mm, float)
    return photo_from_focal_plane(form, u + pp[0], v + pp[1])


def isis_residuals_px(isd: FrameIsd, col: ArrayLike, row: ArrayLike, points_m: ArrayLike
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(sample, line) residuals, measured - computed, of measured cube pixels against body-fixed points as
    ISIS jigsaw reports them (``ControlPoint::ComputeResiduals`` for framing cameras): both undistorted
    focal-plane points taken to the detector by ITRANSS/ITRANSL, so the unit is a *detector* pixel of the
    full scanned frame (0.005 mm for Apollo Metric, 4 cube pixels), not a cube pixel."""
    um, vm = undistort(isd, *focal_plane_from_pixel(isd, col, row))
    uc, vc = ground_to_focal_plane(isd, points_m)
    du, dv = um - uc, vm - vc
    return isd.itrans_s[1] * du + isd.itrans_s[2] * dv, isd.itrans_l[1] * du + isd.itrans_l[2] * dv


# --- the sensor contract: usgscsm frame images in a block (model = "usgscsm") ---------------------------

@dataclass(frozen=True)
class UsgscsmCamera:
    """Images whose geometry is a usgscsm / ALE image support data file each (``model = "usgscsm"``, the ISD
    named by images.csv ``sensor_file``; DESIGN.md §3a). ``kind`` ("frame" or "line") is the ISD's sensor
    model, found when the block is read; ``focal_mm``, ``x0_mm``, ``y0_mm``, ``width_px``, ``height_px`` and
    ``pixel_size_mm`` come from the first ISD (the camera's start values). A-priori sigmas per image:
    ``sigma_position_m`` (X0, Y0, Z0) and ``sigma_attitude_deg`` (omega, phi, kappa; absent: free);
    ``sigma_focal_mm``, ``sigma_x0_mm``, ``sigma_y0_mm`` as for a frame camera, but absent means held (the
    mission's calibration) and a positive value weights it; line scanners: ``attitude_degree`` (0 a bias, 1 a
    drift, up to 3: the degree of the RA, DEC, TWIST corrections), ``twist`` (false: no TWIST correction) and
    ``position_offsets`` (true: a constant J2000 offset of the ISD's trajectory, weighted by ``sigma_position_m``;
    jigsaw's spsolve=position; default false, jigsaw's spsolve=none)."""

    camera_id: str
    kind: str = ""
    sigma_position_m: float | None = None
    sigma_attitude_deg: float | None = None
    sigma_focal_mm: float | None = 0.0
    sigma_x0_mm: float | None = 0.0
    sigma_y0_mm: float | None = 0.0
    attitude_degree: int = 1
    twist: bool = True
    position_offsets: bool = False
    focal_mm: float = float("nan")
    x0_mm: float = 0.0
    y0_mm: float = 0.0
    width_px: int = 0
    height_px: int = 0
    pixel_size_mm: float = float("nan")
    initial_ap = None

    model = "usgscsm"

    @property
    def sensor(self) -> str:
        """The registered sensor of its images: the frame or the line-scan usgscsm sensor."""
        return "usgscsm-line" if self.kind == "line" else "usgscsm"

    @property
    def width_mm(self) -> float:
        return self.width_px * self.pixel_size_mm

    @property
    def height_mm(self) -> float:
        return self.height_px * self.pixel_size_mm


def _r1(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, s], -1), np.stack([z, -s, c], -1)], -2)


def _r3(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, s, z], -1), np.stack([-s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _dr1(a):
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    return np.stack([np.stack([z, z, z], -1), np.stack([z, -s, c], -1), np.stack([z, -c, -s], -1)], -2)


def _dr3(a):
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    return np.stack([np.stack([-s, c, z], -1), np.stack([-c, -s, z], -1), np.stack([z, z, z], -1)], -2)


def pointing_matrix(angles_rad: np.ndarray, derivatives: bool = False):
    """C = R3(TWIST) R1(DEC) R3(RA) (..., 3, 3) of jigsaw's camera angles (radians; passive rotations, SPICE's
    z-x-z), the inverse of :func:`isis_pointing_deg`; with ``derivatives`` also dC/d(RA, DEC, TWIST)
    (..., 3, 3, 3), the angle last."""
    a = np.asarray(angles_rad, float)
    ra, dec, tw = a[..., 0], a[..., 1], a[..., 2]
    R_ra, R_dec, R_tw = _r3(ra), _r1(dec), _r3(tw)
    C = R_tw @ R_dec @ R_ra
    if not derivatives:
        return C
    d = np.stack([R_tw @ R_dec @ _dr3(ra), R_tw @ _dr1(dec) @ R_ra, _dr3(tw) @ R_dec @ R_ra], -1)
    return C, d


class UsgscsmFrameBound(FrameBound):
    """Frame ISD images. Each image's parameters are jigsaw's: the J2000 position of the camera relative to the
    body (m) and its pointing RA, DEC, TWIST (C = R3(TWIST) R1(DEC) R3(RA), J2000 -> camera); the prediction is
    :mod:`selfcal.sensors.frame`'s collinearity of the body-fixed orientation they make (X0 = B X, M =
    diag(Jᵀ, 1) C Bᵀ with B the body rotation at the image's time and J the photo axes in ISIS's focal plane),
    its Jacobians by the chain rule. The measured pixels become ideal photo coordinates through each ISD's
    pixel -> focal-plane affine and lens distortion (:func:`ideal_photo_from_pixel`), once."""

    #: its photo coordinates come through each ISD's distortion: the AP basis stays at the measured ones
    adjusted_ap_positions = False

    def __init__(self, problem, block, o, pixel, sigma_px):
        super().__init__(problem, block, o, pixel, sigma_px)
        self.isds, self.forms = {}, {}
        n = problem.n_images
        self.body = np.tile(np.eye(3), (n, 1, 1))           # B: J2000 -> body-fixed
        self.axes = np.tile(np.eye(3), (n, 1, 1))           # diag(Jᵀ, 1): ISIS camera -> selfcal image axes
        img = problem.obs_image[self.o]
        for i in np.unique(img):
            isd = block.image_models[block.images.image_id[i]]
            form = frame_form(isd)
            self.isds[int(i)], self.forms[int(i)] = isd, form
            self.body[i] = body_from_j2000(isd)
            self.axes[i, :2, :2] = form.focal_from_photo.T
            sel = np.flatnonzero(img == i)
            self.xy_mm[self.o[sel]] = np.column_stack(ideal_photo_from_pixel(isd, form, pixel[sel, 0], pixel[sel, 1]))

    def eop(self, image: np.ndarray, derivatives: bool = False):
        """The body-fixed exterior orientation (n, 6) of jigsaw's parameters (n, 6); with ``derivatives``
        also d(X0, Y0, Z0)/d(X, Y, Z) = B (n, 3, 3) and d(omega, phi, kappa)/d(RA, DEC, TWIST) (n, 3, 3)."""
        from ..geometry.rotation import opk_from_matrix_with_derivatives
        position = np.einsum("nij,nj->ni", self.body, image[:, :3])
        C, dC = pointing_matrix(image[:, 3:], derivatives=True)
        Bt = np.swapaxes(self.body, 1, 2)
        M = self.axes @ C @ Bt
        opk, d_opk = opk_from_matrix_with_derivatives(M)
        eop = np.column_stack([position, opk])
        if not derivatives:
            return eop
        dM = np.einsum("nij,njkc,nkl->nilc", self.axes, dC, Bt)            # (n, 3, 3, angle)
        return eop, self.body, np.einsum("nkij,nijc->nkc", d_opk, dM)

    def context(self, state, jacobians: bool = True):
        iop = np.array([c[:3] if len(c) >= 3 else np.zeros(3) for c in state.cameras]).reshape(-1, 3)
        rotation: np.ndarray | tuple[np.ndarray, np.ndarray]     # M, or (M, dM) with the Jacobians
        if jacobians:
            eop, d_position, d_angles = self.eop(state.image, derivatives=True)
            rotation = matrix_from_opk_with_derivatives(eop[:, 3:])
        else:
            eop, d_position, d_angles = self.eop(state.image), None, None
            rotation = matrix_from_opk(eop[:, 3:])
        return eop, iop, rotation, state.cameras, d_position, d_angles

    def predict(self, context, o, img, cam, points, jacobians):
        eop, iop, rotation, _, d_position, d_angles = context
        out = super().predict((eop, iop, rotation, None), o, img, cam, points, jacobians)
        if not jacobians:
            return out
        f, j_e, j_p, j_c = out
        j_e = np.concatenate([j_e[:, :, :3] @ d_position[img], j_e[:, :, 3:] @ d_angles[img]], axis=2)
        return f, j_e, j_p, j_c

    def _ideal(self, img, pixel):
        out = np.zeros((len(img), 2))
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            out[sel] = np.column_stack(ideal_photo_from_pixel(self.isds[int(i)], self.forms[int(i)],
                                                              pixel[sel, 0], pixel[sel, 1]))
        return out

    def rays(self, context, img, pixel):
        from .frame import rays
        eop, iop = context[0], context[1]
        cam = self.problem.image_camera[img]
        return eop[img, :3], rays(self._ideal(img, pixel), eop[img], iop[cam])

    def pixels(self, context, img, points):
        """Ideal photo coordinates (with the camera's APs), through the lens distortion to cube pixels."""
        xy = self.photo_coordinates(context, img, points)
        out = np.zeros((len(img), 2))
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            isd, form = self.isds[int(i)], self.forms[int(i)]
            pp = np.asarray(isd.principal_point_mm, float)
            fx, fy = focal_plane_from_photo(form, xy[sel, 0], xy[sel, 1])        # undistorted, absolute
            out[sel] = np.column_stack(pixel_from_focal_plane(isd, *distort(isd, fx - pp[0], fy - pp[1])))
        return out

    def ground_sample_distance(self, state):
        """Mean over the observations of the range times the pixel size over the principal distance."""
        img, pt = self.problem.obs_image[self.o], self.problem.obs_point[self.o]
        position = self.eop(state.image)[:, :3]
        distance = np.linalg.norm(state.points[pt] - position[img], axis=1)
        c = np.array([state.cameras[k][0] for k in self.problem.image_camera[img]])
        return float(np.mean(distance * self.pixel_size_mm[self.o] / c))


class UsgscsmFrameSensor(FrameSensor):
    """usgscsm / ALE frame ISDs (the Apollo Metric camera as ISIS computes it): a frame camera in the body-fixed
    frame whose measurements are corrected for the mission's lens model once; the exterior orientation starts
    at the ISD's and may be weighted (``sigma_position_m``, ``sigma_attitude_deg``), the interior orientation
    is held unless weighted, and the frame APs self-calibrate what remains."""

    name = "usgscsm"
    image_parameters = (Parameter("X", "m", "EOP"), Parameter("Y", "m", "EOP"), Parameter("Z", "m", "EOP"),
                        Parameter("RA", "rad", "EOP"), Parameter("DEC", "rad", "EOP"), Parameter("TWIST", "rad", "EOP"))
    object_frame = "ECEF"
    camera_type = UsgscsmCamera
    camera_keys = {"model": ("str", True), "sigma_position_m": ("pos", False), "sigma_attitude_deg": ("pos", False),
                   "sigma_focal_mm": ("nonneg", False), "sigma_x0_mm": ("nonneg", False),
                   "sigma_y0_mm": ("nonneg", False), "attitude_degree": ("count", False), "twist": ("bool", False),
                   "position_offsets": ("bool", False)}
    camera_tables = ()
    supports_resection = False
    min_points_per_image = 1

    def bind(self, problem, block, o, pixel, sigma_px, options):
        return UsgscsmFrameBound(problem, block, o, pixel, sigma_px)

    def configure_camera(self, camera, image_models):
        """The kind of its ISDs (all frame or all line scanner) and its start values from the first."""
        from dataclasses import replace
        if not image_models:
            return camera
        kinds = {"frame" if hasattr(m, "trans_x") else "line" for m in image_models}
        if len(kinds) > 1:
            raise ValueError("a usgscsm camera's ISDs are all frame or all line-scan sensor models")
        first = image_models[0]
        if kinds == {"line"}:
            return replace(camera, kind="line", focal_mm=float(first.focal_length_mm), width_px=first.image_samples,
                           height_px=first.image_lines)
        form = frame_form(first)
        return replace(camera, kind="frame", focal_mm=form.c_mm, x0_mm=form.x0_mm, y0_mm=form.y0_mm,
                       width_px=form.width_px, height_px=form.height_px, pixel_size_mm=form.pixel_size_mm)

    def result_files(self, result, slot):
        """isis_images.csv and isis_points.csv: the adjustment in the quantities of jigsaw's bundleout files."""
        return {"isis_images.csv": isis_image_table(result, slot), "isis_points.csv": isis_point_table(result)}

    def check_camera(self, values):
        degree = values.get("attitude_degree", 1)
        return [] if 0 <= degree <= 3 else [("attitude_degree", f"attitude_degree must be 0..3, found {degree}")]

    def initial_images(self, bound, block, image_index):
        """The ISD's J2000 position (relative to the body) and jigsaw's RA, DEC, TWIST of its pointing."""
        out = []
        for i in image_index:
            isd = block.image_models[block.images.image_id[i]]
            position = isd.positions_m[0] if len(isd.positions_m) == 1 else \
                body_from_j2000(isd).T @ sensor_position_m(isd)
            out.append(np.concatenate([position, np.radians(isis_angles_deg(isd))]))
        return np.array(out).reshape(-1, 6)

    def image_setup(self, block, image_index, options):
        free = np.ones((len(image_index), 6), bool)
        sigma = np.full((len(image_index), 6), np.nan)
        for row, i in enumerate(image_index):
            camera = block.cameras[block.images.camera_id[i]]
            if camera.sigma_position_m is not None:
                sigma[row, :3] = camera.sigma_position_m
            if camera.sigma_attitude_deg is not None:
                sigma[row, 3:] = np.radians(camera.sigma_attitude_deg)
        return free, sigma


SENSOR = UsgscsmFrameSensor()


# --- the adjustment as ISIS jigsaw reports it (isis_images.csv, isis_points.csv) ---------------------------

def isis_pointing_deg(rotation: np.ndarray) -> np.ndarray:
    """(RA, DEC, TWIST) in degrees of J2000 -> camera rotations C (..., 3, 3), as :func:`isis_angles_deg`."""
    C = np.asarray(rotation, float)
    dec = np.arccos(np.clip(C[..., 2, 2], -1.0, 1.0))
    ra = np.arctan2(C[..., 2, 0], -C[..., 2, 1])
    twist = np.arctan2(C[..., 0, 2], C[..., 1, 2])
    return np.degrees(np.stack([ra, dec, twist], -1))


def isis_image_table(result, slot) -> tuple:
    """Per image, jigsaw's bundleout_images quantities: J2000 position (km) and RA/DEC/TWIST (deg) with their
    correction from the ISD and a-posteriori sigma (the image's own parameters), and the residual RMS of its
    measures in detector pixels (sample, line, both; jigsaw's unit: the full scanned frame's pixel)."""
    problem, state, bound = result.problem, result.state, slot.bound
    sigma = result.image_sigma()
    v = result.residuals_px                                    # cube px, photo axes (x: sample, y: -line)
    img_of_obs = result.block.observations.image_index
    cols: dict[str, list] = {
        k: [] for k in ("image_id", "X_km", "dX_km", "sigma_X_km", "Y_km", "dY_km", "sigma_Y_km", "Z_km", "dZ_km",
                        "sigma_Z_km", "RA_deg", "dRA_deg", "sigma_RA_deg", "DEC_deg", "dDEC_deg", "sigma_DEC_deg",
                        "TWIST_deg", "dTWIST_deg", "sigma_TWIST_deg", "rms_sample_px", "rms_line_px", "rms_px",
                        "n_measures")}
    for i in slot.images:
        isd, form = bound.isds[int(i)], bound.forms[int(i)]
        scale = np.array([1e-3] * 3 + [np.degrees(1.0)] * 3)
        final = state.image[i] * scale
        correction = (state.image[i] - problem.image_prior_value[i]) * scale
        correction[3:] = (correction[3:] + 180.0) % 360.0 - 180.0
        s = sigma[i] * scale
        detector = form.pixel_size_mm / isd.pixel_pitch_mm        # detector pixels per cube pixel
        mine = (img_of_obs == i) & np.isfinite(v).all(axis=1)
        r = v[mine] * detector
        values = [result.block.images.image_id[i]]
        for k in range(6):
            values += [final[k], correction[k], s[k]]
        values += [float(np.sqrt(np.mean(r[:, 0] ** 2))), float(np.sqrt(np.mean(r[:, 1] ** 2))),
                   float(np.sqrt(np.mean(r ** 2))), int(mine.sum())]
        for key, value in zip(cols, values):
            cols[key].append(value)
    header = list(cols)
    columns = [np.array(cols[h], dtype=object if h == "image_id" else int if h == "n_measures" else float)
               for h in header]
    return header, columns, [""] + [".9g"] * (len(header) - 2) + ["d"]


def isis_point_table(result) -> tuple:
    """Per point, jigsaw's bundleout_points quantities: planetocentric latitude, longitude (deg), radius (km) and
    the a-posteriori sigmas of latitude, longitude and radius in metres (north, east, radial)."""
    from ..geometry.body import latlon_radius_from_xyz, sigmas_from_covariance
    pts = result.block.points
    xyz = result.state.points
    lat, lon, radius = latlon_radius_from_xyz(xyz)
    sigma = sigmas_from_covariance(xyz, result.point_covariance())
    return (["point_id", "role", "lat_deg", "lon_deg", "radius_km", "sigma_lat_m", "sigma_lon_m", "sigma_radius_m"],
            [pts.point_id.astype(object), pts.role.astype(object), np.degrees(lat), np.degrees(lon) % 360.0,
             radius / 1000.0, sigma[:, 0], sigma[:, 1], sigma[:, 2]], ["", "", ".9f", ".9f", ".9f", ".6f", ".6f", ".6f"])
