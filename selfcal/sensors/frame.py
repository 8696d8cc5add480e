"""Frame camera: collinearity, Eq. (1) of seed 000, with analytic Jacobians.

    x = x0 - c · (m1 · (X - X0)) / (m3 · (X - X0)) + Delta_x
    y = y0 - c · (m2 · (X - X0)) / (m3 · (X - X0)) + Delta_y

with M = R3(kappa) R2(phi) R1(omega) (rows m1, m2, m3; see
:mod:`selfcal.geometry.rotation`), photo coordinates (x, y) in millimetres
(DESIGN.md §2: x = (col - W/2)·p, y = (H/2 - row)·p), principal distance c and
principal point (x0, y0) in millimetres, object coordinates in metres. The
additional parameters Delta are linear and added by the adjustment engine
(:mod:`selfcal.ap`); this module handles the projective part.

Exterior orientation rows are (X0, Y0, Z0, omega, phi, kappa); interior
orientation rows are (c, x0, y0).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from numba import njit

from ..geometry.rotation import matrix_from_opk, matrix_from_opk_with_derivatives
from ..block import FrameCamera
from .base import BoundSensor, Parameter, Sensor

__all__ = [
    "EOP_NAMES",
    "IOP_NAMES",
    "photo_from_pixel",
    "pixel_from_photo",
    "project",
    "project_with_jacobians",
    "project_with_jacobians_indexed",
    "rays",
    "FrameSensor",
    "FrameBound",
    "SENSOR",
]

EOP_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
IOP_NAMES = ("c", "x0", "y0")


def photo_from_pixel(pixel: np.ndarray, width_px: float | np.ndarray, height_px: float | np.ndarray,
                     pixel_size_mm: float | np.ndarray) -> np.ndarray:
    """Photo coordinates (mm, y up, origin at the image centre) of pixel positions (col, row)."""
    pixel = np.asarray(pixel, float)
    x = (pixel[..., 0] - np.asarray(width_px) / 2.0) * pixel_size_mm
    y = (np.asarray(height_px) / 2.0 - pixel[..., 1]) * pixel_size_mm
    return np.stack([x, y], axis=-1)


def pixel_from_photo(xy_mm: np.ndarray, width_px: float | np.ndarray, height_px: float | np.ndarray,
                     pixel_size_mm: float | np.ndarray) -> np.ndarray:
    """Inverse of :func:`photo_from_pixel`."""
    xy_mm = np.asarray(xy_mm, float)
    col = xy_mm[..., 0] / pixel_size_mm + np.asarray(width_px) / 2.0
    row = np.asarray(height_px) / 2.0 - xy_mm[..., 1] / pixel_size_mm
    return np.stack([col, row], axis=-1)


def project(points_m: np.ndarray, eop: np.ndarray, iop: np.ndarray, rotation: np.ndarray | None = None
            ) -> np.ndarray:
    """Ideal photo coordinates (mm, no additional parameters).

    Parameters
    ----------
    points_m : (n, 3) object points
    eop : (n, 6) exterior orientation per point (X0, Y0, Z0, omega, phi, kappa)
    iop : (n, 3) or (3,) interior orientation (c, x0, y0)
    rotation : (n, 3, 3), optional
        Precomputed M of ``eop[:, 3:]``.
    """
    iop = np.broadcast_to(np.asarray(iop, float), (len(points_m), 3))
    m = matrix_from_opk(eop[:, 3:]) if rotation is None else rotation
    u = np.einsum("nij,nj->ni", m, np.asarray(points_m, float) - eop[:, :3])
    c, x0, y0 = iop[:, 0], iop[:, 1], iop[:, 2]
    return np.stack([x0 - c * u[:, 0] / u[:, 2], y0 - c * u[:, 1] / u[:, 2]], axis=-1)


def project_with_jacobians(points_m: np.ndarray, eop: np.ndarray, iop: np.ndarray,
                           rotation: tuple[np.ndarray, np.ndarray] | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ideal photo coordinates and their partial derivatives.

    Parameters
    ----------
    points_m : (n, 3)
    eop : (n, 6)
    iop : (n, 3)
    rotation : tuple (M, dM), optional
        Precomputed :func:`~selfcal.geometry.rotation.matrix_from_opk_with_derivatives`
        of ``eop[:, 3:]`` (saves work when many points share an image).

    Returns
    -------
    xy : (n, 2) photo coordinates in mm
    j_eop : (n, 2, 6) derivatives with respect to X0, Y0, Z0, omega, phi, kappa
    j_point : (n, 2, 3) derivatives with respect to X, Y, Z
    j_iop : (n, 2, 3) derivatives with respect to c, x0, y0
    """
    m, dm = rotation if rotation is not None else matrix_from_opk_with_derivatives(eop[:, 3:])
    d = np.asarray(points_m, float) - eop[:, :3]
    u = np.einsum("nij,nj->ni", m, d)
    c = iop[:, 0]
    inv_w = 1.0 / u[:, 2]
    qx, qy = u[:, 0] * inv_w, u[:, 1] * inv_w
    xy = np.stack([iop[:, 1] - c * qx, iop[:, 2] - c * qy], axis=-1)

    # d(x, y)/du, shape (n, 2, 3)
    a = c * inv_w
    zero = np.zeros_like(a)
    dxy_du = np.stack([np.stack([-a, zero, a * qx], -1), np.stack([zero, -a, a * qy], -1)], axis=1)
    j_point = dxy_du @ m
    du_dangle = np.einsum("nkij,nj->nik", dm, d)  # (n, 3, 3): column k is dM_k · d
    j_eop = np.concatenate([-j_point, dxy_du @ du_dangle], axis=2)
    one = np.ones_like(a)
    j_iop = np.stack([np.stack([-qx, one, zero], -1), np.stack([-qy, zero, one], -1)], axis=1)
    return xy, j_eop, j_point, j_iop


