"""Leverages of every observation: h = j Q j^T, the share of an observation its own estimate takes, from the
Schur structure without any inverse of the full system (the redundancy number is r = 1 - h).

For an image coordinate of point p seen in image i (Q_θp = -Q_θθ Z_p with Z_p = W_p V_p⁻¹):

    h = j_θ Q_θθ j_θᵀ - 2 j_θ (Q_θθ Z_p) j_pᵀ + j_p Q_pp j_pᵀ,

where j_θ touches only the observation's own image and the camera parameters; (Q_θθ Z_p) restricted to those
rows is summed over the observations of the point. The points' cofactor blocks come out of the same pass
(:class:`~selfcal.adjust.covariance.PointCofactors`). A parameter observation's h reads Q only at the pairs of
columns its row couples (:func:`parameter_leverages`), a control point's is diag(W Q_pp Wᵀ).
"""
from __future__ import annotations

import numpy as np

from ..ap.base import pattern_groups
from .ap_columns import evaluate_ap_columns, sparse_ap_rows
from .covariance import PointCofactors, times_lower
from .kernels import NO_SLOTS, image_quadratic, leverage_camera_cross, leverage_pairs, rows_dot_blocks
from .parallel import over_chunks
from .residuals.image import chunk_rows, contexts

__all__ = ["image_leverages", "parameter_leverages"]


def parameter_leverages(J, Q) -> np.ndarray:
    """diag(J Q J^T) of a sparse J, reading Q only at the pairs of columns a row of J couples (on the
    pattern of J^T J, part of the reduced matrix: a BandedCofactor knows them)."""
    counts = np.diff(J.indptr)
    row = np.repeat(np.arange(J.shape[0]), counts)
    # every ordered pair (a, b) of non-zeros of the same row
    sizes = counts[row]
    first = np.repeat(np.arange(J.nnz), sizes)
    offsets = np.arange(first.size) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    second = np.repeat(J.indptr[row], sizes) + offsets
    values = J.data[first] * J.data[second] * Q[J.indices[first], J.indices[second]]
    return np.bincount(row[first], weights=values, minlength=J.shape[0])


