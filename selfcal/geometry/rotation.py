"""Rotations of photogrammetry: omega-phi-kappa and their derivatives.

Convention (DESIGN.md §2, Wolf et al. 2014): the matrix

    M = R3(kappa) · R2(phi) · R1(omega)

maps object-space axes to image axes, with the passive elementary rotations

    R1(w) = [[1, 0, 0], [0, cos w, sin w], [0, -sin w, cos w]]
    R2(p) = [[cos p, 0, -sin p], [0, 1, 0], [sin p, 0, cos p]]
    R3(k) = [[cos k, sin k, 0], [-sin k, cos k, 0], [0, 0, 1]]

so that m31 = sin(phi), m32 = -sin(omega) cos(phi), m33 = cos(omega) cos(phi).
All functions are vectorised over a leading axis; angles are radians.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["matrix_from_opk", "matrix_from_opk_with_derivatives", "opk_from_matrix",
           "opk_from_matrix_with_derivatives", "matrix_from_quaternion", "quaternion_from_matrix",
           "matrix_from_rotation_vector", "slerp", "looking_at"]


def _elementary(omega, phi, kappa, derivatives: bool = True):
    co, so = np.cos(omega), np.sin(omega)
    cp, sp = np.cos(phi), np.sin(phi)
    ck, sk = np.cos(kappa), np.sin(kappa)
    n = np.shape(omega)
    zero, one = np.zeros(n), np.ones(n)
    r1 = np.stack([one, zero, zero, zero, co, so, zero, -so, co], -1).reshape(n + (3, 3))
    r2 = np.stack([cp, zero, -sp, zero, one, zero, sp, zero, cp], -1).reshape(n + (3, 3))
    r3 = np.stack([ck, sk, zero, -sk, ck, zero, zero, zero, one], -1).reshape(n + (3, 3))
    if not derivatives:
        return r1, r2, r3
    d1 = np.stack([zero, zero, zero, zero, -so, co, zero, -co, -so], -1).reshape(n + (3, 3))
    d2 = np.stack([-sp, zero, -cp, zero, zero, zero, cp, zero, -sp], -1).reshape(n + (3, 3))
    d3 = np.stack([-sk, ck, zero, -ck, -sk, zero, zero, zero, zero], -1).reshape(n + (3, 3))
    return r1, r2, r3, d1, d2, d3


def matrix_from_opk(opk: np.ndarray) -> np.ndarray:
    """Rotation matrices M, shape (..., 3, 3), from angles (..., 3) = (omega, phi, kappa)."""
    opk = np.asarray(opk, float)
    r1, r2, r3 = _elementary(opk[..., 0], opk[..., 1], opk[..., 2], derivatives=False)
    return r3 @ r2 @ r1


def matrix_from_opk_with_derivatives(opk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M and its partial derivatives dM/d(omega), dM/d(phi), dM/d(kappa).

    Returns
    -------
    M : ndarray (..., 3, 3)
    dM : ndarray (..., 3, 3, 3)
        ``dM[..., k, :, :]`` is the derivative with respect to angle k.
    """
    opk = np.asarray(opk, float)
    r1, r2, r3, d1, d2, d3 = _elementary(opk[..., 0], opk[..., 1], opk[..., 2])
    r21 = r2 @ r1
    m = r3 @ r21
    dm = np.stack([r3 @ r2 @ d1, r3 @ d2 @ r1, d3 @ r21], axis=-3)
    return m, dm


def opk_from_matrix(m: np.ndarray) -> np.ndarray:
    """Angles (omega, phi, kappa) of rotation matrices M (..., 3, 3); phi in [-pi/2, pi/2]."""
    m = np.asarray(m, float)
    phi = np.arcsin(np.clip(m[..., 2, 0], -1.0, 1.0))
    omega = np.arctan2(-m[..., 2, 1], m[..., 2, 2])
    kappa = np.arctan2(-m[..., 1, 0], m[..., 0, 0])
    return np.stack([omega, phi, kappa], axis=-1)


