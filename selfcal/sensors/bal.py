"""The camera model of Bundle Adjustment in the Large (BAL; Agarwal et al. 2010).

Each image has a rotation vector r (angle-axis, radians), a translation t and
its own intrinsics f, k1, k2:

    P = R(r) X + t,   p = -P_xy / P_z,   pixel = f · (1 + k1 |p|^2 + k2 |p|^4) · p

with image coordinates centred on the image, x right and y up (the camera
looks along -z, as in photogrammetry). In a selfcal block a BAL image is a
camera of its own (``model = "bal"``) with pixel size 1, so photo coordinates
in "mm" are BAL's pixels.

Unknowns per image are [r, t] (updated additively, as BAL's reference
solvers do); the camera parameters are [f, k1, k2]. The exterior orientation
of images.csv (perspective centre, omega-phi-kappa) converts to and from
[r, t] with :func:`params_from_eop` and :func:`eop_from_params`.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..geometry.rotation import matrix_from_opk, matrix_from_rotation_vector, opk_from_matrix
from ..block import BalCamera
from .base import BoundSensor, Parameter, Sensor
from .frame import photo_from_pixel, pixel_from_photo

__all__ = ["BalSensor", "SENSOR", "CAMERA_NAMES", "IMAGE_NAMES", "project_with_jacobians_indexed", "params_from_eop", "eop_from_params",
           "rotation_vector_from_matrix", "left_jacobian"]

CAMERA_NAMES = ("f", "k1", "k2")
IMAGE_NAMES = ("r1", "r2", "r3", "t1", "t2", "t3")


def rotation_vector_from_matrix(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3)."""
    R = np.asarray(R, float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = np.sin(theta)
    small = sin < 1e-8
    out = np.where(small[..., None], 0.5 * w, w * (theta / np.where(small, 1.0, 2.0 * sin))[..., None])
    # near pi: axis from the symmetric part
    near_pi = (theta > np.pi - 1e-4)
    if np.any(near_pi):
        idx = np.argwhere(near_pi)
        for i in idx:
            Ri = R[tuple(i)]
            B = 0.5 * (Ri + np.eye(3))
            axis = np.sqrt(np.clip(np.diag(B), 0, None))
            k = int(np.argmax(axis))
            axis = B[:, k] / np.sqrt(B[k, k])
            out[tuple(i)] = axis * theta[tuple(i)]
    return out


def params_from_eop(position: np.ndarray, opk: np.ndarray) -> np.ndarray:
    """[r, t] (n, 6) of images given their perspective centres and omega-phi-kappa."""
    R = matrix_from_opk(opk)
    t = -np.einsum("nij,nj->ni", R, position)
    return np.column_stack([rotation_vector_from_matrix(R), t])


def eop_from_params(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Perspective centres and omega-phi-kappa of images given [r, t] (n, 6)."""
    R = matrix_from_rotation_vector(params[:, :3])
    return -np.einsum("nji,nj->ni", R, params[:, 3:]), opk_from_matrix(R)


def behind_camera(points: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Per observation, whether its point (n, 3) lies behind the camera [r, t] (n, 6): P_z > 0, as BAL
    cameras look along -z. BAL's formula still projects such a point (mirrored)."""
    R = matrix_from_rotation_vector(params[:, :3])
    return (np.einsum("nij,nj->ni", R, points) + params[:, 3:6])[:, 2] > 0


def left_jacobian(r: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3) at rotation vectors r (..., 3): R(r + d) ~ Exp(J_l(r) d) R(r)."""
    r = np.asarray(r, float)
    theta2 = np.sum(r * r, axis=-1)
    theta = np.sqrt(theta2)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    c = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / np.where(small, 1.0, theta2))
    d = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (safe - np.sin(safe)) / np.where(small, 1.0, theta2 * safe))
    zero = np.zeros_like(r[..., 0])
    K = np.stack([np.stack([zero, -r[..., 2], r[..., 1]], -1), np.stack([r[..., 2], zero, -r[..., 0]], -1),
                  np.stack([-r[..., 1], r[..., 0], zero], -1)], -2)
    return np.eye(3) + c[..., None, None] * K + d[..., None, None] * (K @ K)


@njit(cache=True, nogil=True)
def _project_indexed(points, params, R_img, Jl_img, cameras, img, cam, jacobians):
    n = points.shape[0]
    m = n if jacobians else 0
    xy = np.empty((n, 2))
    j_e = np.zeros((m, 2, 6))
    j_p = np.zeros((m, 2, 3))
    j_c = np.zeros((m, 2, 3))
    RX = np.empty(3)
    dP = np.empty((2, 3))
    for o in range(n):
        i = img[o]
        k = cam[o]
        f, k1, k2 = cameras[k, 0], cameras[k, 1], cameras[k, 2]
        for a in range(3):
            RX[a] = R_img[i, a, 0] * points[o, 0] + R_img[i, a, 1] * points[o, 1] + R_img[i, a, 2] * points[o, 2]
        Px = RX[0] + params[i, 3]
        Py = RX[1] + params[i, 4]
        Pz = RX[2] + params[i, 5]
        iz = 1.0 / Pz
        px = -Px * iz
        py = -Py * iz
        r2 = px * px + py * py
        d = 1.0 + k1 * r2 + k2 * r2 * r2
        xy[o, 0] = f * d * px
        xy[o, 1] = f * d * py
        if not jacobians:
            continue
        dd = 2.0 * (k1 + 2.0 * k2 * r2)
        # du/dp = f (d I + dd p p^T);  dp/dP = [[-1/Pz, 0, Px/Pz^2], [0, -1/Pz, Py/Pz^2]]
        a00 = f * (d + dd * px * px)
        a01 = f * dd * px * py
        a11 = f * (d + dd * py * py)
        dP[0, 0] = -a00 * iz
        dP[0, 1] = -a01 * iz
        dP[0, 2] = (a00 * Px + a01 * Py) * iz * iz
        dP[1, 0] = -a01 * iz
        dP[1, 1] = -a11 * iz
        dP[1, 2] = (a01 * Px + a11 * Py) * iz * iz
        for row in range(2):
            # translation: dP/dt = I
            for c in range(3):
                j_e[o, row, 3 + c] = dP[row, c]
            # point: dP/dX = R
            for q in range(3):
                s = 0.0
                for c in range(3):
                    s += dP[row, c] * R_img[i, c, q]
                j_p[o, row, q] = s
            # rotation vector: dP/dr = -[RX]x J_l;  w = dP[row] @ (-[RX]x) = (RX x dP[row])
            w0 = RX[1] * dP[row, 2] - RX[2] * dP[row, 1]
            w1 = RX[2] * dP[row, 0] - RX[0] * dP[row, 2]
            w2 = RX[0] * dP[row, 1] - RX[1] * dP[row, 0]
            for q in range(3):
                j_e[o, row, q] = w0 * Jl_img[i, 0, q] + w1 * Jl_img[i, 1, q] + w2 * Jl_img[i, 2, q]
        j_c[o, 0, 0] = d * px
        j_c[o, 1, 0] = d * py
        j_c[o, 0, 1] = f * r2 * px
        j_c[o, 1, 1] = f * r2 * py
        j_c[o, 0, 2] = f * r2 * r2 * px
        j_c[o, 1, 2] = f * r2 * r2 * py
    return xy, j_e, j_p, j_c


def project_with_jacobians_indexed(points: np.ndarray, params_images: np.ndarray, cameras: np.ndarray,
                                   image_index: np.ndarray, camera_index: np.ndarray, rotation: np.ndarray | None = None,
                                   jacobians: bool = True):
    """Image coordinates and Jacobians of observations given by image and camera index (``rotation``: the
    images' rotation matrices, if known). Without ``jacobians`` the three Jacobians are empty, (0, 2, k).

    Returns
    -------
    xy : (n, 2); j_e : (n, 2, 6) w.r.t. [r, t]; j_p : (n, 2, 3); j_c : (n, 2, 3) w.r.t. [f, k1, k2]
    """
    params_images = np.ascontiguousarray(params_images, dtype=np.float64)
    R = matrix_from_rotation_vector(params_images[:, :3]) if rotation is None else rotation
    Jl = left_jacobian(params_images[:, :3]) if jacobians else np.zeros((0, 3, 3))
    return _project_indexed(np.ascontiguousarray(points, dtype=np.float64), params_images,
                            np.ascontiguousarray(R, dtype=np.float64), np.ascontiguousarray(Jl),
                            np.ascontiguousarray(cameras, dtype=np.float64),
                            np.ascontiguousarray(image_index, dtype=np.int64),
                            np.ascontiguousarray(camera_index, dtype=np.int64), jacobians)


# --- the sensor contract (selfcal.sensors.base) --------------------------------------------------

class BalBound(BoundSensor):
    """BAL images of a problem: observations are BAL's centred pixels (x right, y up), pixel size 1."""

    def __init__(self, problem, block, o, pixel, sigma_px):
        self.problem = problem
        self.o = np.asarray(o)
        cams = [block.cameras[c] for c in problem.camera_ids]
        self.format_px = np.array([(c.width_px, c.height_px) for c in cams], float)
        w, h = self.format_px[problem.image_camera[problem.obs_image[self.o]]].T
        self.xy = np.zeros((problem.n_image_observations, 2))
        self.xy[self.o] = photo_from_pixel(pixel, w, h, 1.0)
        self.sigma = np.repeat(np.asarray(sigma_px, float)[:, None], 2, axis=1)

    def observations(self):
        return self.xy[self.o], self.sigma

    def context(self, state, jacobians: bool = True):
        core = np.array([c[:3] if len(c) >= 3 else np.zeros(3) for c in state.cameras]).reshape(-1, 3)
        return state.image, core, matrix_from_rotation_vector(state.image[:, :3])

    def predict(self, context, o, img, cam, points, jacobians):
        image, core, rotation = context
        if jacobians:
            return project_with_jacobians_indexed(points, image, core, img, cam, rotation)
        return project_with_jacobians_indexed(points, image, core, img, cam, rotation, jacobians=False)[0]

    def rays(self, context, img, pixel):
        """Rays of the distortion-free camera: P = s (x/f, y/f, -1) in the camera frame."""
        image, core, _ = context
        cam = self.problem.image_camera[img]
        f = core[cam, 0]
        R = matrix_from_rotation_vector(image[img, :3])
        w, h = self.format_px[cam].T
        d = np.column_stack([photo_from_pixel(pixel, w, h, 1.0) / f[:, None], -np.ones(len(img))])
        origin = -np.einsum("nji,nj->ni", R, image[img, 3:])
        direction = np.einsum("nji,nj->ni", R, d)
        return origin, direction / np.linalg.norm(direction, axis=1, keepdims=True)

    def pixels(self, context, img, points):
        image, core, rotation = context
        cam = self.problem.image_camera[img]
        w, h = self.format_px[cam].T
        xy = project_with_jacobians_indexed(points, image, core, img, cam, rotation, jacobians=False)[0]
        return pixel_from_photo(xy, w, h, 1.0)

    def pixel_residuals(self, o, v):
        return np.column_stack([v[:, 0], -v[:, 1]])


class BalSensor(Sensor):
    """The camera of Bundle Adjustment in the Large: each image its own camera (f, k1, k2)."""

    name = "bal"
    central_projection = True
    #: BAL problems come with their points: they are not intersected (BAL's rays need its distortion inverted)
    given_points_only = True
    image_parameters = tuple(Parameter(n, "rad" if n[0] == "r" else "m", "EOP") for n in IMAGE_NAMES)
    camera_parameters = (Parameter("f", "px", "IOP"), Parameter("k1", "", "IOP"), Parameter("k2", "", "IOP"))
    camera_type = BalCamera
    camera_keys = {
    "model": ("str", True),
    "width_px": ("int", True),
    "height_px": ("int", True),
    "focal_px": ("pos", True),
    "k1": ("num", False),
    "k2": ("num", False),
}

    def bind(self, problem, block, o, pixel, sigma_px, options):
        return BalBound(problem, block, o, pixel, sigma_px)

    def initial_images(self, bound, block, image_index):
        images = block.images
        position, attitude = images.position_m[image_index], images.attitude_rad[image_index]
        if not (np.isfinite(position).all() and np.isfinite(attitude).all()):
            from ..errors import AdjustmentError
            raise AdjustmentError("BAL images need their orientation in images.csv (no resection for this model)")
        return params_from_eop(position, attitude)

    def camera_setup(self, camera, options):
        return np.array([camera.focal_px, camera.k1, camera.k2], float), np.ones(3, bool), np.full(3, np.nan)


SENSOR = BalSensor()