def image_leverages(problem, state, lin, v_inv, Q, Q_points=None):
    """h (m, 2) of every image coordinate (sorted order), whitened residuals l - f, and the points' cofactor
    blocks: ``Q_points`` if given, else computed in the same pass (they share its products)."""
    n_img, n_d = problem.n_images, problem.n_d
    sparse = sparse_ap_rows(problem) if n_d else None
    parts = PointCofactors(problem, Q, full_product=sparse is not None)  # Q_theta on the reduced matrix's pattern only
    Q_diag, L_dd = parts.Q_diag, parts.L_dd
    dense = n_d and not parts.compact                   # compact cameras are part of each observation's block
    G_sparse = None
    if sparse is not None:
        # j_d = [core, a] blockdiag(I, T) with a the sparse rows, T sparse.to_params: j_d Q_dd j_d^T = x G x^T
        # over each observation's few non-zeros x, G = blockdiag(I, T) Q_dd blockdiag(I, T)^T
        n_core = problem.cameras[0].n_core
        T = np.zeros((n_core + sparse.to_params.shape[0], n_d))
        T[:n_core, :n_core] = np.eye(n_core)
        T[n_core:, n_core:] = sparse.to_params
        G_sparse = T @ parts.Q_dd @ T.T
    Q_ed = parts.Q_ed.reshape(n_img, parts.rows_width, n_d) if parts.Q_ed is not None else None  # (dense: not None)
    context = contexts(problem, state)
    h_all = np.zeros((problem.n_image_observations, 2))
    r_all = np.zeros((problem.n_image_observations, 2))
    points = np.zeros((problem.n_points, 3, 3)) if Q_points is None else Q_points
    structure = problem.structure()
    evaluate_ap_columns(problem)

    def work(chunk, _) -> None:
        ch, cs, Vi = chunk
        n_pc = ch.p1 - ch.p0
        img, ptl = cs.img, cs.ptl
        m = len(img)
        # the rows in working columns where the linearisation has them (its couplings are in the same slots)
        r, j_e, j_p, j_d, columns = chunk_rows(problem, state, cs, context, parts.compact, ch.columns is not None)
        slots = NO_SLOTS if columns is None else columns
        if parts.compact:
            j_e = np.concatenate([j_e, j_d], axis=2)        # the image's and its camera's columns, one block
        terms = parts.chunk(ch, cs, Vi)
        if Q_points is None:
            points[ch.points] = terms.Q_pp
        G = np.zeros((m, j_e.shape[2], 3))
        leverage_pairs(terms.Z_e, img, cs.pair_a, cs.pair_b, cs.pair_key, Q_diag, parts.Q_pair, G, slots)  # Q_ab Z_b
        h = image_quadratic(j_e, Q_diag, img, slots)
        jp_term = j_e @ G                                                   # (m, 2, 3), completed below
        if dense:
            assert terms.Z is not None and terms.A is not None          # (the products of the dense camera part)
            Z = terms.Z.reshape(n_pc, 3, n_d)
            leverage_camera_cross(j_e, j_d, img, ptl, Q_ed, Z, jp_term, h, slots)   # j_e Q_ed terms
            # H_p = Q_dd Z_d(p) + sum over the point's observations of Q_ed(image)^T Z_e, H_p^T stored
            if terms.ZL is None:
                assert terms.H is not None                              # (H without the factor L_dd)
                jp_term += rows_dot_blocks(j_d, ptl, terms.H.reshape(n_pc, 3, n_d))
                if sparse is None:
                    h += np.einsum("rd,rd->r", j_d.reshape(2 * m, n_d) @ parts.Q_dd,
                                   j_d.reshape(2 * m, n_d)).reshape(m, 2)
                else:
                    assert G_sparse is not None                         # (made with the sparse rows)
                    h += _sparse_quadratic(j_d[:, :, :n_core], sparse, cs.o0, cs.o1, G_sparse)
            else:
                assert L_dd is not None                                 # (ZL is Z L_dd)
                jp_term += rows_dot_blocks(j_d, ptl, terms.A.reshape(n_pc, 3, n_d))
                # with Q_dd = L L^T: j_d Q_dd Z^T = (j_d L)(Z L)^T and j_d Q_dd j_d^T = |j_d L|^2, two triangular
                # products instead of a general one and a second pass
                for XL, ZL in zip(times_lower(j_d.reshape(2 * m, n_d), L_dd), terms.ZL):   # column blocks
                    jp_term += rows_dot_blocks(XL.reshape(m, 2, -1), ptl, ZL.reshape(n_pc, 3, -1))
                    h += np.einsum("rd,rd->r", XL, XL).reshape(m, 2)
        h -= 2.0 * np.einsum("okj,okj->ok", jp_term, j_p)
        h += np.einsum("oki,oij,okj->ok", j_p, points[ch.points[ptl]], j_p)
        h_all[cs.o0:cs.o1] = h
        r_all[cs.o0:cs.o1] = r

    over_chunks(list(zip(lin.chunks, structure.chunks, v_inv)), work, lambda: None)
    return h_all, r_all, points


def _sparse_quadratic(core: np.ndarray, sparse, o0: int, o1: int, G: np.ndarray) -> np.ndarray:
    """x G x^T of each x and y row of observations o0:o1, x = [core, sparse values] at the columns
    [0..n_core), n_core + the raw columns of the observation's pattern: one dense product per pattern and
    axis over its observations (a few dozen columns each, where j_d has hundreds)."""
    m, _, n_core = core.shape
    out = np.empty((m, 2))
    pattern = sparse.pattern[o0:o1]
    for rows in pattern_groups(pattern):
        for k in range(2):
            cols = np.concatenate([np.arange(n_core), n_core + sparse.columns[pattern[rows[0]], k]])
            X = np.concatenate([core[rows, k], sparse.values[o0 + rows, k]], axis=1)
            out[rows, k] = np.einsum("rd,rd->r", X @ G[np.ix_(cols, cols)], X)
    return out

