"""Redundancy numbers, Baarda's w-test and reliability of every observation.

For whitened observations (P = I) the cofactor matrix of the residuals is
Q_vv = I - J Q Jᵀ, so the redundancy number of observation i is

    r_i = 1 - h_i,    h_i = j_i Q j_iᵀ,

and sum_i r_i = n - u. For an image coordinate of point p seen in image i,
h_i is computed from the Schur structure without any inverse of the full
system (Q_θp = -Q_θθ Z_p with Z_p = W_p V_p⁻¹):

    h = j_θ Q_θθ j_θᵀ - 2 j_θ (Q_θθ Z_p) j_pᵀ + j_p Q_pp j_pᵀ,

where j_θ touches only the observation's own image and the camera
parameters; (Q_θθ Z_p) restricted to those rows is summed over the
observations of the point.

Baarda's w-test uses the a-priori sigma (unit weight 1 after whitening):
w_i = v_i / sqrt(r_i), standard normal for a blunder-free observation.
Internal reliability: the minimal detectable blunder
MDB_i = delta0 · sigma_i / sqrt(r_i); external reliability: Baarda's factor
delta_bar_i = delta0 · sqrt((1 - r_i) / r_i), the largest effect of an
undetected blunder of size MDB_i on any function of the unknowns, in units of
that function's standard deviation. delta0 = k + z(beta0) with the critical
value k of the test and the power beta0 = 80 %.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from ..adjust.ap_columns import evaluate_ap_columns, sparse_ap_rows
from ..adjust.residuals import parameter_observations
from ..adjust.residuals.image import chunk_rows, contexts
from ..adjust.parallel import over_chunks
from ..adjust.covariance import PointCofactors, times_lower
from ..adjust.linalg import blas_threads
from ..adjust.kernels import leverage_camera_cross, leverage_pairs, rows_dot_blocks
from ..ap.base import pattern_groups

__all__ = ["ObservationTests", "observation_tests", "noncentrality"]

POWER = 0.80


def noncentrality(critical: float, power: float = POWER) -> float:
    """delta0 of Baarda's test: the blunder (in sigma) detected with probability ``power``."""
    return float(critical + norm.ppf(power))


@dataclass
class ObservationTests:
    """Per-observation statistics; image arrays follow ``result.block.observations`` order."""

    image_redundancy: np.ndarray   # (m, 2) for x and y
    image_w: np.ndarray            # (m, 2)
    image_mdb_px: np.ndarray       # (m, 2) minimal detectable blunder, pixels
    image_external: np.ndarray     # (m, 2) Baarda's external reliability factor
    control_redundancy: np.ndarray  # (n_gcp, 3)
    control_w: np.ndarray           # (n_gcp, 3)
    parameter_redundancy: np.ndarray  # (k,)
    parameter_w: np.ndarray           # (k,)
    critical: float
    delta0: float

    @property
    def total_redundancy(self) -> float:
        return float(self.image_redundancy.sum() + self.control_redundancy.sum() + self.parameter_redundancy.sum())

    def image_w_max(self) -> np.ndarray:
        """Per image observation, the w of the coordinate with the larger ``|w|`` (sign kept)."""
        w = self.image_w
        pick = np.argmax(np.abs(w), axis=1)
        return w[np.arange(len(w)), pick]


def _row_quadratic(J, Q) -> np.ndarray:
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


def _image_leverage(problem, state, lin, v_inv, Q, Q_points=None):
    """h (m, 2) of every image coordinate (sorted order), whitened residuals l - f, and the points' cofactor
    blocks: ``Q_points`` if given, else computed in the same pass (they share its products)."""
    n_img, n_d, width = problem.n_images, problem.n_d, problem.image_width
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
    Q_ed = parts.Q_ed.reshape(n_img, width, n_d) if dense else None
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
        r, j_e, j_p, j_d = chunk_rows(problem, state, cs, context, parts.compact)
        if parts.compact:
            j_e = np.concatenate([j_e, j_d], axis=2)        # the image's and its camera's columns, one block
        terms = parts.chunk(ch, cs, Vi)
        if Q_points is None:
            points[ch.points] = terms.Q_pp
        G = np.zeros((m, j_e.shape[2], 3))
        leverage_pairs(terms.Z_e, img, cs.pair_a, cs.pair_b, cs.pair_key, Q_diag, parts.Q_pair, G)  # sum_b Q_ab Z_b
        h = np.einsum("oki,oij,okj->ok", j_e, Q_diag[img], j_e)
        jp_term = j_e @ G                                                   # (m, 2, 3), completed below
        if dense:
            Z = terms.Z.reshape(n_pc, 3, n_d)
            leverage_camera_cross(j_e, j_d, img, ptl, Q_ed, Z, jp_term, h)   # j_e Q_ed terms
            # H_p = Q_dd Z_d(p) + sum over the point's observations of Q_ed(image)^T Z_e, H_p^T stored
            if terms.ZL is None:
                jp_term += rows_dot_blocks(j_d, ptl, terms.H.reshape(n_pc, 3, n_d))
                if sparse is None:
                    h += np.einsum("rd,rd->r", j_d.reshape(2 * m, n_d) @ parts.Q_dd,
                                   j_d.reshape(2 * m, n_d)).reshape(m, 2)
                else:
                    h += _sparse_quadratic(j_d[:, :, :n_core], sparse, cs.o0, cs.o1, G_sparse)
            else:
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


def observation_tests(result, critical: float = 3.0) -> ObservationTests:
    """Redundancy numbers, w-tests and reliability of all observations of an adjustment."""
    problem, state = result.problem, result.state
    Q = result.Q_theta
    delta0 = noncentrality(critical)
    with blas_threads(problem.n_images):
        h, res, Qp = _image_leverage(problem, state, result.linearisation, result.v_inv, Q,
                                     result.point_cofactor_blocks)
    result.point_cofactor_blocks = Qp
    red = np.clip(1.0 - h, 1e-12, None)
    v = -res                                             # whitened residuals v = f - l
    # back to the block's observation order
    image_r = np.empty_like(red)
    image_r[problem.obs_order] = red
    image_v = np.empty_like(v)
    image_v[problem.obs_order] = v
    sigma_px = result.block.observations.sigma_px[:, None]
    image_w = image_v / np.sqrt(image_r)
    mdb = delta0 * sigma_px / np.sqrt(image_r)
    external = delta0 * np.sqrt((1.0 - image_r) / image_r)

    ctl = problem.control_index
    W = problem.control_weight
    ctl_h = np.einsum("nij,njk,nik->ni", W, Qp[ctl], W)                # diag(W Q_pp W^T)
    ctl_r = np.clip(1.0 - ctl_h, 1e-12, None)
    ctl_v = np.einsum("nij,nj->ni", W, state.points[ctl] - problem.control_xyz)
    J_x, r_x = parameter_observations(problem, state)
    par_h = _row_quadratic(J_x.tocsr(), Q) if J_x.shape[0] else np.zeros(0)
    par_r = np.clip(1.0 - par_h, 1e-12, None)
    return ObservationTests(
        image_redundancy=image_r, image_w=image_w, image_mdb_px=mdb, image_external=external,
        control_redundancy=ctl_r, control_w=ctl_v / np.sqrt(ctl_r),
        parameter_redundancy=par_r, parameter_w=-r_x / np.sqrt(par_r),
        critical=critical, delta0=delta0,
    )
