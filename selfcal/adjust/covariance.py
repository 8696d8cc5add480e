"""Cofactor matrices of the estimate, without inverting the full normal matrix.

Q_theta = S^-1 comes from the reduced system. The 3x3 cofactor block of each
object point follows from the Schur structure:

    Q_pp = V^-1 + Z^T Q_theta Z,     Z = W V^-1 (the point's coupling with theta),

summed over the pairs of observations of the point (their images' blocks of
Q_theta) and the camera-parameter block, so the cost grows with the number of
observations, not with the square of the number of unknowns.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .normal import Linearisation, point_camera_coupling
from .problem import Problem
from .kernels import point_blocks_times, point_cofactor_pairs

__all__ = ["point_cofactors", "by_point_and_image"]


def by_point_and_image(Z_e: np.ndarray, img: np.ndarray, ptl: np.ndarray, n_pc: int, n_img: int) -> sp.csr_matrix:
    """Sparse (3 n_pc, w n_img) matrix holding Z_e[o]^T (Z_e: (m, w, 3)) at (point of o, image of o), summed."""
    w = Z_e.shape[1]
    rows = (3 * ptl[:, None, None] + np.arange(3)[None, :, None]).repeat(w, axis=2)      # (m, 3, w)
    cols = (w * img[:, None, None] + np.arange(w)[None, None, :]).repeat(3, axis=1)
    vals = Z_e.transpose(0, 2, 1)                                                        # (m, 3, w)
    return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n_pc, w * n_img))


def point_cofactors(problem: Problem, lin: Linearisation, v_inv: list, Q: np.ndarray) -> np.ndarray:
    """Cofactor blocks Q_pp of all points, shape (n_points, 3, 3)."""
    n_img, n_e, n_d = problem.n_images, problem.n_e, problem.n_d
    Q_e = np.ascontiguousarray(Q[:n_e, :n_e])
    Q_dd = Q[n_e:n_e + n_d, n_e:n_e + n_d]
    Q_ed_2d = np.ascontiguousarray(Q[:n_e, n_e:n_e + n_d])
    out = np.zeros((problem.n_points, 3, 3))
    for ch, cs, Vi in zip(lin.chunks, problem.structure().chunks, v_inv):
        n_pc = ch.p1 - ch.p0
        img, ptl = cs.img, cs.ptl
        Z_e = ch.w_e @ Vi[ptl]                                              # (m, w, 3)
        Qp = Vi.copy()
        point_cofactor_pairs(Z_e, img, ptl, cs.pair_a, cs.pair_b, Q_e, Qp)
        if n_d:
            W_pd = point_camera_coupling(problem, ch, cs)
            Z = point_blocks_times(Vi, W_pd, False).reshape(n_pc, 3, n_d)      # Z[p] = Vi[p] W_pd[p]
            QZ = (Z.reshape(3 * n_pc, n_d) @ Q_dd).reshape(n_pc, 3, n_d)
            # per point: sum over its observations of Z_e^T Q_ed(image), as one sparse product
            A = (by_point_and_image(Z_e, img, ptl, n_pc, n_img) @ Q_ed_2d).reshape(n_pc, 3, n_d)
            cross = A @ Z.transpose(0, 2, 1)
            Qp += Z @ QZ.transpose(0, 2, 1) + cross + cross.transpose(0, 2, 1)
        out[ch.p0:ch.p1] = 0.5 * (Qp + Qp.transpose(0, 2, 1))
    return out
