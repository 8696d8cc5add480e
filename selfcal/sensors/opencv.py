"""OpenCV's camera model as a sensor (``model = "opencv"``): a chessboard calibration in selfcal with the model
that cv::calibrateCamera and mrcal's LENSMODEL_OPENCV4/5/8/12 estimate.

The image's exterior orientation is a frame image's (X0, Y0, Z0, omega, phi, kappa; :mod:`.frame`); in its camera
axes u = M (X - X0) (x right, y up, looking along -z) the point has OpenCV's normalised coordinates
n = (x, y) = (-u_x / u_z, u_y / u_z) (x right, y down, z forward), distorted by (cv::projectPoints)

    r2 = x^2 + y^2,   R = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    x_d = x R + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2
    y_d = y R + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2

and imaged at col = fx x_d + cx + 0.5, row = fy y_d + cy + 0.5 pixels (DESIGN.md §2's pixels; OpenCV's and mrcal's
cx, cy count from the centre of the first pixel). The camera's core parameters are fx, fy, cx, cy and the sixteen
coefficients in OpenCV's order (k1, k2, p1, p2, k3, k4, k5, k6, s1..s4); ``distortion`` (block.toml) says how many
are estimated: ``opencv4`` (k1, k2, p1, p2), ``plumb_bob`` (+ k3), ``rational`` (+ k4, k5, k6: OPENCV8),
``thin_prism`` (+ s1..s4: OPENCV12); the others are held at zero. Observations are pixels; the camera takes no
additional parameters (its distortion is its own).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..block import OpenCVCamera
from ..geometry.rotation import matrix_from_opk, matrix_from_opk_with_derivatives
from .base import BoundSensor, Parameter, Sensor
from .frame import EOP_NAMES, project, project_with_jacobians_indexed

__all__ = ["OpenCVSensor", "SENSOR", "COEFFICIENT_NAMES", "DISTORTION_MODELS", "opencv_radial_tangential",
           "distortion_with_jacobians", "undistort"]

#: OpenCV's distortion coefficients in its order
COEFFICIENT_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
#: the models (calibration_models' names for them) -> how many of the coefficients they estimate
DISTORTION_MODELS = {"opencv4": 4, "plumb_bob": 5, "rational": 8, "thin_prism": 12}
CORE_NAMES = ("fx", "fy", "cx", "cy") + COEFFICIENT_NAMES


def _padded(k: ArrayLike) -> np.ndarray:
    c = np.zeros(12)
    k = np.asarray(k, float).ravel()
    c[:min(len(k), 12)] = k[:12]
    return c


def opencv_radial_tangential(n: np.ndarray, k: ArrayLike) -> np.ndarray:
    """OpenCV's distortion of normalised coordinates n (m, 2), coefficients (k1, k2, p1, p2, k3, k4, k5, k6,
    s1..s4; fewer: the rest zero) (the formula of cv::projectPoints)."""
    return distortion_with_jacobians(n, k, jacobians=False)[0]


def distortion_with_jacobians(n: np.ndarray, k: ArrayLike, jacobians: bool = True):
    """(distorted (m, 2), d distorted / d n (m, 2, 2), d distorted / d coefficients (m, 2, 12)) of normalised
    coordinates n under OpenCV's coefficients ``k`` (the Jacobians None without ``jacobians``)."""
    c = _padded(k)
    n = np.atleast_2d(np.asarray(n, float))
    x, y = n[:, 0], n[:, 1]
    r2 = x * x + y * y
    a = 1 + c[0] * r2 + c[1] * r2**2 + c[4] * r2**3
    b = 1 + c[5] * r2 + c[6] * r2**2 + c[7] * r2**3
    R = a / b
    xd = x * R + 2 * c[2] * x * y + c[3] * (r2 + 2 * x * x) + c[8] * r2 + c[9] * r2**2
    yd = y * R + c[2] * (r2 + 2 * y * y) + 2 * c[3] * x * y + c[10] * r2 + c[11] * r2**2
    distorted = np.column_stack([xd, yd])
    if not jacobians:
        return distorted, None, None
    da = c[0] + 2 * c[1] * r2 + 3 * c[4] * r2**2
    db = c[5] + 2 * c[6] * r2 + 3 * c[7] * r2**2
    dR = (da * b - a * db) / (b * b)                       # dR / d r2
    prism_x = c[8] + 2 * c[9] * r2                          # d(s1 r2 + s2 r2^2) / d r2
    prism_y = c[10] + 2 * c[11] * r2
    dn = np.empty((len(x), 2, 2))
    dn[:, 0, 0] = R + 2 * x * x * dR + 2 * c[2] * y + 6 * c[3] * x + 2 * x * prism_x
    dn[:, 0, 1] = 2 * x * y * dR + 2 * c[2] * x + 2 * c[3] * y + 2 * y * prism_x
    dn[:, 1, 0] = 2 * x * y * dR + 2 * c[2] * x + 2 * c[3] * y + 2 * x * prism_y
    dn[:, 1, 1] = R + 2 * y * y * dR + 6 * c[2] * y + 2 * c[3] * x + 2 * y * prism_y
    dk = np.zeros((len(x), 2, 12))
    radial = {0: r2 / b, 1: r2**2 / b, 4: r2**3 / b, 5: -a * r2 / b**2, 6: -a * r2**2 / b**2, 7: -a * r2**3 / b**2}
    for j, dRj in radial.items():
        dk[:, 0, j] = x * dRj
        dk[:, 1, j] = y * dRj
    dk[:, 0, 2], dk[:, 1, 2] = 2 * x * y, r2 + 2 * y * y
    dk[:, 0, 3], dk[:, 1, 3] = r2 + 2 * x * x, 2 * x * y
    dk[:, 0, 8], dk[:, 0, 9] = r2, r2**2
    dk[:, 1, 10], dk[:, 1, 11] = r2, r2**2
    return distorted, dn, dk


