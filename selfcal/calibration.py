"""An estimated frame-camera calibration, and what other programs need from it.

selfcal's model (DESIGN.md §2) gives the distortion as a function of the
*measured* position: ideal = measured - Delta(measured). OpenCV and COLMAP
give it as a function of the *ideal* position: measured = D(ideal). This module
holds the calibration of one camera (:class:`Calibration`) and converts:

* :meth:`Calibration.measured_from_ideal` inverts selfcal's model by Newton's
  method on the AP basis derivatives;
* :func:`fit_opencv` finds the OpenCV camera (camera matrix and distortion
  coefficients of a chosen model) that projects like selfcal, by least squares
  over the image, and reports the misfit in pixels;
* :func:`undistortion_maps` builds the per-pixel source positions that
  ``cv2.remap`` needs to turn a measured image into an ideal (distortion-free)
  one: exact on a grid of nodes, bicubic between them.

Pixel conventions, the source of many exporter bugs: selfcal and COLMAP put
(0, 0) at the upper-left corner of the first pixel (its centre at (0.5, 0.5));
OpenCV puts the centre of the first pixel at (0, 0). Hence
``u_opencv = col - 0.5``, and COLMAP's principal point is OpenCV's + 0.5.
Camera frames: OpenCV's looks along +z with y down; selfcal's along -z with y
up, so (X, Y, Z)_opencv = (X, -Y, -Z)_selfcal.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .ap import APModel, ImageFrame, ap_from_dict
from .sensors.frame import photo_from_pixel

__all__ = ["Calibration", "OpenCVCamera", "OPENCV_MODELS", "fit_opencv", "undistortion_maps", "undistort_image",
           "opencv_project", "colmap_parameters"]

#: OpenCV distortion models by name: number of coefficients, in OpenCV's order
#: (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4); opencv4 is COLMAP's OPENCV model,
#: rational its FULL_OPENCV
OPENCV_MODELS = {"opencv4": 4, "plumb_bob": 5, "rational": 8, "thin_prism": 12}
#: a camera's parameters in camera.json that are not its calibration (a rolling shutter's readout, ms)
NOT_CALIBRATION = ("readout",)

#: Newton's method for the inverse stops when the step is below this (pixels)
INVERSE_TOLERANCE_PX = 1e-9
#: points per chunk of the inverse (bounds the memory of the basis matrices)
CHUNK_POINTS = 8192


@dataclass(frozen=True)
class Calibration:
    """Interior orientation and additional parameters of one frame camera (camera.json of a results folder)."""

    camera_id: str
    width_px: int
    height_px: int
    pixel_size_mm: float
    focal_mm: float
    x0_mm: float
    y0_mm: float
    ap: APModel
    coefficients_px: np.ndarray          # inactive (screened-out) coefficients are zero
    #: covariance of :attr:`theta_names` (c, x0, y0 in mm, AP coefficients in px; zero rows and columns for
    #: held ones), from camera.json's ``covariance``; None when the results folder has none
    covariance: np.ndarray | None = None
    #: the warning that the correction is extrapolated beyond the observations (camera.json ``extrapolation``,
    #: :mod:`selfcal.stats.extrapolation`), or ""
    extrapolation_warning: str = ""

    @property
    def theta_names(self) -> tuple[str, ...]:
        """selfcal's parameters of the camera: c, x0, y0 (mm) and the AP coefficients (px)."""
        return ("c", "x0", "y0") + tuple(self.ap.parameter_names)

    @classmethod
    def from_camera_json(cls, camera_id: str, entry: dict) -> "Calibration":
        p = float(entry["pixel_size_mm"])
        frame = ImageFrame(entry["width_px"] * p, entry["height_px"] * p, p)
        ap = ap_from_dict(entry["ap"], frame)
        # held coefficients (an imported calibration held with --fixed) keep their value, screened ones are zero
        values = np.array([c["value_px"] if c["active"] or c.get("held") else 0.0
                           for c in entry["ap"]["coefficients"]], float)
        if len(values) != ap.n_params:
            raise ValueError(f"camera {camera_id}: {len(values)} AP coefficients for {ap.spec}, which has "
                             f"{ap.n_params}")
        written = [c.get("name") for c in entry["ap"]["coefficients"]]
        wrong = next((k for k, name in enumerate(written) if name is not None and name != ap.parameter_names[k]), None)
        if wrong is not None:
            raise ValueError(f"camera {camera_id}: AP coefficient {wrong + 1} is '{written[wrong]}', but {ap.spec} "
                             f"rebuilt from the file has '{ap.parameter_names[wrong]}' there")
        names = ("c", "x0", "y0") + tuple(ap.parameter_names)
        covariance = None
        if entry.get("covariance"):
            given = entry["covariance"]
            index = {name: k for k, name in enumerate(names)}
            unknown = [name for name in given["parameters"] if name not in index and name not in NOT_CALIBRATION]
            if unknown:
                raise ValueError(f"camera {camera_id}: covariance of an unknown parameter '{unknown[0]}'")
            # (a rolling shutter's readout is not the lens's: its rows and columns are left out, its marginal)
            kept = [k for k, name in enumerate(given["parameters"]) if name in index]
            at = np.array([index[given["parameters"][k]] for k in kept], dtype=np.int64)
            n = len(given["parameters"])
            matrix = np.asarray(given["matrix"], float).reshape(n, n)[np.ix_(kept, kept)]
            covariance = np.zeros((len(names), len(names)))
            covariance[np.ix_(at, at)] = matrix
        return cls(camera_id, int(entry["width_px"]), int(entry["height_px"]), p, float(entry["focal_mm"]["value"]),
                   float(entry["x0_mm"]["value"]), float(entry["y0_mm"]["value"]), ap, values, covariance,
                   str((entry.get("extrapolation") or {}).get("warning") or ""))

    @property
    def focal_px(self) -> float:
        return self.focal_mm / self.pixel_size_mm

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """(col, row) of the principal point in selfcal's (= COLMAP's) pixel convention."""
        return (self.width_px / 2 + self.x0_mm / self.pixel_size_mm,
                self.height_px / 2 - self.y0_mm / self.pixel_size_mm)

    def delta_px(self, pixel: np.ndarray) -> np.ndarray:
        """Delta along the pixel axes (dcol, drow) at measured positions (col, row), shape (n, 2)."""
        xy = self._photo(np.atleast_2d(np.asarray(pixel, float)))
        dx, dy = self.ap.displacement_px(xy[:, 0], xy[:, 1], self.coefficients_px)
        return np.column_stack([dx, -dy])

    def _photo(self, pixel: np.ndarray) -> np.ndarray:
        return photo_from_pixel(pixel, self.width_px, self.height_px, self.pixel_size_mm)

    def ideal_from_measured(self, pixel: np.ndarray) -> np.ndarray:
        """Ideal (distortion-free) pixel positions of measured ones: measured - Delta(measured)."""
        pixel = np.atleast_2d(np.asarray(pixel, float))
        return pixel - self.delta_px(pixel)

    def measured_from_ideal(self, ideal: np.ndarray, max_iterations: int = 30) -> np.ndarray:
        """Where an ideal position is measured: solves m - Delta(m) = ideal by Newton's method.

        Raises
        ------
        ArithmeticError
            If some positions do not converge (a distortion so strong that the
            mapping folds over, far outside the image).
        """
        ideal = np.atleast_2d(np.asarray(ideal, float))
        if self.ap.n_params == 0 or not np.any(self.coefficients_px):
            return ideal.copy()
        # in chunks: the basis matrices are (points x coefficients), hundreds of columns for WAPs
        return np.concatenate([self._newton(ideal[k:k + CHUNK_POINTS], max_iterations)
                               for k in range(0, len(ideal), CHUNK_POINTS)])

    def _newton(self, ideal: np.ndarray, max_iterations: int) -> np.ndarray:
        m = ideal.copy()
        p = self.pixel_size_mm
        todo = np.ones(len(m), bool)
        a = self.coefficients_px
        for _ in range(max_iterations):
            x, y = self._photo(m[todo]).T
            bx, by = self.ap.basis(x, y)
            dbx_dx, dbx_dy, dby_dx, dby_dy = self.ap.basis_derivatives(x, y)
            # residual of m - Delta(m) - ideal along the pixel axes (drow = -dy) and its Jacobian per pixel
            r = m[todo] - np.column_stack([bx @ a, -(by @ a)]) - ideal[todo]
            j11 = 1.0 - p * (dbx_dx @ a)              # d(col - dx)/dcol, x grows with col
            j12 = p * (dbx_dy @ a)                    # d(col - dx)/drow, y falls with row
            j21 = p * (dby_dx @ a)                    # d(row + dy)/dcol
            j22 = 1.0 - p * (dby_dy @ a)              # d(row + dy)/drow
            det = j11 * j22 - j12 * j21
            step = np.column_stack([(j22 * r[:, 0] - j12 * r[:, 1]) / det, (j11 * r[:, 1] - j21 * r[:, 0]) / det])
            m[todo] -= step
            done = np.max(np.abs(step), axis=1) < INVERSE_TOLERANCE_PX
            todo[np.flatnonzero(todo)[done]] = False
            if not todo.any():
                return m
        raise ArithmeticError(f"{int(todo.sum())} position(s) of camera {self.camera_id} did not converge in the "
                              f"inverse of the distortion (e.g. ideal {ideal[todo][0]})")

    def opencv_intrinsics(self) -> np.ndarray:
        """The ideal camera as an OpenCV camera matrix (pixel centres at integers)."""
        col, row = self.principal_point_px
        f = self.focal_px
        return np.array([[f, 0.0, col - 0.5], [0.0, f, row - 0.5], [0.0, 0.0, 1.0]])

    def normalised_from_measured(self, pixel: np.ndarray) -> np.ndarray:
        """Normalised ideal coordinates (X/Z, Y/Z in OpenCV's camera frame) of measured positions."""
        ideal = self.ideal_from_measured(pixel)
        col, row = self.principal_point_px
        return np.column_stack([(ideal[:, 0] - col) / self.focal_px, (ideal[:, 1] - row) / self.focal_px])


