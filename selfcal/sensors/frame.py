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

from ..geometry.rotation import matrix_from_opk, matrix_from_opk_with_derivatives

__all__ = [
    "EOP_NAMES",
    "IOP_NAMES",
    "photo_from_pixel",
    "pixel_from_photo",
    "project",
    "project_with_jacobians",
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


def rays(xy_mm: np.ndarray, eop: np.ndarray, iop: np.ndarray) -> np.ndarray:
    """Unit object-space directions of the rays through photo points (mm), shape (n, 3)."""
    iop = np.broadcast_to(np.asarray(iop, float), (len(xy_mm), 3))
    m = matrix_from_opk(eop[:, 3:])
    v = np.stack([xy_mm[:, 0] - iop[:, 1], xy_mm[:, 1] - iop[:, 2], -iop[:, 0]], axis=-1)
    d = np.einsum("nji,nj->ni", m, v)
    return d / np.linalg.norm(d, axis=1, keepdims=True)