def undistort(distorted: np.ndarray, k: ArrayLike, iterations: int = 20) -> np.ndarray:
    """The normalised coordinates (m, 2) that ``k`` distorts to ``distorted``: Newton's method from the distorted
    ones (NaN where it does not converge to 1e-12)."""
    target = np.atleast_2d(np.asarray(distorted, float))
    n = target.copy()
    for _ in range(iterations):
        d, dn, _ = distortion_with_jacobians(n, k)
        r = d - target
        det = dn[:, 0, 0] * dn[:, 1, 1] - dn[:, 0, 1] * dn[:, 1, 0]
        n = n - np.column_stack([dn[:, 1, 1] * r[:, 0] - dn[:, 0, 1] * r[:, 1],
                                 dn[:, 0, 0] * r[:, 1] - dn[:, 1, 0] * r[:, 0]]) / det[:, None]
        if np.all(np.abs(r) < 1e-14):
            break
    miss = np.abs(distortion_with_jacobians(n, k, jacobians=False)[0] - target).max(axis=1)
    n[~(miss < 1e-12)] = np.nan
    return n


class OpenCVBound(BoundSensor):
    """OpenCV cameras' images of a problem; observations are pixels (col, row)."""

    def __init__(self, problem, block, o, pixel, sigma_px):
        self.problem = problem
        self.o = np.asarray(o)
        self.pixel = np.zeros((problem.n_image_observations, 2))
        self.pixel[self.o] = pixel
        self.sigma = np.repeat(np.asarray(sigma_px, float)[:, None], 2, axis=1)
        self.unit_iop = np.tile([1.0, 0.0, 0.0], (len(problem.camera_ids), 1))

    def observations(self):
        return self.pixel[self.o], self.sigma

    def context(self, state, jacobians: bool = True):
        core = np.array([np.asarray(c[:len(CORE_NAMES)], float) if len(c) >= len(CORE_NAMES) else
                         np.zeros(len(CORE_NAMES)) for c in state.cameras]).reshape(-1, len(CORE_NAMES))
        rotation = matrix_from_opk_with_derivatives(state.image[:, 3:]) if jacobians else \
            matrix_from_opk(state.image[:, 3:])
        return state.image, core, rotation

    def _normalised(self, context, img, cam, points, jacobians):
        image, core, rotation = context
        if jacobians:
            xy, j_e, j_p, _ = project_with_jacobians_indexed(points, image, self.unit_iop, rotation, img, cam)
            flip = np.array([1.0, -1.0])[None, :, None]
            return np.column_stack([xy[:, 0], -xy[:, 1]]), j_e * flip, j_p * flip
        M = rotation[0] if isinstance(rotation, tuple) else rotation
        xy = project(points, image[img], np.array([1.0, 0.0, 0.0]), M[img])
        return np.column_stack([xy[:, 0], -xy[:, 1]]), None, None

    def predict(self, context, o, img, cam, points, jacobians):
        _, core, _ = context
        n, jn_e, jn_p = self._normalised(context, img, cam, points, jacobians)
        f = core[cam, :2]
        pixel = np.empty((len(img), 2))
        if not jacobians:
            for k in np.unique(cam):
                sel = cam == k
                pixel[sel] = distortion_with_jacobians(n[sel], core[k, 4:], jacobians=False)[0]
            return pixel * f + core[cam, 2:4] + 0.5
        dn = np.empty((len(img), 2, 2))
        dk = np.empty((len(img), 2, 12))
        for k in np.unique(cam):
            sel = cam == k
            pixel[sel], dn[sel], dk[sel] = distortion_with_jacobians(n[sel], core[k, 4:])
        j_core = np.zeros((len(img), 2, len(CORE_NAMES)))
        j_core[:, 0, 0], j_core[:, 1, 1] = pixel[:, 0], pixel[:, 1]
        j_core[:, 0, 2], j_core[:, 1, 3] = 1.0, 1.0
        j_core[:, :, 4:] = dk * f[:, :, None]
        dpix_dn = dn * f[:, :, None]
        return (pixel * f + core[cam, 2:4] + 0.5, dpix_dn @ jn_e, dpix_dn @ jn_p, j_core)

    def rays(self, context, img, pixel):
        image, core, rotation = context
        cam = self.problem.image_camera[img]
        M = rotation[0] if isinstance(rotation, tuple) else rotation
        n = np.empty((len(img), 2))
        for k in np.unique(cam):
            sel = cam == k
            n[sel] = undistort((pixel[sel] - core[k, 2:4] - 0.5) / core[k, :2], core[k, 4:])
        v = np.column_stack([n[:, 0], -n[:, 1], -np.ones(len(img))])
        d = np.einsum("nji,nj->ni", M[img], v)
        return image[img, :3], d / np.linalg.norm(d, axis=1, keepdims=True)

    def pixels(self, context, img, points):
        cam = self.problem.image_camera[img]
        return self.predict(context, None, img, cam, points, False)

    def ground_sample_distance(self, state):
        """Mean over the observations of the distance to the camera over the focal length fx (m per pixel)."""
        problem = self.problem
        img, pt = problem.obs_image[self.o], problem.obs_point[self.o]
        distance = np.linalg.norm(state.points[pt] - state.image[img, :3], axis=1)
        fx = np.array([state.cameras[k][0] for k in problem.image_camera[img]])
        return float(np.mean(distance / fx))

    def pixel_residuals(self, o, v):
        return np.array(v, float)


