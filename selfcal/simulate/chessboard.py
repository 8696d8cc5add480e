"""A chessboard calibration with known truth: one flat board of known corners, photographed from ``n_frames``
poses by one camera of OpenCV's model (:mod:`selfcal.sensors.opencv`), as cv::calibrateCamera and mrcal take it.

The board lies in the object frame's XY plane (corners at (i s, j s, 0), row by row), each image looks at it from
0.5-1.3 ``distance_m`` above, from a position up to ``spread`` distances aside, turned by a random kappa and aimed
so that the board's centre images anywhere within 80 % of the frame's half-width and half-height of its centre
(the corners of the frame get observations, as a careful calibration takes them); a pose is kept only where every
corner images inside the frame (mrcal's "all cameras must see the full board") and at most 90 % of the radius
where the lens's (or the start camera's) image of the field folds back (:func:`fold_radius`: beyond it a point
images on the other side of the centre, and the start would be meaningless). The corners are control points with
:data:`BOARD_SIGMA_M` (a known board: held in effect, a thousandth of a pixel at 1 m); the images' orientations
start off the truth by ``start_error`` (m, deg) and the camera at ``start_camera`` (default: fx = fy 2 % off,
the principal point at the frame's centre, the distortion coefficients at 90 % of the truth's: a calibration of
a similar lens. The rational model cannot start from no distortion: at k = 0 its k4, k5, k6 undo k1, k2, k3
exactly and the normal equations are singular, which is why OpenCV and mrcal users bootstrap it from a smaller
model).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..block import Block, Dropped, Images, Observations, OpenCVCamera, Points
from ..geometry.rotation import looking_at, opk_from_matrix
from ..sensors.opencv import distortion_with_jacobians

__all__ = ["ChessboardSimulation", "simulate_chessboard", "DEFAULT_CAMERA", "BOARD_SIGMA_M", "board_corners",
           "project_opencv", "fold_radius"]

#: a-priori sigma of the board's corners (m): far below an image point's footprint (1 px ~ 1 mm at 2 m)
BOARD_SIGMA_M = 1e-6

#: the simulated lens: 3000 x 2000 px, a wide angle (fx 1700 px) with strong barrel distortion of OpenCV's rational
#: model (OPENCV8). The model's image of the field folds back at r = 1.56 (distorted radius 0.96 of fx): the
#: frame's corners (1.07) are beyond it and no pixel there is imaged. Over the radii observed (20 poses), the
#: coefficients are determined to sigma 0.02-0.28; a milder or narrower lens leaves OPENCV8's k4..k6 undoing
#: k1..k3 along a valley of sigma 10-4000 (docs/DESIGN-NOTES.md, the OpenCV sensor)
DEFAULT_CAMERA = OpenCVCamera("cam", 3000, 2000, fx_px=1700.0, fy_px=1702.0, cx_px=1510.3, cy_px=991.7,
                              distortion="rational", k1=-0.28, k2=0.09, p1=4e-4, p2=-3e-4, k3=-0.012, k4=0.12,
                              k5=-0.03, k6=0.01)


@dataclass
class ChessboardSimulation:
    block: Block
    camera: OpenCVCamera        # the true camera
    eop: np.ndarray             # (n_frames, 6) true X0, Y0, Z0, omega, phi, kappa (rad)
    corners_m: np.ndarray       # (n_corners, 3)
    pixels: np.ndarray          # (n_frames, n_corners, 2) the noise-free pixels (selfcal's convention)
    noise_px: np.ndarray        # (n_frames, n_corners, 2) the noise added


def board_corners(columns: int, rows: int, spacing_m: float) -> np.ndarray:
    """The corners (n, 3) of a board of ``columns`` x ``rows`` corners, row by row, in its plane Z = 0."""
    i, j = np.meshgrid(np.arange(columns), np.arange(rows))
    return np.column_stack([i.ravel() * spacing_m, j.ravel() * spacing_m, np.zeros(i.size)])


def _looking_at(position: np.ndarray, target: np.ndarray, kappa: float, offset: np.ndarray) -> np.ndarray:
    """M (object to image axes, the camera looking along its -z) of a camera at ``position`` that images
    ``target`` at the normalised photo coordinates ``offset`` (x right, y up), turned by ``kappa``."""
    x, y, z = looking_at(position, target, (0.0, 1.0, 0.0))
    c, s = np.cos(kappa), np.sin(kappa)
    M = np.array([c * x + s * y, -s * x + c * y, z])
    # turn the camera so that the target's direction -(0, 0, 1) becomes (offset, -1) (normalised)
    want = np.array([offset[0], offset[1], -1.0])
    want /= np.linalg.norm(want)
    axis = np.cross([0.0, 0.0, -1.0], want)
    angle = float(np.arcsin(min(float(np.linalg.norm(axis)), 1.0)))
    if angle < 1e-12:
        return M
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K      # turns (0, 0, -1) into ``want``
    return R.T @ M


def fold_radius(camera: OpenCVCamera, largest: float = 4.0) -> float:
    """The radius of normalised coordinates where the camera's radial distortion r R(r^2) stops growing (its image
    of the field folds back; ``largest`` if it does not before)."""
    r = np.linspace(0.0, largest, 4001)
    d = distortion_with_jacobians(np.column_stack([r, np.zeros_like(r)]), camera.coefficients[:8] + (0.0,) * 4,
                                  jacobians=False)[0][:, 0]
    falls = np.flatnonzero(np.diff(d) <= 0)
    return float(r[falls[0]]) if falls.size else largest


def project_opencv(camera: OpenCVCamera, M: np.ndarray, position: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (selfcal's convention) of object points in an image of rotation M at ``position``; NaN behind it."""
    u = (points - position) @ M.T
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.column_stack([-u[:, 0] / u[:, 2], u[:, 1] / u[:, 2]])
    d = distortion_with_jacobians(n, camera.coefficients, jacobians=False)[0]
    pixel = d * [camera.fx_px, camera.fy_px] + [camera.cx_px + 0.5, camera.cy_px + 0.5]
    pixel[u[:, 2] >= 0] = np.nan
    return pixel