@njit(cache=True, nogil=True)
def _project_indexed(points, eop, iop, m_img, dm_img, img, cam, shift):
    n = points.shape[0]
    moved = shift.shape[0] > 0
    xy = np.empty((n, 2))
    j_e = np.empty((n, 2, 6))
    j_p = np.empty((n, 2, 3))
    j_i = np.zeros((n, 2, 3))
    d = np.empty(3)
    u = np.empty(3)
    for o in range(n):
        i = img[o]
        k = cam[o]
        c = iop[k, 0]
        for a in range(3):
            d[a] = points[o, a] - eop[i, a]
        if moved:
            for a in range(3):
                d[a] -= shift[o, a]
        for a in range(3):
            u[a] = m_img[i, a, 0] * d[0] + m_img[i, a, 1] * d[1] + m_img[i, a, 2] * d[2]
        inv_w = 1.0 / u[2]
        qx = u[0] * inv_w
        qy = u[1] * inv_w
        xy[o, 0] = iop[k, 1] - c * qx
        xy[o, 1] = iop[k, 2] - c * qy
        f = c * inv_w
        # d(x, y)/du = [[-f, 0, f qx], [0, -f, f qy]]
        for b in range(3):
            jx = -f * m_img[i, 0, b] + f * qx * m_img[i, 2, b]
            jy = -f * m_img[i, 1, b] + f * qy * m_img[i, 2, b]
            j_p[o, 0, b] = jx
            j_p[o, 1, b] = jy
            j_e[o, 0, b] = -jx
            j_e[o, 1, b] = -jy
        for t in range(3):
            du0 = dm_img[i, t, 0, 0] * d[0] + dm_img[i, t, 0, 1] * d[1] + dm_img[i, t, 0, 2] * d[2]
            du1 = dm_img[i, t, 1, 0] * d[0] + dm_img[i, t, 1, 1] * d[1] + dm_img[i, t, 1, 2] * d[2]
            du2 = dm_img[i, t, 2, 0] * d[0] + dm_img[i, t, 2, 1] * d[1] + dm_img[i, t, 2, 2] * d[2]
            j_e[o, 0, 3 + t] = -f * du0 + f * qx * du2
            j_e[o, 1, 3 + t] = -f * du1 + f * qy * du2
        j_i[o, 0, 0] = -qx
        j_i[o, 1, 0] = -qy
        j_i[o, 0, 1] = 1.0
        j_i[o, 1, 2] = 1.0
    return xy, j_e, j_p, j_i


_NO_SHIFT = np.zeros((0, 3))