@dataclass(frozen=True)
class OpenCVCamera:
    """An OpenCV camera: camera matrix, distortion coefficients (OpenCV's order) and how well they
    reproduce the calibration they were fitted to (misfit over the image, pixels)."""

    model: str
    camera_matrix: np.ndarray
    distortion: np.ndarray
    misfit_rms_px: float
    misfit_max_px: float
    width_px: int
    height_px: int


#: COLMAP camera model of each OpenCV distortion model COLMAP has
COLMAP_MODELS = {"opencv4": "OPENCV", "rational": "FULL_OPENCV"}


def colmap_parameters(camera: OpenCVCamera) -> tuple[str, list[float]]:
    """COLMAP's model name and parameters of an OpenCV camera (principal point + 0.5: COLMAP puts the
    centre of the first pixel at (0.5, 0.5))."""
    if camera.model not in COLMAP_MODELS:
        raise ValueError(f"COLMAP has no camera model for OpenCV's '{camera.model}' (it has: "
                         f"{', '.join(COLMAP_MODELS)})")
    K = camera.camera_matrix
    params = [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5]
    return COLMAP_MODELS[camera.model], [float(v) for v in params + list(camera.distortion)]


def opencv_distort(normalised: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """OpenCV's distortion of normalised coordinates (the formula of cv::projectPoints)."""
    from .calibration_models import opencv_radial_tangential
    return opencv_radial_tangential(normalised, np.asarray(coefficients, float))


def opencv_project(normalised: np.ndarray, camera_matrix: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """OpenCV pixel positions (centres at integers) of normalised ideal coordinates."""
    d = opencv_distort(normalised, coefficients)
    K = camera_matrix
    return np.column_stack([K[0, 0] * d[:, 0] + K[0, 2], K[1, 1] * d[:, 1] + K[1, 2]])


def fit_opencv(calibration: Calibration, models: Sequence[str] = tuple(OPENCV_MODELS), tolerance_px: float = 0.01,
               nodes_x: int = 121) -> OpenCVCamera:
    """The OpenCV camera that projects like ``calibration`` over its image.

    On a grid of measured positions, selfcal gives the ideal normalised
    coordinates n; the camera matrix (fx, fy, cx, cy) and the distortion
    coefficients are fitted so that OpenCV projects n to the measured
    position (nonlinear least squares, :func:`selfcal.calibration_models.fit_best`).
    ``models`` are tried in order (each starting from the previous fit): the
    first whose largest misfit is within ``tolerance_px`` is returned, else the
    one with the smallest misfit.

    selfcal's Delta cannot always be written in OpenCV's form: its terms are
    centred on the frame, not the principal point, the shear b2 has no OpenCV
    counterpart, and the inverse of radial plus tangential distortion has cross
    terms. The misfit says how much is lost; undistortion maps lose nothing.
    """
    from .calibration_models import fit_best
    unknown = [m for m in models if m not in OPENCV_MODELS]
    if unknown or not models:
        raise ValueError(f"unknown OpenCV distortion model '{unknown[0] if unknown else ''}' "
                         f"(known: {', '.join(OPENCV_MODELS)})")
    fitted = fit_best(calibration, "opencv", sorted(models, key=OPENCV_MODELS.__getitem__), tolerance_px, nodes_x)
    q = fitted.values
    return OpenCVCamera(fitted.model.name, np.array([[q[0], 0, q[2]], [0, q[1], q[3]], [0, 0, 1]]), q[4:].copy(),
                        fitted.misfit_rms_px, fitted.misfit_max_px, calibration.width_px, calibration.height_px)


def undistortion_maps(calibration: Calibration, step_px: int = 4,
                      progress: Callable[[str, float], None] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maps for ``cv2.remap`` from a measured image to the ideal one, and the ideal camera matrix.

    The ideal image has the size of the measured one, the principal distance as
    fx = fy and the principal point of the calibration (no resampling of scale).
    For every ideal pixel centre (u, v) (OpenCV convention) the maps hold the
    measured position that shows it: exact (Newton) on nodes every ``step_px``
    pixels, bicubic splines between them. Between nodes 4 px apart the maps
    follow a db4 WAP field (whose scaling function is only about 1.6 times
    differentiable) within 0.01 px; polynomial fields far better. ``progress``
    receives the stage (``"nodes inverted"``, then ``"map rows interpolated"``)
    and its share done so far (0-1) after each of about a hundred bands of rows.

    Returns
    -------
    map_x, map_y : float32 (height, width)
    camera_matrix : (3, 3) of the ideal image (OpenCV convention)
    """
    from scipy.interpolate import RectBivariateSpline     # 0.4 s to import: the exports' --help goes without
    w, h = calibration.width_px, calibration.height_px
    u_nodes = np.unique(np.concatenate([np.arange(0, w, step_px), [w - 1]])).astype(float)
    v_nodes = np.unique(np.concatenate([np.arange(0, h, step_px), [h - 1]])).astype(float)
    U, V = np.meshgrid(u_nodes, v_nodes)
    ideal = np.column_stack([U.ravel(), V.ravel()]) + 0.5      # selfcal's convention
    bands = np.array_split(np.arange(len(v_nodes)), min(100, len(v_nodes)))
    measured = np.empty_like(ideal)
    for k, rows in enumerate(bands):          # node rows in bands: the inversion says how far it is
        at = slice(rows[0] * len(u_nodes), (rows[-1] + 1) * len(u_nodes))
        measured[at] = calibration.measured_from_ideal(ideal[at]) - 0.5
        if progress is not None:
            progress("nodes inverted", (k + 1) / len(bands))
    mx = RectBivariateSpline(v_nodes, u_nodes, measured[:, 0].reshape(U.shape), kx=3, ky=3)
    my = RectBivariateSpline(v_nodes, u_nodes, measured[:, 1].reshape(U.shape), kx=3, ky=3)
    u_all = np.arange(w, dtype=float)
    map_x = np.empty((h, w), np.float32)
    map_y = np.empty((h, w), np.float32)
    pixel_bands = np.array_split(np.arange(h), min(100, h))
    for k, rows in enumerate(pixel_bands):    # and so does the interpolation between the nodes
        v_rows = rows.astype(float)
        map_x[rows] = mx(v_rows, u_all)
        map_y[rows] = my(v_rows, u_all)
        if progress is not None:
            progress("map rows interpolated", (k + 1) / len(pixel_bands))
    return map_x, map_y, calibration.opencv_intrinsics()


def undistort_image(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """The ideal image: ``cv2.remap`` with the maps of :func:`undistortion_maps`, bicubic, black outside
    (OpenCV rounds source positions to 1/32 px)."""
    import cv2

    return cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT)