class OpenCVSensor(Sensor):
    """OpenCV's pinhole camera with its radial, tangential and thin-prism distortion (module docstring)."""

    name = "opencv"
    image_parameters = tuple(Parameter(n, u, "EOP", key=n if u == "m" else None)
                             for n, u in zip(EOP_NAMES, ("m", "m", "m", "rad", "rad", "rad")))
    camera_parameters = tuple(Parameter(n, "px", "IOP", plausible=0.5 if n in ("fx", "fy") else None)
                              for n in CORE_NAMES[:4]) + tuple(Parameter(n, "", "IOP") for n in COEFFICIENT_NAMES)
    central_projection = True
    camera_type: type = OpenCVCamera
    camera_keys = {"model": ("str", True), "width_px": ("int", True), "height_px": ("int", True),
                   "fx_px": ("pos", True), "fy_px": ("pos", True), "cx_px": ("num", True), "cy_px": ("num", True),
                   "distortion": ("str", False)} | {n: ("num", False) for n in COEFFICIENT_NAMES}

    def bind(self, problem, block, o, pixel, sigma_px, options):
        return OpenCVBound(problem, block, o, pixel, sigma_px)

    def check_camera(self, values):
        model = values.get("distortion", "rational")
        if model not in DISTORTION_MODELS:
            return [("distortion", f"unknown OpenCV distortion model '{model}' (known: "
                                   f"{', '.join(DISTORTION_MODELS)})")]
        n = DISTORTION_MODELS[model]
        return [(name, f"{name} is not a coefficient of the '{model}' model ({', '.join(COEFFICIENT_NAMES[:n])})")
                for name in COEFFICIENT_NAMES[n:] if values.get(name)]

    def initial_images(self, bound, block, image_index):
        images = block.images
        position, attitude = images.position_m[image_index], images.attitude_rad[image_index]
        if not (np.isfinite(position).all() and np.isfinite(attitude).all()):
            from ..errors import AdjustmentError
            raise AdjustmentError("OpenCV camera images need their orientation in images.csv (no resection for this "
                                  "model)")
        return np.column_stack([position, attitude])

    def camera_setup(self, camera, options):
        n = DISTORTION_MODELS[camera.distortion]
        value = np.r_[camera.fx_px, camera.fy_px, camera.cx_px, camera.cy_px, _padded(camera.coefficients)]
        free = np.r_[np.ones(4 + n, bool), np.zeros(12 - n, bool)]
        return value, free, np.full(len(CORE_NAMES), np.nan)


SENSOR = OpenCVSensor()
