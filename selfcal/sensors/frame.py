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

import numpy as np
from numba import njit

from ..geometry.rotation import matrix_from_opk, matrix_from_opk_with_derivatives

__all__ = [
    "EOP_NAMES",
    "IOP_NAMES",
    "photo_from_pixel",
    "pixel_from_photo",
    "project",
    "project_with_jacobians",
    "project_with_jacobians_indexed",
    "rays",
]

EOP_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
IOP_NAMES = ("c", "x0", "y0")


def photo_from_pixel(pixel: np.ndarray, width_px, height_px, pixel_size_mm) -> np.ndarray:
    """Photo coordinates (mm, y up, origin at the image centre) of pixel positions (col, row)."""
    pixel = np.asarray(pixel, float)
    x = (pixel[..., 0] - np.asarray(width_px) / 2.0) * pixel_size_mm
    y = (np.asarray(height_px) / 2.0 - pixel[..., 1]) * pixel_size_mm
    return np.stack([x, y], axis=-1)


def pixel_from_photo(xy_mm: np.ndarray, width_px, height_px, pixel_size_mm) -> np.ndarray:
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
                           rotation=None):
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
def _project_indexed(points, eop, iop, m_img, dm_img, img, cam):
    n = points.shape[0]
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


def project_with_jacobians_indexed(points_m: np.ndarray, eop_images: np.ndarray, iop_cameras: np.ndarray,
                                   rotation, image_index: np.ndarray, camera_index: np.ndarray):
    """:func:`project_with_jacobians` for observations given by image and camera index.

    Parameters
    ----------
    points_m : (n, 3) object point of each observation
    eop_images : (n_images, 6) exterior orientation of every image
    iop_cameras : (n_cameras, 3) interior orientation of every camera
    rotation : (M, dM) of every image, from ``matrix_from_opk_with_derivatives(eop_images[:, 3:])``
    image_index, camera_index : (n,) the observation's image and camera

    Same results as :func:`project_with_jacobians` (a compiled loop; the tests compare both).
    """
    m_img, dm_img = rotation
    return _project_indexed(np.ascontiguousarray(points_m, dtype=np.float64),
                            np.ascontiguousarray(eop_images, dtype=np.float64),
                            np.ascontiguousarray(iop_cameras, dtype=np.float64),
                            np.ascontiguousarray(m_img), np.ascontiguousarray(dm_img),
                            np.ascontiguousarray(image_index, dtype=np.int64),
                            np.ascontiguousarray(camera_index, dtype=np.int64))


def rays(xy_mm: np.ndarray, eop: np.ndarray, iop: np.ndarray) -> np.ndarray:
    """Unit object-space directions of the rays through photo points (mm), shape (n, 3)."""
    iop = np.broadcast_to(np.asarray(iop, float), (len(xy_mm), 3))
    m = matrix_from_opk(eop[:, 3:])
    v = np.stack([xy_mm[:, 0] - iop[:, 1], xy_mm[:, 1] - iop[:, 2], -iop[:, 0]], axis=-1)
    d = np.einsum("nji,nj->ni", m, v)
    return d / np.linalg.norm(d, axis=1, keepdims=True)