def project_with_jacobians_indexed(points_m: np.ndarray, eop_images: np.ndarray, iop_cameras: np.ndarray,
                                   rotation: tuple[np.ndarray, np.ndarray], image_index: np.ndarray,
                                   camera_index: np.ndarray, shift_m: np.ndarray | None = None
                                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`project_with_jacobians` for observations given by image and camera index.

    Parameters
    ----------
    points_m : (n, 3) object point of each observation
    eop_images : (n_images, 6) exterior orientation of every image
    iop_cameras : (n_cameras, 3) interior orientation of every camera
    rotation : (M, dM) of every image, from ``matrix_from_opk_with_derivatives(eop_images[:, 3:])``
    image_index, camera_index : (n,) the observation's image and camera
    shift_m : (n, 3), optional
        Each observation's projection centre moved by this from its image's (a rolling shutter's line,
        :mod:`selfcal.sensors.rolling`); the derivatives with respect to X0, Y0, Z0 are those of the moved centre.

    Same results as :func:`project_with_jacobians` (a compiled loop; the tests compare both).
    """
    m_img, dm_img = rotation
    shift = _NO_SHIFT if shift_m is None else np.ascontiguousarray(shift_m, dtype=np.float64)
    return _project_indexed(np.ascontiguousarray(points_m, dtype=np.float64),
                            np.ascontiguousarray(eop_images, dtype=np.float64),
                            np.ascontiguousarray(iop_cameras, dtype=np.float64),
                            np.ascontiguousarray(m_img), np.ascontiguousarray(dm_img),
                            np.ascontiguousarray(image_index, dtype=np.int64),
                            np.ascontiguousarray(camera_index, dtype=np.int64), shift)


def rays(xy_mm: np.ndarray, eop: np.ndarray, iop: np.ndarray, m: np.ndarray | None = None) -> np.ndarray:
    """Unit object-space directions of the rays through photo points (mm), shape (n, 3); ``m``: each point's
    rotation matrix if known (else from ``eop``'s angles)."""
    iop = np.broadcast_to(np.asarray(iop, float), (len(xy_mm), 3))
    m = matrix_from_opk(eop[:, 3:]) if m is None else m
    v = np.stack([xy_mm[:, 0] - iop[:, 1], xy_mm[:, 1] - iop[:, 2], -iop[:, 0]], axis=-1)
    d = np.einsum("nji,nj->ni", m, v)
    return d / np.linalg.norm(d, axis=1, keepdims=True)



# --- the sensor contract (selfcal.sensors.base) --------------------------------------------------

class FrameBound(BoundSensor):
    """Frame images of a problem. Observations are photo coordinates in mm (DESIGN.md §2) measured
    in the image; the prediction is Eq. (1) without the additional parameters, whose Delta is a
    linear basis at the measured coordinates (:mod:`selfcal.ap`), or at the adjusted ones of an earlier
    adjustment where the block's observations carry them (``Observations.ap_at_px``: the basis at the
    measured, noisy coordinates correlates with their noise, an errors-in-variables bias; the engine's
    :func:`~selfcal.adjust.engine.adjust` moves it to the adjusted coordinates, DESIGN-NOTES "Honest
    precision")."""

    #: whether the AP basis may be evaluated at adjusted image coordinates (``Observations.ap_at_px``); a
    #: subclass whose photo coordinates are not :func:`photo_from_pixel` of the pixels sets False
    adjusted_ap_positions = True

    def __init__(self, problem, block, o, pixel, sigma_px):
        self.problem = problem
        self.o = np.asarray(o)
        cams = [block.cameras[c] for c in problem.camera_ids]
        self.format_px = np.array([(c.width_px, c.height_px, c.pixel_size_mm) for c in cams], float)
        cam_of_obs = problem.image_camera[problem.obs_image[self.o]]
        w, h, p = self.format_px[cam_of_obs].T
        self.xy_mm = np.zeros((problem.n_image_observations, 2))
        self.xy_mm[self.o] = photo_from_pixel(pixel, w, h, p)
        # where the AP basis is evaluated: the measured coordinates (the same array), or the adjusted ones
        self.ap_xy_mm = self.xy_mm
        at = block.observations.ap_at_px
        if at is not None and self.adjusted_ap_positions:
            self.ap_xy_mm = np.zeros((problem.n_image_observations, 2))
            self.ap_xy_mm[self.o] = photo_from_pixel(at[problem.obs_order[self.o]], w, h, p)
        self.pixel_size_mm = np.full(problem.n_image_observations, np.nan)
        self.pixel_size_mm[self.o] = p
        self.sigma_mm = np.repeat((np.asarray(sigma_px, float) * p)[:, None], 2, axis=1)

    def observations(self):
        return self.xy_mm[self.o], self.sigma_mm

    def context(self, state, jacobians: bool = True):
        iop = np.array([c[:3] if len(c) >= 3 else np.zeros(3) for c in state.cameras]).reshape(-1, 3)
        rotation = matrix_from_opk_with_derivatives(state.image[:, 3:]) if jacobians else \
            matrix_from_opk(state.image[:, 3:])
        return state.image, iop, rotation, state.cameras

    def predict(self, context, o, img, cam, points, jacobians):
        image, iop, rotation, _ = context
        if jacobians:
            return project_with_jacobians_indexed(points, image, iop, rotation, img, cam)
        return project(points, image[img], iop[cam], rotation[img])

    def ap_columns(self, camera, o, ap, out=None):
        bx, by = ap.basis(self.ap_xy_mm[o, 0], self.ap_xy_mm[o, 1])
        out = np.empty((len(o), 2, bx.shape[1])) if out is None else out
        pixel = self.pixel_size_mm[o][:, None]
        np.multiply(bx, pixel, out=out[:, 0])
        np.multiply(by, pixel, out=out[:, 1])
        return out

    def sparse_ap_columns(self, camera, o, ap):
        sparse = ap.sparse_basis(self.ap_xy_mm[o, 0], self.ap_xy_mm[o, 1])
        if sparse is None:
            return None
        return replace(sparse, values=sparse.values * self.pixel_size_mm[o][:, None, None])

    def rays(self, context, img, pixel):
        image, iop, rotation, _ = context
        M = rotation[0] if isinstance(rotation, tuple) else rotation    # per image: not once per observation
        cam = self.problem.image_camera[img]
        w, h, p = self.format_px[cam].T
        return image[img, :3], rays(photo_from_pixel(pixel, w, h, p), image[img], iop[cam], M[img])

    def photo_coordinates(self, context, img, points) -> np.ndarray:
        """Eq. (1) with the additional parameters (mm), Delta evaluated at the predicted position (at the
        measured one, where the adjustment takes it, it differs by a second-order term)."""
        image, iop, rotation, values = context[:4]
        cam = self.problem.image_camera[img]
        M = rotation[0] if isinstance(rotation, tuple) else rotation
        return self.with_additional_parameters(project(points, image[img], iop[cam], M[img]), cam, values)

    def with_additional_parameters(self, xy: np.ndarray, cam: np.ndarray, values: list) -> np.ndarray:
        """Ideal photo coordinates ``xy`` (mm) of observations of cameras ``cam`` with the cameras' AP displacement
        added (the parameters ``values`` of every camera), in place."""
        for k, camera in enumerate(self.problem.cameras):
            sel = np.flatnonzero(cam == k)
            a = values[k][camera.n_core:] * camera.free[camera.n_core:]
            if sel.size and a.any():                    # (a start from zero APs: no basis to evaluate)
                dx, dy = camera.ap.displacement_px(xy[sel, 0], xy[sel, 1], a)
                xy[sel, 0] += camera.pixel_size_mm * dx
                xy[sel, 1] += camera.pixel_size_mm * dy
        return xy

    def pixels(self, context, img, points):
        """:meth:`photo_coordinates` in pixels."""
        xy = self.photo_coordinates(context, img, points)
        cam = self.problem.image_camera[img]
        w, h, p = self.format_px[cam].T
        return pixel_from_photo(xy, w, h, p)

    def ground_sample_distance(self, state):
        """Mean over images of pixel size x (Z0 - mean height of the image's points) / c."""
        problem = self.problem
        img, pt = problem.obs_image[self.o], problem.obs_point[self.o]
        images = np.unique(img)
        heights = np.bincount(img, weights=state.points[pt, 2], minlength=problem.n_images)[images]
        heights /= np.bincount(img, minlength=problem.n_images)[images]
        cam = problem.image_camera[images]
        c = np.array([state.cameras[k][0] for k in cam])
        p = self.format_px[cam, 2]
        return float(np.mean(np.abs(p * (state.image[images, 2] - heights) / c)))

    def pixel_residuals(self, o, v):
        p = self.pixel_size_mm[o]
        return np.column_stack([v[:, 0] / p, -v[:, 1] / p])


class FrameSensor(Sensor):
    """A frame camera (seed 000): collinearity, Eq. (1); interior orientation c, x0, y0 (mm) and the
    additional parameters of :mod:`selfcal.ap` per camera; exterior orientation per image."""

    name = "frame"
    image_parameters = tuple(Parameter(n, u, "EOP", key=n if u == "m" else None)
                             for n, u in zip(EOP_NAMES, ("m", "m", "m", "rad", "rad", "rad")))
    # a real camera's principal distance is known to half of itself (the focal length on the lens; a start 30 % off is
    # recovered by a block that determines it, a collapse takes it to a few per cent of itself)
    camera_parameters = tuple(Parameter(n, "mm", "IOP", key="focal_mm" if n == "c" else None,
                                        plausible=0.5 if n == "c" else None) for n in IOP_NAMES)
    ap_domain = "frame"
    supports_resection = True
    central_projection = True
    camera_type: type = FrameCamera
    camera_tables: tuple[str, ...] = ("initial_ap",)
    camera_keys = {
    "model": ("str", True),
    "width_px": ("int", True),
    "height_px": ("int", True),
    "pixel_size_mm": ("pos", True),
    "focal_mm": ("pos", True),
    "x0_mm": ("num", False),
    "y0_mm": ("num", False),
    "sigma_focal_mm": ("nonneg", False),
    "sigma_x0_mm": ("nonneg", False),
    "sigma_y0_mm": ("nonneg", False),
    "shutter": ("str", False),
    "readout_ms": ("nonneg", False),
    "sigma_readout_ms": ("nonneg", False),
    "readout_direction": ("str", False),
    "readout_rotation": ("bool", False),
}

    def bind(self, problem, block, o, pixel, sigma_px, options):
        return FrameBound(problem, block, o, pixel, sigma_px)

    def check_camera(self, values):
        """``shutter`` global or rolling; the readout keys only with a rolling shutter (:mod:`.rolling`)."""
        from .rolling import READOUT_DIRECTIONS
        shutter = values.get("shutter", "global")
        if shutter not in ("global", "rolling"):
            return [("shutter", f"shutter must be \"global\" or \"rolling\", found {shutter!r}")]
        if shutter != "rolling":
            given = [k for k in ("readout_ms", "sigma_readout_ms", "readout_direction", "readout_rotation")
                     if k in values]
            if given:
                return [(given[0], f"{given[0]} is a rolling shutter's: give shutter = \"rolling\" with it")]
        direction = values.get("readout_direction", "down")
        if direction not in READOUT_DIRECTIONS:
            return [("readout_direction", f"readout_direction must be one of {', '.join(READOUT_DIRECTIONS)} "
                                          f"(the direction the sensor's lines are read in the image), "
                                          f"found {direction!r}")]
        return []

    def initial_images(self, bound, block, image_index):
        images = block.images
        return np.column_stack([images.position_m[image_index], images.attitude_rad[image_index]])

    def create_ap(self, spec, camera, observed, settings, model=None):
        """The AP model of a frame camera (``model`` when given) and its initial coefficients (block.toml
        ``initial_ap``, fitted to the model when another: :func:`initial_coefficients`)."""
        from ..ap import ImageFrame, create_ap
        from ..errors import UsageError
        frame = ImageFrame(camera.width_mm, camera.height_mm, camera.pixel_size_mm)
        if model is not None:
            ap = model
        else:
            try:
                ap = create_ap(spec, frame, observed, **settings)
            except ValueError as exc:
                raise UsageError(f"AP model {spec}: {exc}") from None
        initial = np.zeros(ap.n_params)
        if camera.initial_ap is not None:
            initial = initial_coefficients(ap, camera.initial_ap, frame, observed, camera.camera_id)
        return ap, initial

    def camera_setup(self, camera, options):
        value = np.array([camera.focal_mm, camera.x0_mm, camera.y0_mm], float)
        free = np.ones(3, bool)
        sigma = np.full(3, np.nan)
        for i, s in enumerate((camera.sigma_focal_mm, camera.sigma_x0_mm, camera.sigma_y0_mm)):
            if s is not None:
                if s == 0:
                    free[i] = False
                else:
                    sigma[i] = s
        return value, free, sigma


SENSOR = FrameSensor()


def initial_coefficients(ap, initial, frame, observed_xy_mm: np.ndarray, camera_id: str) -> np.ndarray:
    """Initial AP coefficients from block.toml `[cameras.ID.initial_ap]`: the values themselves when the
    model is the same, else ``ap``'s least-squares fit of their distortion field on a 61-node grid (the parts
    the orientation absorbs fitted alongside and left to it)."""
    from ..ap import create_ap, fit_displacement, frame_nodes_mm
    from ..errors import BlockError
    where = f"cameras.{camera_id}.initial_ap"
    try:
        source = create_ap(initial.spec, frame, observed_xy_mm)
    except ValueError as exc:
        raise BlockError("block.toml", str(exc), None, f"{where}.model") from None
    given = dict(zip(initial.names, initial.values_px))
    unknown = sorted(set(given) - set(source.parameter_names))
    if unknown:
        raise BlockError("block.toml", f"{initial.spec} has no coefficient {unknown[0]!r} (its coefficients: "
                                       f"{', '.join(source.parameter_names)})", None, f"{where}.{unknown[0]}")
    values = np.array([given.get(name, 0.0) for name in source.parameter_names])
    if source.spec == ap.spec and source.parameter_names == ap.parameter_names:
        return values
    x, y = frame_nodes_mm(frame)
    dx, dy = source.displacement_px(x, y, values)
    return fit_displacement(ap, x, y, dx, dy, absorbed=True)[0]