def opk_from_matrix_with_derivatives(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angles of M (as :func:`opk_from_matrix`) and their derivatives with respect to its elements.

    Returns
    -------
    opk : ndarray (..., 3)
    d_opk : ndarray (..., 3, 3, 3)
        ``d_opk[..., k, i, j]`` = d(angle k) / d(M[i, j]); only M[2, 0], M[2, 1], M[2, 2], M[1, 0], M[0, 0] enter.
    """
    m = np.asarray(m, float)
    opk = opk_from_matrix(m)
    d = np.zeros(m.shape[:-2] + (3, 3, 3))
    r_omega = m[..., 2, 1] ** 2 + m[..., 2, 2] ** 2
    d[..., 0, 2, 1] = -m[..., 2, 2] / r_omega
    d[..., 0, 2, 2] = m[..., 2, 1] / r_omega
    d[..., 1, 2, 0] = 1.0 / np.sqrt(np.clip(1.0 - m[..., 2, 0] ** 2, 1e-300, None))
    r_kappa = m[..., 1, 0] ** 2 + m[..., 0, 0] ** 2
    d[..., 2, 1, 0] = -m[..., 0, 0] / r_kappa
    d[..., 2, 0, 0] = m[..., 1, 0] / r_kappa
    return opk, d


def matrix_from_quaternion(q: np.ndarray, scalar_first: bool = True) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4).

    ``scalar_first``: (w, x, y, z) as COLMAP writes them; otherwise (x, y, z, w)
    as DESIGN.md §3 stores attitudes (q1, q2, q3 vector, q4 scalar). The
    matrix rotates vectors: v' = R v (active), Hamilton convention.
    """
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    if scalar_first:
        w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    else:
        x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def quaternion_from_matrix(m: np.ndarray, scalar_first: bool = True) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation matrices (..., 3, 3), the inverse of
    :func:`matrix_from_quaternion` (scalar part >= 0). Shepperd's method: the largest of
    the four squared components is taken from the diagonal, the others from sums and
    differences of off-diagonal elements."""
    m = np.asarray(m, float)
    t = np.stack([1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2], 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                  1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2], 1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], -1)
    pick = np.argmax(t, axis=-1)
    s = 2.0 * np.sqrt(np.take_along_axis(t, pick[..., None], -1)[..., 0])
    d21, d02, d10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    s21, s02, s10 = m[..., 2, 1] + m[..., 1, 2], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1]
    candidates = np.stack([
        np.stack([s / 4, d21 / s, d02 / s, d10 / s], -1),
        np.stack([d21 / s, s / 4, s10 / s, s02 / s], -1),
        np.stack([d02 / s, s10 / s, s / 4, s21 / s], -1),
        np.stack([d10 / s, s02 / s, s21 / s, s / 4], -1),
    ], -2)                                                        # (..., 4 cases, (w, x, y, z))
    q = np.take_along_axis(candidates, pick[..., None, None], -2)[..., 0, :]
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    return q if scalar_first else np.concatenate([q[..., 1:], q[..., :1]], -1)


def matrix_from_rotation_vector(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (axis times angle, radians; Rodrigues)."""
    v = np.asarray(v, float)
    theta = np.linalg.norm(v, axis=-1)
    small = theta < 1e-12
    safe = np.where(small, 1.0, theta)
    k = v / safe[..., None]
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    K = np.stack([np.stack([zero, -kz, ky], -1), np.stack([kz, zero, -kx], -1), np.stack([-ky, kx, zero], -1)], -2)
    s, c = np.sin(theta)[..., None, None], np.cos(theta)[..., None, None]
    R = np.eye(3) + s * K + (1 - c) * (K @ K)
    # first-order for tiny angles: I + [v]x
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    V = np.stack([np.stack([zero, -vz, vy], -1), np.stack([vz, zero, -vx], -1), np.stack([-vy, vx, zero], -1)], -2)
    return np.where(small[..., None, None], np.eye(3) + V, R)


def slerp(times: np.ndarray, quaternions: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (n, 4) sampled at increasing ``times``, at ``t``
    (clamped to the first and last interval: extrapolated along them). Either component order works
    (the interpolation is component-wise). Neighbours are brought to the same hemisphere first, so the
    shorter arc is taken."""
    times = np.asarray(times, float)
    q = np.array(quaternions, float)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    if len(q) == 1:
        return np.broadcast_to(q[0], (np.size(t), 4)).copy()
    for k in range(1, len(q)):                         # same hemisphere as the previous sample
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    t = np.atleast_1d(np.asarray(t, float))
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    u = (t - times[i]) / (times[i + 1] - times[i])
    q0, q1 = q[i], q[i + 1]
    cos = np.clip(np.einsum("ni,ni->n", q0, q1), -1.0, 1.0)
    angle = np.arccos(cos)
    small = angle < 1e-12
    sin = np.where(small, 1.0, np.sin(angle))
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * angle) / sin)
    w1 = np.where(small, u, np.sin(u * angle) / sin)
    out = w0[:, None] * q0 + w1[:, None] * q1
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def looking_at(position: ArrayLike, target: ArrayLike, up: ArrayLike) -> np.ndarray:
    """M (object to image axes: x right, y up, z towards the viewer; the camera looks along its -z) of a camera at
    ``position`` whose axis points at ``target``, its x axis perpendicular to the object's direction ``up``."""
    z = np.asarray(position, float) - np.asarray(target, float)
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])