def simulate_chessboard(seed: int = 0, camera: OpenCVCamera = DEFAULT_CAMERA, n_frames: int = 20,
                        board: tuple[int, int] = (10, 8), spacing_m: float = 0.1, distance_m: float = 1.0,
                        spread: float = 0.6, image_sigma_px: float = 0.3, noise_seed: int | None = None,
                        start_error: tuple[float, float] = (0.01, 0.5), start_camera: OpenCVCamera | None = None,
                        margin_px: float = 2.0) -> ChessboardSimulation:
    """Simulate the calibration (module docstring). ``noise_seed``: the image noise from a generator of its own
    (every ``noise_seed`` the same poses with another noise)."""
    rng = np.random.default_rng(seed)
    corners = board_corners(*board, spacing_m)
    centre = corners.mean(axis=0)
    eop: list[np.ndarray] = []
    pixels: list[np.ndarray] = []
    half = 0.8 * np.array([camera.width_px / camera.fx_px, camera.height_px / camera.fy_px]) / 2
    if start_camera is None:
        start_camera = replace(camera, fx_px=camera.fx_px * 1.02, fy_px=camera.fx_px * 1.02,
                               cx_px=camera.width_px / 2 - 0.5, cy_px=camera.height_px / 2 - 0.5,
                               **{k: 0.9 * getattr(camera, k) for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5",
                                                                        "k6", "s1", "s2", "s3", "s4")})
    # no corner beyond 90 % of the radius where the lens's (or the start's) image of the field folds back
    valid = 0.9 * min(fold_radius(camera), fold_radius(start_camera))
    while len(eop) < n_frames:
        height = distance_m * rng.uniform(0.5, 1.3)
        position = centre + [*(rng.uniform(-spread, spread, 2) * distance_m), height]
        M = _looking_at(position, centre, rng.uniform(-np.pi, np.pi), rng.uniform(-half, half))
        pix = project_opencv(camera, M, position, corners)
        u = (corners - position) @ M.T
        with np.errstate(divide="ignore", invalid="ignore"):
            radius = np.hypot(u[:, 0], u[:, 1]) / np.abs(u[:, 2])
        inside = np.isfinite(pix).all() and (pix >= margin_px).all() and (radius < valid).all() and \
            (pix[:, 0] <= camera.width_px - margin_px).all() and (pix[:, 1] <= camera.height_px - margin_px).all()
        if inside:
            eop.append(np.r_[position, opk_from_matrix(M[None])[0]])
            pixels.append(pix)
    eop_true = np.array(eop)
    clean = np.array(pixels)
    noise_rng = rng if noise_seed is None else np.random.default_rng([seed, noise_seed])
    noise = noise_rng.normal(0.0, image_sigma_px, clean.shape)
    start_rng = np.random.default_rng([seed, 7])
    start = eop_true.copy()
    start[:, :3] += start_rng.normal(0, start_error[0], (n_frames, 3))
    start[:, 3:] += np.radians(start_rng.normal(0, start_error[1], (n_frames, 3)))
    n_corners = len(corners)
    images = Images(image_id=np.array([f"F{k + 1:03d}" for k in range(n_frames)], object),
                    camera_id=np.full(n_frames, camera.camera_id, object), strip_id=np.full(n_frames, "", object),
                    time_s=np.full(n_frames, np.nan), position_m=start[:, :3], attitude_rad=start[:, 3:],
                    line=np.arange(2, n_frames + 2))
    points = Points(point_id=np.array([f"C{k + 1:03d}" for k in range(n_corners)], object),
                    role=np.full(n_corners, "gcp", object), xyz_m=corners,
                    sigma_m=np.full((n_corners, 3), BOARD_SIGMA_M),
                    line=np.arange(2, n_corners + 2))
    n_obs = n_frames * n_corners
    observations = Observations(image_index=np.repeat(np.arange(n_frames), n_corners),
                                point_index=np.tile(np.arange(n_corners), n_frames),
                                pixel=(clean + noise).reshape(-1, 2), sigma_px=np.full(n_obs, image_sigma_px),
                                line=np.arange(2, n_obs + 2))
    block = Block(name="chessboard", crs="local", cameras={camera.camera_id: start_camera}, images=images,
                  points=points, observations=observations, image_sigma_px=image_sigma_px, dropped=Dropped())
    return ChessboardSimulation(block, camera, eop_true, corners, clean, noise)
