"""Cofactor matrices of the estimate, without inverting the full normal matrix.

Q_theta = S^-1 comes from the reduced system. The 3x3 cofactor block of each
object point follows from the Schur structure:

    Q_pp = V^-1 + Z^T Q_theta Z,     Z = W V^-1 (the point's coupling with theta),

summed over the pairs of observations of the point (their images' blocks of
Q_theta) and the camera-parameter block, so the cost grows with the number of
observations, not with the square of the number of unknowns. Of Q_theta it reads
only the blocks on the pattern of the reduced matrix (:func:`image_blocks`: each
image's own block and those of the pairs of images that share a point) and the
camera parameters' columns, so a :class:`~selfcal.adjust.selected.BandedCofactor`
(the selected inverse) serves as well as the dense inverse.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from .normal import Linearisation, point_camera_coupling
from .problem import Problem
from .kernels import add_point_image_products, point_blocks_times, point_cofactor_pairs

__all__ = ["point_cofactors", "image_blocks", "lower_cholesky", "times_lower",
           "camera_quadratic"]


def image_blocks(Q, problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Q_theta's image blocks: (n_images, w, w) of each image, and (n_pairs, w, w) of each pair of
    images that share a point (``problem.structure().pair_keys``: Q(image_pair_a, image_pair_b)).
    ``Q`` is a dense ndarray or a BandedCofactor: both take NumPy's fancy indexing."""
    w, n_img = problem.image_width, problem.n_images
    structure = problem.structure()
    k = np.arange(w)
    diag = w * np.arange(n_img)[:, None, None]
    Q_diag = Q[diag + k[None, :, None], diag + k[None, None, :]]
    rows = w * structure.image_pair_a[:, None, None] + k[None, :, None]
    cols = w * structure.image_pair_b[:, None, None] + k[None, None, :]
    Q_pair = Q[rows, cols] if len(structure.pair_keys) else np.zeros((0, w, w))
    return np.ascontiguousarray(Q_diag), np.ascontiguousarray(Q_pair)


def point_cofactors(problem: Problem, lin: Linearisation, v_inv: list, Q) -> np.ndarray:
    """Cofactor blocks Q_pp of all points, shape (n_points, 3, 3); ``Q``: Q_theta (see module docstring)."""
    n_e, n_d = problem.n_e, problem.n_d
    Q_diag, Q_pair = image_blocks(Q, problem)
    Q_dd = Q[n_e:n_e + n_d, n_e:n_e + n_d]
    Q_ed_2d = np.ascontiguousarray(Q[:n_e, n_e:n_e + n_d])
    L_dd = lower_cholesky(Q_dd) if n_d else None
    out = np.zeros((problem.n_points, 3, 3))
    for ch, cs, Vi in zip(lin.chunks, problem.structure().chunks, v_inv):
        n_pc = ch.p1 - ch.p0
        img, ptl = cs.img, cs.ptl
        Z_e = ch.w_e @ Vi[ptl]                                              # (m, w, 3)
        Qp = Vi.copy()
        point_cofactor_pairs(Z_e, img, ptl, cs.pair_a, cs.pair_b, cs.pair_key, Q_diag, Q_pair, Qp)
        if n_d:
            W_pd = point_camera_coupling(problem, ch, cs)
            Z = point_blocks_times(Vi, W_pd, False)                            # Z[p] = Vi[p] W_pd[p], (3 n_pc, n_d)
            # per point: sum over its observations of Z_e^T Q_ed(image)
            A = np.zeros((3 * n_pc, n_d))
            add_point_image_products(Z_e, img, ptl, Q_ed_2d, A)
            cross = A.reshape(n_pc, 3, n_d) @ Z.reshape(n_pc, 3, n_d).transpose(0, 2, 1)
            Qp += camera_quadratic(Z, Q_dd, L_dd).reshape(n_pc, 3, 3) + cross + cross.transpose(0, 2, 1)
        out[ch.p0:ch.p1] = 0.5 * (Qp + Qp.transpose(0, 2, 1))
    return out


def lower_cholesky(Q: np.ndarray) -> np.ndarray | None:
    """L with Q = L L^T, or None if Q is not numerically positive definite."""
    try:
        return np.linalg.cholesky(Q)
    except np.linalg.LinAlgError:
        return None


def times_lower(X: np.ndarray, L: np.ndarray) -> np.ndarray:
    """X L for a lower triangular L: a triangular product (half the flops of X Q), as a new C-ordered array."""
    # X^T is Fortran-ordered: L^T X^T is X L, written to a copy (X may be a view of kept data)
    return scipy.linalg.blas.dtrmm(1.0, L, X.T, side=0, lower=1, trans_a=1).T


def camera_quadratic(Z: np.ndarray, Q: np.ndarray, L: np.ndarray | None) -> np.ndarray:
    """The 3x3 blocks Z[p] Q Z[p]^T of Z (3 n, k): with Q = L L^T, Gram matrices of the rows of Z L."""
    n = Z.shape[0] // 3
    if L is None:
        return (Z @ Q).reshape(n, 3, -1) @ Z.reshape(n, 3, -1).transpose(0, 2, 1)
    ZL = times_lower(Z, L).reshape(n, 3, -1)
    return ZL @ ZL.transpose(0, 2, 1)
