"""Other tools' frame-camera models, fitted to a selfcal calibration, and the covariance carried through the fit.

A tool's model maps ideal normalised coordinates n = (X/Z, Y/Z) in the camera frame of OpenCV, OpenSfM,
Metashape and Kalibr (x right, y down, z forward) to a measured pixel position. Every projection here returns
pixels in selfcal's convention ((0, 0) at the upper-left corner of the first pixel, its centre at (0.5, 0.5));
each model's own pixel convention is applied inside it and stated in its docstring.

:func:`fit_camera_model` finds the parameters q of a model that project like a :class:`Calibration` over its
image (least squares on a grid of measured positions, as :func:`selfcal.calibration.fit_opencv`), and the
sensitivity L = dq/dtheta of the fitted parameters to selfcal's parameters theta = (c, x0, y0 in mm, AP
coefficients in px): at the solution of min |r(q, theta)|^2, L = -(J_q^T J_q)^-1 J_q^T dr/dtheta (the implicit
function theorem, Gauss-Newton form). :func:`propagate` gives Sigma_q = L Sigma_theta L^T.

:func:`initial_from_model` goes the other way: a tool's model becomes selfcal's interior orientation and the
initial values of an AP model (a least-squares fit of its distortion field).

:func:`fit_for_lens` chooses between a tool's model of a frame (rectilinear) lens and its model of a fisheye
lens (:data:`LENS_MODELS`) from the lens itself: its field of view across the diagonal, and which of the two
models reproduces it.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np
from numpy.typing import ArrayLike

from .ap import ImageFrame, create_ap, fit_displacement, frame_nodes_mm
from .sensors.frame import photo_from_pixel, pixel_from_photo
from .sensors.opencv import opencv_radial_tangential

if TYPE_CHECKING:
    from .calibration import Calibration

__all__ = ["CameraModel", "FittedModel", "InitialCalibration", "LensChoice", "MODELS", "FAMILIES", "LENS_MODELS",
           "FISHEYE_FIELD_DEG", "FRAME_MODEL_FAILS_PX", "fit_camera_model", "fit_best", "fit_for_lens",
           "field_of_view_deg", "propagate", "ideal_from_pixel", "initial_from_model", "opencv_radial_tangential"]


def _opencv(n, q, w, h):
    """OpenCV: K = [[fx, 0, cx], [0, fy, cy]], pixel centres at integers (u_selfcal = u_opencv + 0.5)."""
    d = opencv_radial_tangential(n, q[4:])
    return np.column_stack([q[0] * d[:, 0] + q[2] + 0.5, q[1] * d[:, 1] + q[3] + 0.5])


def _theta(n):
    r = np.hypot(n[:, 0], n[:, 1])
    theta = np.arctan(r)
    ratio = np.where(r > 1e-12, theta / np.where(r > 1e-12, r, 1.0), 1.0)    # theta / r -> 1 at the centre
    return r, theta, ratio


def _kalibr_equidistant(n, q, w, h):
    """Kalibr's equidistant model (OpenCV's fisheye): theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8),
    x' = theta_d / r x; u = fu x' + pu, pixel centres at integers."""
    _, theta, ratio = _theta(n)
    t2 = theta * theta
    scale = ratio * (1 + q[4] * t2 + q[5] * t2**2 + q[6] * t2**3 + q[7] * t2**4)
    return np.column_stack([q[0] * scale * n[:, 0] + q[2] + 0.5, q[1] * scale * n[:, 1] + q[3] + 0.5])


def _metashape(n, q, w, h):
    """Metashape's frame camera (user manual, Appendix "Camera models", Frame cameras):
    x' = x(1 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + P1 (r^2 + 2 x^2) + 2 P2 x y,
    y' = y(1 + K1 r^2 + ...) + P2 (r^2 + 2 y^2) + 2 P1 x y,
    u = w/2 + cx + x' f + x' B1 + y' B2, v = h/2 + cy + y' f, the centre of the first pixel at (0.5, 0.5)
    (selfcal's convention). q = (f, cx, cy, b1, b2, k1, k2, k3, k4, p1, p2)."""
    f, cx, cy, b1, b2, k1, k2, k3, k4, p1, p2 = q
    x, y = n[:, 0], n[:, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3 + k4 * r2**4
    xd = x * radial + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y
    yd = y * radial + p2 * (r2 + 2 * y * y) + 2 * p1 * x * y
    return np.column_stack([w / 2 + cx + xd * (f + b1) + yd * b2, h / 2 + cy + yd * f])


def _opensfm_scale(w, h):
    return float(max(w, h))


def _opensfm_pixel(u, v, w, h):
    """OpenSfM's normalised image coordinates (origin at the image centre, the larger side 1) to pixels:
    OpenCV pixel = max(w, h) u + (w - 1)/2 (OpenSfM docs, Geometric models, Pixel coordinates), so
    selfcal's = max(w, h) u + w/2."""
    s = _opensfm_scale(w, h)
    return np.column_stack([s * u + w / 2, s * v + h / 2])


def _opensfm_perspective(n, q, w, h):
    f, k1, k2 = q
    r2 = n[:, 0] ** 2 + n[:, 1] ** 2
    d = 1 + k1 * r2 + k2 * r2**2
    return _opensfm_pixel(f * d * n[:, 0], f * d * n[:, 1], w, h)


def _opensfm_brown(n, q, w, h):
    fx, fy, cx, cy, k1, k2, k3, p1, p2 = q
    x, y = n[:, 0], n[:, 1]
    r2 = x * x + y * y
    dr = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    dtx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    dty = 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    return _opensfm_pixel(fx * (dr * x + dtx) + cx, fy * (dr * y + dty) + cy, w, h)


def _opensfm_fisheye(n, q, w, h):
    f, k1, k2 = q
    _, theta, ratio = _theta(n)
    d = 1 + k1 * theta**2 + k2 * theta**4
    return _opensfm_pixel(f * d * ratio * n[:, 0], f * d * ratio * n[:, 1], w, h)


@dataclass(frozen=True)
class CameraModel:
    """A tool's camera model: parameter names, projection ``project(n, q, width, height) -> pixel`` (selfcal's
    convention) and how its parameters start from and scale with a camera of focal length f_px and principal
    point (col, row) in selfcal's convention."""

    tool: str
    name: str
    parameter_names: tuple[str, ...]
    projection: Callable
    start: Callable            # (f_px, (col, row), w, h) -> q0
    scale: Callable            # (f_px, w, h) -> typical size of each parameter (least_squares x_scale)

    def project(self, n: np.ndarray, q: ArrayLike, width_px: int, height_px: int) -> np.ndarray:
        return self.projection(np.atleast_2d(np.asarray(n, float)), np.asarray(q, float), width_px, height_px)


def _opencv_model(tool, name, names):
    count = len(names) - 4
    return CameraModel(tool, name, tuple(names), _opencv,
                       lambda f, pp, w, h: np.r_[f, f, pp[0] - 0.5, pp[1] - 0.5, np.zeros(count)],
                       lambda f, w, h: np.r_[f, f, 1.0, 1.0, np.full(count, 0.01)])


_OPENCV_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")

#: (tool, model) -> CameraModel
MODELS: dict[tuple[str, str], CameraModel] = {}
for _name, _count in (("opencv4", 4), ("plumb_bob", 5), ("rational", 8), ("thin_prism", 12)):
    MODELS["opencv", _name] = _opencv_model("opencv", _name, ("fx", "fy", "cx", "cy") + _OPENCV_NAMES[:_count])
MODELS["kalibr", "radtan"] = _opencv_model("kalibr", "radtan", ("fu", "fv", "pu", "pv", "k1", "k2", "r1", "r2"))
MODELS["kalibr", "equidistant"] = CameraModel(
    "kalibr", "equidistant", ("fu", "fv", "pu", "pv", "k1", "k2", "k3", "k4"), _kalibr_equidistant,
    lambda f, pp, w, h: np.r_[f, f, pp[0] - 0.5, pp[1] - 0.5, np.zeros(4)],
    lambda f, w, h: np.r_[f, f, 1.0, 1.0, np.full(4, 0.01)])
MODELS["metashape", "frame"] = CameraModel(
    "metashape", "frame", ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2"), _metashape,
    lambda f, pp, w, h: np.r_[f, pp[0] - w / 2, pp[1] - h / 2, np.zeros(8)],
    lambda f, w, h: np.r_[f, 1.0, 1.0, 1.0, 1.0, np.full(6, 0.01)])
MODELS["opensfm", "perspective"] = CameraModel(
    "opensfm", "perspective", ("focal", "k1", "k2"), _opensfm_perspective,
    lambda f, pp, w, h: np.r_[f / _opensfm_scale(w, h), 0.0, 0.0],
    lambda f, w, h: np.r_[f / _opensfm_scale(w, h), 0.01, 0.01])
MODELS["opensfm", "brown"] = CameraModel(
    "opensfm", "brown", ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "k3", "p1", "p2"), _opensfm_brown,
    lambda f, pp, w, h: np.r_[f / _opensfm_scale(w, h), f / _opensfm_scale(w, h),
                              (pp[0] - w / 2) / _opensfm_scale(w, h), (pp[1] - h / 2) / _opensfm_scale(w, h),
                              np.zeros(5)],
    lambda f, w, h: np.r_[f / _opensfm_scale(w, h), f / _opensfm_scale(w, h), 1e-3, 1e-3, np.full(5, 0.01)])
MODELS["opensfm", "fisheye"] = CameraModel(
    "opensfm", "fisheye", ("focal", "k1", "k2"), _opensfm_fisheye,
    lambda f, pp, w, h: np.r_[f / _opensfm_scale(w, h), 0.0, 0.0],
    lambda f, w, h: np.r_[f / _opensfm_scale(w, h), 0.01, 0.01])

#: each tool's models, in the order 'auto' tries them (simplest first); a model not listed is only had by name
FAMILIES = {
    "opencv": ("opencv4", "plumb_bob", "rational", "thin_prism"),
    "kalibr": ("radtan", "equidistant"),
    "metashape": ("frame",),
    "opensfm": ("perspective", "brown"),
}


@dataclass(frozen=True)
class FittedModel:
    """A tool's model fitted to a calibration: its parameter values, how far it projects from selfcal over the
    image (pixels) and the sensitivity of its parameters to the calibration's (``theta_names``)."""

    model: CameraModel
    values: np.ndarray
    misfit_rms_px: float
    misfit_max_px: float
    width_px: int
    height_px: int
    sensitivity: np.ndarray         # (n_q, n_theta): dq/dtheta
    theta_names: tuple[str, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.parameter_names

    def as_dict(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.names, self.values)}


def _theta_jacobian_normalised(calibration, measured: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dn/dtheta at measured positions: (dn_x/dtheta, dn_y/dtheta), each (points, 3 + n_ap).

    n_x = (col - Delta_col - pp_col) / f_px, n_y = (row - Delta_row - pp_row) / f_px with f_px = c / p,
    pp = (W/2 + x0/p, H/2 - y0/p) and Delta = (Bx a, -By a)."""
    c = calibration.focal_mm
    f_px = calibration.focal_px
    xy = photo_from_pixel(measured, calibration.width_px, calibration.height_px, calibration.pixel_size_mm)
    bx, by = calibration.ap.basis(xy[:, 0], xy[:, 1])
    zero = np.zeros(len(n))
    jx = np.column_stack([-n[:, 0] / c, np.full(len(n), -1.0 / c), zero, -bx / f_px])
    jy = np.column_stack([-n[:, 1] / c, zero, np.full(len(n), 1.0 / c), by / f_px])
    return jx, jy


def fit_camera_model(calibration: Calibration, model: CameraModel, nodes_x: int = 121,
                     start: np.ndarray | None = None) -> FittedModel:
    """The parameters of ``model`` that project like ``calibration`` over its image, by nonlinear least
    squares on a grid of ``nodes_x`` measured positions across (selfcal gives their ideal normalised
    coordinates), with the sensitivity dq/dtheta of the result (module docstring)."""
    from scipy.optimize import least_squares     # imported on use: the exports' --help goes without SciPy
    w, h = calibration.width_px, calibration.height_px
    x, y = frame_nodes_mm(calibration.ap.frame, nodes_x)
    measured = pixel_from_photo(np.column_stack([x, y]), w, h, calibration.pixel_size_mm)
    n = calibration.normalised_from_measured(measured)
    f = calibration.focal_px
    q0 = model.start(f, calibration.principal_point_px, w, h) if start is None else np.asarray(start, float)

    def residual(q):
        return (model.projection(n, q, w, h) - measured).ravel()

    fit = least_squares(residual, q0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        x_scale=model.scale(f, w, h))
    q = fit.x
    miss = np.hypot(*fit.fun.reshape(-1, 2).T)
    # J_q by central differences at the solution, dr/dn likewise (the projection is smooth in both)
    scale = model.scale(f, w, h)
    jq = np.empty((len(fit.fun), len(q)))
    for k in range(len(q)):
        step = 1e-6 * scale[k]
        qp, qm = q.copy(), q.copy()
        qp[k] += step
        qm[k] -= step
        jq[:, k] = (residual(qp) - residual(qm)) / (2 * step)
    step = 1e-7
    dp_dnx = (model.projection(n + [step, 0], q, w, h) - model.projection(n - [step, 0], q, w, h)) / (2 * step)
    dp_dny = (model.projection(n + [0, step], q, w, h) - model.projection(n - [0, step], q, w, h)) / (2 * step)
    jx, jy = _theta_jacobian_normalised(calibration, measured, n)
    # dr/dtheta, rows interleaved (col, row) per point like the residual vector
    dr = np.empty((2 * len(n), jx.shape[1]))
    dr[0::2] = dp_dnx[:, :1] * jx + dp_dny[:, :1] * jy
    dr[1::2] = dp_dnx[:, 1:] * jx + dp_dny[:, 1:] * jy
    sensitivity = -np.linalg.lstsq(jq, dr, rcond=None)[0]
    return FittedModel(model, q, float(np.sqrt(np.mean(miss**2))), float(miss.max()), w, h, sensitivity,
                       tuple(calibration.theta_names))


def fit_best(calibration: Calibration, tool: str, names: Sequence[str] | None = None, tolerance_px: float = 0.01,
             nodes_x: int = 121) -> FittedModel:
    """The first of a tool's models (``names``, default all of :data:`FAMILIES` [tool], simplest first) that
    reproduces ``calibration`` within ``tolerance_px`` over the image, else the one with the smallest
    largest misfit."""
    names = FAMILIES[tool] if names is None else tuple(names)
    unknown = [m for m in names if (tool, m) not in MODELS]
    if unknown or not names:
        raise ValueError(f"unknown {tool} camera model '{unknown[0] if unknown else ''}' (known: "
                         f"{', '.join(m for t, m in MODELS if t == tool)})")
    best = previous = None
    for name in names:
        model = MODELS[tool, name]
        start = None
        if previous is not None and model.parameter_names[:len(previous.names)] == previous.names:
            # a larger model of the same family starts from the smaller one's fit (OpenCV's rational, say)
            f = calibration.focal_px
            start = model.start(f, calibration.principal_point_px, calibration.width_px, calibration.height_px)
            start[:len(previous.values)] = previous.values
        fitted = previous = fit_camera_model(calibration, model, nodes_x, start)
        if fitted.misfit_max_px <= tolerance_px:
            return fitted
        if best is None or fitted.misfit_max_px < best.misfit_max_px:
            best = fitted
    assert best is not None                     # names is not empty
    return best


#: tool -> (its model of a frame (rectilinear) lens, its model of a fisheye lens), for :func:`fit_for_lens`
LENS_MODELS = {"kalibr": ("radtan", "equidistant")}
#: a lens whose field of view across the diagonal is this wide or wider (degrees) is a fisheye: a rectilinear
#: lens's image height c tan(theta) grows without bound towards 90 degrees off axis, and the frame models'
#: polynomials in r = tan(theta) fit it ever worse, while a fisheye's (about c theta) stays finite
FISHEYE_FIELD_DEG = 120.0
#: below that field, the lens is still taken for a fisheye when the frame model misses selfcal's by more than
#: this (px) somewhere in the image and the fisheye model does at least twice as well
FRAME_MODEL_FAILS_PX = 1.0


def field_of_view_deg(calibration: Calibration) -> float:
    """The field of view across the image diagonal (degrees): the angle between the rays through two opposite
    corners of the image (the wider of the two diagonals), with selfcal's distortion."""
    w, h = calibration.width_px, calibration.height_px
    n = calibration.normalised_from_measured(np.array([[0.0, 0.0], [w, h], [w, 0.0], [0.0, h]]))
    rays = np.column_stack([n, np.ones(4)])
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    cosines = [np.clip(rays[0] @ rays[1], -1.0, 1.0), np.clip(rays[2] @ rays[3], -1.0, 1.0)]
    return float(np.degrees(np.arccos(min(cosines))))


@dataclass(frozen=True)
class LensChoice:
    """The model :func:`fit_for_lens` chose and why: ``lens`` is "frame" or "fisheye", ``by`` what decided it
    ("field": the field of view; "misfit": the frame model failing where the fisheye one does not), with the
    largest misfits of the models fitted (None for a model not fitted)."""

    fitted: FittedModel
    lens: str
    by: str
    field_of_view_deg: float
    frame_misfit_max_px: float | None
    fisheye_misfit_max_px: float | None


def fit_for_lens(calibration: Calibration, tool: str, nodes_x: int = 121) -> LensChoice:
    """The tool's frame-lens model (:data:`LENS_MODELS`) fitted to ``calibration``, unless the lens is a
    fisheye: a field of view of :data:`FISHEYE_FIELD_DEG` or more across the diagonal, or the frame model
    missing selfcal's by more than :data:`FRAME_MODEL_FAILS_PX` where the fisheye model misses by at most half
    as much. The frame model is not dropped for fitting a little worse than the fisheye model: a rectilinear
    lens with some higher-order radial distortion is still a rectilinear lens (and its misfit is reported)."""
    frame_name, fisheye_name = LENS_MODELS[tool]
    field = field_of_view_deg(calibration)
    if field >= FISHEYE_FIELD_DEG:
        fisheye = fit_camera_model(calibration, MODELS[tool, fisheye_name], nodes_x)
        return LensChoice(fisheye, "fisheye", "field", field, None, fisheye.misfit_max_px)
    frame = fit_camera_model(calibration, MODELS[tool, frame_name], nodes_x)
    if frame.misfit_max_px <= FRAME_MODEL_FAILS_PX:
        return LensChoice(frame, "frame", "field", field, frame.misfit_max_px, None)
    fisheye = fit_camera_model(calibration, MODELS[tool, fisheye_name], nodes_x)
    if fisheye.misfit_max_px <= 0.5 * frame.misfit_max_px:
        return LensChoice(fisheye, "fisheye", "misfit", field, frame.misfit_max_px, fisheye.misfit_max_px)
    return LensChoice(frame, "frame", "field", field, frame.misfit_max_px, fisheye.misfit_max_px)


def propagate(fitted: FittedModel, covariance_theta: np.ndarray) -> np.ndarray:
    """Covariance of the fitted parameters, L Sigma_theta L^T (``covariance_theta`` over
    ``fitted.theta_names``, in mm for c, x0, y0 and px for the AP coefficients)."""
    L = fitted.sensitivity
    return L @ np.asarray(covariance_theta, float) @ L.T


def ideal_from_pixel(model: CameraModel, values: ArrayLike, width_px: int, height_px: int, pixel: np.ndarray,
                     iterations: int = 50) -> np.ndarray:
    """Normalised ideal coordinates whose projection by ``model`` is ``pixel`` (selfcal's convention):
    Newton's method with a numerical 2 x 2 Jacobian per point. Raises ArithmeticError where it fails."""
    q = np.asarray(values, float)
    pixel = np.atleast_2d(np.asarray(pixel, float))
    centre = model.project(np.zeros((1, 2)), q, width_px, height_px)[0]
    step = 1e-7
    ex = model.project(np.array([[step, 0.0]]), q, width_px, height_px)[0] - centre
    f = max(abs(ex[0]) / step, 1e-9)
    n = (pixel - centre) / f
    for _ in range(iterations):
        p = model.project(n, q, width_px, height_px)
        r = p - pixel
        a = (model.project(n + [step, 0], q, width_px, height_px) - p) / step
        b = (model.project(n + [0, step], q, width_px, height_px) - p) / step
        det = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
        dn = np.column_stack([(b[:, 1] * r[:, 0] - b[:, 0] * r[:, 1]) / det,
                              (a[:, 0] * r[:, 1] - a[:, 1] * r[:, 0]) / det])
        n = n - dn
        if np.max(np.abs(r)) < 1e-10:
            break
    if not np.all(np.isfinite(n)) or np.max(np.abs(model.project(n, q, width_px, height_px) - pixel)) > 1e-6:
        raise ArithmeticError(f"the {model.tool} {model.name} model cannot be inverted over the image")
    return n


@dataclass(frozen=True)
class InitialCalibration:
    """A tool's calibration as selfcal's interior orientation and AP initial values, and the largest misfit
    of the AP fit over the image (pixels)."""

    focal_mm: float
    x0_mm: float
    y0_mm: float
    ap_spec: str
    ap_names: tuple[str, ...]
    ap_values_px: tuple[float, ...]
    misfit_max_px: float


def initial_from_model(model: CameraModel, values: ArrayLike, width_px: int, height_px: int, pixel_size_mm: float,
                       ap_spec: str = "brown", nodes_x: int = 61) -> InitialCalibration:
    """The calibration ``model(values)`` as selfcal's c, x0, y0 and the coefficients of ``ap_spec``.

    The principal point is where n = 0 projects; c is the mean of the scales along x and y there (a
    difference becomes brown's affinity b1); Delta = measured - (pp + c n) on a grid over the image,
    with n from the inverse of the tool's model, is fitted by the AP model's basis (one linear solve)."""
    p = pixel_size_mm
    q = np.asarray(values, float)
    centre = model.project(np.zeros((1, 2)), q, width_px, height_px)[0]
    step = 1e-7
    ex = (model.project(np.array([[step, 0.0]]), q, width_px, height_px)[0] - centre) / step
    ey = (model.project(np.array([[0.0, step]]), q, width_px, height_px)[0] - centre) / step
    f_px = 0.5 * (ex[0] + ey[1])
    frame = ImageFrame(width_px * p, height_px * p, p)
    x, y = frame_nodes_mm(frame, nodes_x)
    measured = pixel_from_photo(np.column_stack([x, y]), width_px, height_px, p)
    n = ideal_from_pixel(model, q, width_px, height_px, measured)
    ideal = centre + f_px * n                                  # ideal pixel positions (col, row)
    d_col, d_row = (measured - ideal).T
    ap = create_ap(ap_spec, frame)
    coefficients, misfit = fit_displacement(ap, x, y, d_col, -d_row)
    return InitialCalibration(f_px * p, (centre[0] - width_px / 2) * p, (height_px / 2 - centre[1]) * p, ap.spec,
                              tuple(ap.parameter_names), tuple(float(v) for v in coefficients),
                              float(np.max(np.hypot(misfit[:, 0], misfit[:, 1]))))
