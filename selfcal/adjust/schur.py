"""Normal equations with the object points eliminated (Schur complement).

With the unknowns split into theta (orientation, camera, extra) and the object
points p, the normal equations of the whitened problem are

    [ U    W ] [d_theta]   [g_theta]
    [ W^T  V ] [d_p    ] = [g_p    ]

where V is block diagonal with one 3x3 block per point. Eliminating the points
gives the reduced system

    (U - W V^-1 W^T) d_theta = g_theta - W V^-1 g_p,      d_p = V^-1 (g_p - W^T d_theta).

Everything is assembled chunk by chunk over the points (observations are sorted
by point), with NumPy and sparse products and no Python loop over
observations. The image observations (:mod:`.residuals.image`) give U, V and W;
every other residual block (:mod:`.residuals`) adds to the points' blocks V
(observations of points) or to theta's part (observations of parameters),
whatever its kind. The linearisation (Jacobians, U, V, W) is computed once per
iteration; the reduction is repeated only when the Levenberg-Marquardt damping
changes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import AdjustmentError
from .ap_columns import evaluate_ap_columns, sparse_ap_rows, sparse_gram
from .kernels import (NO_SLOTS, accumulate_observations, camera_couplings, camera_couplings_compact, compressed_columns,
                      point_blocks_times, schur_image_blocks, spd_inverse_3x3, subtract_image_couplings,
                      transposed_positions)
from .parallel import over_chunks
from .problem import Problem, State
from .residuals import parameter_observations
from .residuals.image import chunk_rows, contexts, image_residuals
from .working import image_maps, symmetrised, working_columns

__all__ = ["ChunkLinearisation", "Linearisation", "linearise", "linearise_points", "with_parameter_observations",
           "reduce", "back_substitute", "evaluate_cost",
           "cost_and_residuals", "points_cost_and_residuals", "parameter_cost",
           "SingularPoints", "damped_inverse"]


@dataclass
class ChunkLinearisation:
    p0: int              # positions [p0, p1) in Problem.point_order
    p1: int
    o0: int
    o1: int
    points: np.ndarray   # (n_pc,) the block's point at each position
    V: np.ndarray        # (n_pc, 3, 3) point normal blocks, control prior included
    g_p: np.ndarray      # (n_pc, 3)
    w_e: np.ndarray      # (m_c, width, 3) coupling of each observation's image with its point
    W_pd: np.ndarray | None      # (3 n_pc, n_d) coupling of the points with the camera parameters (dense form)
    w_d: np.ndarray | None = None  # (m_c, 3, width) its non-zero parts per observation (compact form)
    #: (m_c, slots): the working column (:mod:`.working`) of each of w_e's slots; None: w_e is in the image's columns
    columns: np.ndarray | None = None

    @property
    def slots(self) -> np.ndarray:
        """``columns`` as the kernels take them (:data:`~.kernels.NO_SLOTS` without working columns)."""
        return NO_SLOTS if self.columns is None else self.columns

    def couplings(self, transposed: bool = False) -> np.ndarray:
        """Each observation's coupling with its point over the columns it touches, (m_c, w, 3): its image's,
        then (compact cameras) its camera's (:func:`selfcal.adjust.covariance.observation_columns` names them).
        ``transposed``: (m_c, 3, w), C-contiguous."""
        if transposed:
            if self.w_d is None:
                return np.ascontiguousarray(self.w_e.transpose(0, 2, 1))
            return np.concatenate([self.w_e.transpose(0, 2, 1), self.w_d], axis=2)
        return self.w_e if self.w_d is None else np.concatenate([self.w_e, self.w_d.transpose(0, 2, 1)], axis=1)


@dataclass
class Linearisation:
    cost: float
    U_ee: np.ndarray     # (n_images, width, width)
    U_ed: np.ndarray     # (n_e, n_d)
    U_dd: np.ndarray     # (n_d, n_d)
    g_theta: np.ndarray  # (n_theta,) before elimination, parameter observations included
    J_x: sp.csr_matrix   # parameter observations (whitened), (k, n_theta)
    r_x: np.ndarray
    chunks: list[ChunkLinearisation]
    diag_theta: np.ndarray   # diagonal of U (parameter observations included)

    def of_points(self, name: str) -> np.ndarray:
        """A chunk quantity of every point (``"V"``, ``"g_p"``) in the block's point order."""
        parts = [getattr(ch, name) for ch in self.chunks]
        out = np.empty((sum(len(ch.points) for ch in self.chunks),) + parts[0].shape[1:])
        for ch, part in zip(self.chunks, parts):
            out[ch.points] = part
        return out


def _gram(rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """rows[:, columns]^T rows[:, columns]: the product of all columns, then the block of ``columns``. A
    strided view or a gathered copy of the columns is several times slower than the few extra ones."""
    return _self_product(rows)[np.ix_(columns, columns)]


def _self_product(Z: np.ndarray) -> np.ndarray:
    """Z^T Z. NumPy sees the transpose of the same array and takes BLAS's symmetric rank-k update (half the
    flops of a general product), and releases the interpreter lock in it, so the threads of a pass
    (:mod:`.parallel`) run theirs side by side; SciPy's BLAS wrappers (dsyrk) hold the lock."""
    Z = np.ascontiguousarray(Z)
    return Z.T @ Z


def linearise(problem: Problem, state: State) -> Linearisation:
    """Jacobians and normal-equation blocks at ``state``: the observations of points
    (:func:`linearise_points`) and then, once, those of theta alone (:func:`with_parameter_observations`)."""
    return with_parameter_observations(problem, state, linearise_points(problem, state))


def linearise_points(problem: Problem, state: State) -> Linearisation:
    """The part of the normal equations that the image observations and the observations of points give: a sum
    over the points, so over any partition of them (a share of the points on a worker of a distributed
    adjustment gives its part, and the parts add). Without the observations of theta alone and without the held
    image parameters' unit diagonal, which belong to the whole problem once: ``J_x`` is empty and ``g_theta``,
    ``diag_theta`` and ``cost`` are the points' part."""
    n_img, n_e, n_d, width = problem.n_images, problem.n_e, problem.n_d, problem.image_width
    structure = problem.structure()
    context = contexts(problem, state)
    point_blocks = [(b, b.position(problem.n_points)) for b in problem.point_residuals if len(b)]
    varying = problem.d_varying()
    constant = np.setdiff1d(np.arange(n_d), varying)
    if not constant.size:
        varying = np.arange(n_d)
    compact = problem.compact_cameras
    if compact:
        cols = problem.camera_columns()
        constant = constant[:0]                 # the camera blocks are summed in every iteration
        varying = np.arange(n_d)
    gram = problem.ap_cache.gram
    build_gram = gram is None and constant.size > 0
    # one camera: the AP columns are its sparse rows times a map, where the model gives them so; their Gram
    # matrix is summed over each row's few raw columns, then mapped (T^T R T)
    sparse = sparse_ap_rows(problem) if build_gram else None
    if sparse is not None and not np.array_equal(constant, np.arange(problem.cameras[0].n_core, n_d)):
        sparse = None
    gram_size = sparse.to_params.shape[0] if sparse is not None else constant.size
    evaluate_ap_columns(problem)
    # the image rows in working columns where the sensor gives them (:mod:`.working`): the image blocks are summed
    # there and mapped to the image parameters afterwards
    working = working_columns(problem)
    rows_width = width if working is None else working.width

    def new_sums() -> dict:
        return {"U_ee": np.zeros((n_img, rows_width, rows_width)), "U_ed": np.zeros((n_img * rows_width, n_d)),
                "U_dd": np.zeros((n_d, n_d)), "g_e": np.zeros((n_img, rows_width)), "g_d": np.zeros(n_d),
                "cost": np.zeros(1), "gram": np.zeros((gram_size, gram_size)) if build_gram else None}

    def work(cs, sums: dict) -> ChunkLinearisation:
        p0, p1, o0, o1 = cs.p0, cs.p1, cs.o0, cs.o1
        m, n_pc = o1 - o0, p1 - p0
        r, j_e, j_p, j_d, columns = chunk_rows(problem, state, cs, context, compact, working is not None)
        slots = NO_SLOTS if columns is None else columns
        sums["cost"] += 0.5 * float(np.sum(r * r))

        # image and point blocks, and the coupling of each observation's image and point
        V, g_p, w_e = accumulate_observations(j_e, j_p, r, cs.img, cs.ptl, sums["U_ee"], sums["g_e"], n_pc, slots)
        W_pd, w_d = None, None
        if n_d and compact:
            w_d = camera_couplings_compact(j_d, j_e, j_p, r, cs.img, problem.image_camera[cs.img], cols,
                                           sums["U_ed"], sums["U_dd"], sums["g_d"])
        elif n_d:
            W_pd = np.zeros((3 * n_pc, n_d))
            U_vd = np.zeros((varying.size, n_d))
            camera_couplings(j_d, j_e, j_p, r, cs.img, cs.ptl, varying, sums["U_ed"], W_pd, sums["g_d"], U_vd,
                             slots, rows_width)
            U_dd = sums["U_dd"]
            if constant.size:
                # the AP columns are constant: their Gram block is summed once per problem
                U_dd[varying, :] += U_vd
                U_dd[np.ix_(constant, varying)] += U_vd[:, constant].T
                if build_gram:
                    sums["gram"] += (_gram(j_d.reshape(2 * m, n_d), constant) if sparse is None else
                                     sparse_gram(sparse, o0, o1))
            else:
                U_dd += U_vd

        # the rows of every observation of points alone (control coordinates, ...) go into their blocks
        for block, position in point_blocks:
            sel = position[cs.points]
            has = np.flatnonzero(sel >= 0)
            if has.size:
                rc, J = block.rows(state.points[cs.points[has]], sel[has])
                sums["cost"] += 0.5 * float(np.sum(rc * rc))
                V[has] += np.einsum("nki,nkj->nij", J, J)
                g_p[has] += np.einsum("nki,nk->ni", J, rc)
        return ChunkLinearisation(p0, p1, o0, o1, cs.points, V, g_p, w_e, W_pd, w_d, columns)

    chunks, parts = over_chunks(structure.chunks, work, new_sums)
    U_ee, U_ed, U_dd, g_e, g_d, cost = (sum(part[name] for part in parts)
                                        for name in ("U_ee", "U_ed", "U_dd", "g_e", "g_d", "cost"))
    cost = float(cost[0])
    if working is not None:
        maps = image_maps(problem, working)
        U_ee, g_e, U_ed = (maps.blocks_to_parameters(symmetrised(U_ee)), maps.vectors_to_parameters(g_e),
                           maps.rows_to_parameters(U_ed))
    if build_gram:
        gram = sum(part["gram"] for part in parts)
        if sparse is not None:
            gram = sparse.to_params.T @ gram @ sparse.to_params

    if constant.size:
        if build_gram:
            problem.ap_cache.gram = gram
        U_dd[np.ix_(constant, constant)] += gram
    g_theta = np.concatenate([g_e.ravel(), g_d, np.zeros(problem.n_extra)])
    return Linearisation(cost, U_ee, U_ed, U_dd, g_theta, sp.csr_matrix((0, problem.n_theta)), np.zeros(0), chunks,
                         np.zeros(0))


def with_parameter_observations(problem: Problem, state: State, lin: Linearisation) -> Linearisation:
    """``lin`` (the points' part, :func:`linearise_points`, of the whole problem or summed over shares of its
    points) completed, in place, with what the whole problem has once: the held image parameters' unit diagonal
    (their correction is zero), the observations of theta alone (priors, GNSS, IMU, the trajectory terms), and
    theta's diagonal."""
    if not problem.all_images_free:
        held_image, held_entry = np.nonzero(~problem.image_free)
        lin.U_ee[held_image, held_entry, held_entry] = 1.0
    J_x, r_x = parameter_observations(problem, state)
    lin.cost += 0.5 * float(np.sum(r_x * r_x))
    if J_x.shape[0]:
        lin.g_theta += J_x.T @ r_x
    diag_theta = np.concatenate([np.einsum("nii->ni", lin.U_ee).ravel(), np.diag(lin.U_dd).copy(),
                                 np.zeros(problem.n_extra)])
    if J_x.shape[0]:
        diag_theta += np.asarray(J_x.multiply(J_x).sum(axis=0)).ravel()
    lin.J_x, lin.r_x, lin.diag_theta = J_x, r_x, diag_theta
    return lin


class SingularPoints(AdjustmentError):
    """Point blocks of the normal equations that cannot be inverted (``indices`` into the points)."""

    def __init__(self, indices: np.ndarray):
        self.indices = np.asarray(indices)
        super().__init__(f"{len(self.indices)} object point(s) are not determined by their rays (parallel rays, "
                         f"or a point gone to infinity or behind its cameras)")


#: a point block whose condition number is beyond this is singular in double precision
SINGULAR_CONDITION = 1e16


def damped_inverse(V: np.ndarray, lam: float, points: np.ndarray | None = None) -> np.ndarray:
    """The inverse damped point blocks; a block that is singular raises SingularPoints naming its point
    (``points``: the block's point of each block, by default its index)."""
    if lam:
        V = V + lam * np.einsum("nii,ij->nij", V, np.eye(3))
    finite = np.isfinite(V).all(axis=(1, 2))
    if not finite.all():                    # a point gone to infinity (least squares pulled by wrong rays)
        bad = np.flatnonzero(~finite)
        raise SingularPoints(bad if points is None else points[bad])
    out = np.empty_like(V)
    if spd_inverse_3x3(V, out) < 0:
        # positive pivots, but a block as good as singular (two rays of wrong matches meeting at infinity): its
        # condition number is at least trace(V) trace(V^-1) / 9
        condition = np.einsum("nii->n", V) * np.einsum("nii->n", out)
        singular = ~(condition < SINGULAR_CONDITION)
        if singular.any():
            bad = np.flatnonzero(singular)
            raise SingularPoints(bad if points is None else points[bad])
        return out
    try:                                    # a block not positive definite: LU, which names singular ones
        return np.linalg.inv(V)
    except np.linalg.LinAlgError:
        w = np.linalg.eigvalsh(V)
        bad = np.flatnonzero(w[:, 0] <= 1e-14 * np.abs(w[:, 2]))
        raise SingularPoints(bad if points is None else points[bad]) from None


def _point_schur(Vi: np.ndarray, W_pd: np.ndarray) -> np.ndarray:
    """W_pd^T blockdiag(Vi) W_pd, (n_d, n_d): with Vi = L L^T per point, Z = blockdiag(L^T) W_pd
    and the product is Z^T Z, a symmetric rank-k update (half the flops of a general product)."""
    try:
        L = np.linalg.cholesky(Vi)
    except np.linalg.LinAlgError:                       # a point block not positive definite: the plain product
        return W_pd.T @ point_blocks_times(Vi, W_pd, False)
    return _self_product(point_blocks_times(L, W_pd, True))


@dataclass
class ReducedSums:
    """The reduced normal equations as sums over the points, before their assembly into one matrix: the image
    blocks (one per image, one per pair of images that share a point, ``pair_keys`` ia * n_images + ib with
    ia < ib), the image-camera and camera-camera parts, and the right-hand side. :meth:`start` holds the
    linearisation's U and g, to which :func:`add_point_schur` adds the points' - W V^-1 W^T and - W V^-1 g_p;
    :meth:`zeros` holds nothing, for the part of a share of the points (a worker's)."""

    diag: np.ndarray        # (n_images, w, w)
    off: np.ndarray         # (n_pairs, w, w)
    pair_keys: np.ndarray   # (n_pairs,)
    S_ed: np.ndarray        # (n_e, n_d)
    S_dd: np.ndarray        # (n_d, n_d)
    g: np.ndarray           # (n_theta,)

    @classmethod
    def start(cls, problem: Problem, lin: Linearisation) -> "ReducedSums":
        keys = problem.structure().pair_keys
        return cls(lin.U_ee.copy(), np.zeros((len(keys), problem.image_width, problem.image_width)), keys,
                   lin.U_ed.copy(), lin.U_dd.copy(), lin.g_theta.copy())

    @classmethod
    def zeros(cls, problem: Problem) -> "ReducedSums":
        keys = problem.structure().pair_keys
        w, n_d = problem.image_width, problem.n_d
        return cls(np.zeros((problem.n_images, w, w)), np.zeros((len(keys), w, w)), keys, np.zeros((problem.n_e, n_d)),
                   np.zeros((n_d, n_d)), np.zeros(problem.n_theta))

    def add(self, part: "ReducedSums") -> None:
        """Add another share's part (its pairs among these)."""
        self.diag += part.diag
        if len(part.pair_keys):
            self.off[np.searchsorted(self.pair_keys, part.pair_keys)] += part.off
        self.S_ed += part.S_ed
        self.S_dd += part.S_dd
        self.g += part.g


def reduce(problem: Problem, lin: Linearisation, lam: float = 0.0, dense: bool = True):
    """Reduced normal matrix S and right-hand side g of theta, with damping ``lam``.

    The damping adds ``lam * diag(N)`` to the full normal matrix N
    (Levenberg-Marquardt with Marquardt's scaling).

    The image-image part of W V^-1 W^T is summed over the pairs of
    observations of each point (one 6x6 block per pair of images that share
    the point); the camera-parameter parts are dense products.

    Returns
    -------
    S : ndarray or scipy.sparse.csc_matrix, (n_theta, n_theta)
    g : ndarray (n_theta,)
    v_inv : list of (n_pc, 3, 3) damped inverse point blocks per chunk
    """
    sums = ReducedSums.start(problem, lin)
    v_inv = add_point_schur(problem, lin.chunks, lam, sums)
    return assemble(problem, lin, sums, lam, dense), sums.g, v_inv


def add_point_schur(problem: Problem, chunks: list[ChunkLinearisation], lam: float, sums: ReducedSums) -> list:
    """Add the points' part of the reduced system, - W V^-1 W^T and - W V^-1 g_p with the damped point blocks, to
    ``sums`` (over the problem's pairs of images); returns the damped inverse point blocks of each chunk."""
    n_img, n_e, n_d, n_t = problem.n_images, problem.n_e, problem.n_d, problem.n_theta
    w = problem.image_width
    structure = problem.structure()
    S_ed, S_dd, g, diag_blocks, off_blocks = sums.S_ed, sums.S_dd, sums.g, sums.diag, sums.off
    # compact cameras: an observation's block is its image's columns and its camera's (one camera per
    # image in BAL); the Schur terms of both are summed over the pairs of each point's observations at once
    # and spread over S_ee, S_ed and S_dd afterwards
    compact = bool(n_d) and bool(chunks) and chunks[0].w_d is not None
    if compact:
        own = problem.camera_columns()[problem.image_camera]               # (n_images, camera width), -1 pads
        wide = w + own.shape[1]
        wide_diag = np.zeros((n_img, wide, wide))
        wide_off = np.zeros((len(structure.pair_keys), wide, wide))
    n_pairs = len(structure.pair_keys)
    # image rows in working columns (:mod:`.working`): the Schur terms are summed there, then mapped
    working = working_columns(problem)
    rows_width = w if working is None else working.width

    def new_sums() -> dict:
        wider = wide if compact else rows_width
        return {"diag": np.zeros((n_img, wider, wider)), "off": np.zeros((n_pairs, wider, wider)),
                "g": np.zeros(n_t), "S_ed": np.zeros((n_img * rows_width, n_d)), "S_dd": np.zeros((n_d, n_d)),
                "g_w": np.zeros(n_img * rows_width) if working is not None else None}

    def work(pair, sums: dict) -> np.ndarray:
        ch, cs = pair
        Vi = damped_inverse(ch.V, lam, ch.points)
        g = sums["g"]
        Y_t = schur_image_blocks(Vi, cs.ptl, ch.couplings(transposed=True), cs.img, cs.pair_a, cs.pair_b,
                                 cs.pair_key, sums["diag"], sums["off"], ch.slots)  # (m, 3, w or wide) = V^-1 W^T
        if ch.columns is not None:
            yg = np.einsum("oki,ok->oi", Y_t, ch.g_p[cs.ptl])
            at = (rows_width * cs.img[:, None] + ch.columns).ravel()
            sums["g_w"] -= np.bincount(at, weights=yg.ravel(), minlength=n_img * rows_width)
            if n_d:
                subtract_image_couplings(Y_t, ch.W_pd, cs.img, cs.ptl, sums["S_ed"], ch.slots, rows_width)
                sums["S_dd"] -= _point_schur(Vi, ch.W_pd)
                g[n_e:n_e + n_d] -= ch.W_pd.T @ np.einsum("pij,pj->pi", Vi, ch.g_p).ravel()
            return Vi
        if compact:
            yg = np.einsum("oki,ok->oi", Y_t, ch.g_p[cs.ptl])
            g[:n_e] -= (cs.sum_by_image @ yg[:, :w]).ravel()
            cols = own[cs.img]
            np.subtract.at(g, n_e + cols[cols >= 0], yg[:, w:][cols >= 0])
            return Vi
        g[:n_e] -= (cs.sum_by_image @ np.einsum("oki,ok->oi", Y_t, ch.g_p[cs.ptl])).ravel()
        if n_d:
            subtract_image_couplings(Y_t, ch.W_pd, cs.img, cs.ptl, sums["S_ed"], NO_SLOTS, w)
            sums["S_dd"] -= _point_schur(Vi, ch.W_pd)
            g[n_e:n_e + n_d] -= ch.W_pd.T @ np.einsum("pij,pj->pi", Vi, ch.g_p).ravel()
        return Vi

    v_inv, parts = over_chunks(list(zip(chunks, structure.chunks)), work, new_sums)
    ia, ib = structure.image_pair_a, structure.image_pair_b
    if working is not None:
        maps = image_maps(problem, working)
        diag_blocks += maps.blocks_to_parameters(symmetrised(sum(part["diag"] for part in parts)))
        off_blocks += maps.pairs_to_parameters(sum(part["off"] for part in parts), ia, ib)
        g[:n_e] += maps.vectors_to_parameters(sum(part["g_w"] for part in parts).reshape(n_img, -1)).ravel()
        S_ed += maps.rows_to_parameters(sum(part["S_ed"] for part in parts))
    for part in parts:
        g += part["g"]
        S_dd += part["S_dd"]
        if working is not None:
            continue
        S_ed += part["S_ed"]
        if compact:
            wide_diag += part["diag"]
            wide_off += part["off"]
        else:
            diag_blocks += part["diag"]
            off_blocks += part["off"]
    if compact:
        diag_blocks += wide_diag[:, :w, :w]
        off_blocks += wide_off[:, :w, :w]
        _spread_camera_blocks(wide_diag, wide_off, own, ia, ib, w, S_ed, S_dd)

    return v_inv


def assemble(problem: Problem, lin: Linearisation, sums: ReducedSums, lam: float, dense: bool):
    """The reduced normal matrix from its sums over the points (``sums``, the linearisation's U included), with
    the observations of theta alone and the damping ``lam``; dense or sparse (csc)."""
    n_img, n_e, n_d, n_t = problem.n_images, problem.n_e, problem.n_d, problem.n_theta
    w = problem.image_width
    S_ed, S_dd, diag_blocks, off_blocks = sums.S_ed, sums.S_dd, sums.diag, sums.off
    ia, ib = (sums.pair_keys // n_img, sums.pair_keys % n_img) if n_img else (sums.pair_keys, sums.pair_keys)
    damp = lam * lin.diag_theta
    S: np.ndarray | sp.csc_matrix
    if dense:
        S = np.zeros((n_t, n_t))
        S_ee = np.zeros((n_img, n_img, w, w))
        S_ee[np.arange(n_img), np.arange(n_img)] = diag_blocks
        S_ee[ia, ib] = off_blocks
        S_ee[ib, ia] = off_blocks.transpose(0, 2, 1)
        S[:n_e, :n_e] = S_ee.transpose(0, 2, 1, 3).reshape(n_e, n_e)
        S[:n_e, n_e:n_e + n_d] = S_ed
        S[n_e:n_e + n_d, :n_e] = S_ed.T
        S[n_e:n_e + n_d, n_e:n_e + n_d] = S_dd
        if lin.J_x.shape[0]:
            S += (lin.J_x.T @ lin.J_x).toarray()
        S[np.diag_indices(n_t)] += damp
        S = 0.5 * (S + S.T)
    else:
        J_x = (lin.J_x.T @ lin.J_x).tocoo() if lin.J_x.shape[0] else None
        if J_x is not None:
            J_x.sum_duplicates()                    # (each entry once, in a fixed order: the pattern is kept)
        pattern = _SparsePattern.of(problem, sums.pair_keys, J_x)
        # every entry as the sum of sparse matrices computes it: (blocks + J_x^T J_x) + damping, then made symmetric
        # as (S + S^T) / 2 with the sums that come out exactly zero left out
        a = np.zeros(len(pattern.indices))
        a[pattern.at_blocks] = diag_blocks.ravel()
        a[pattern.at_pairs] = off_blocks.ravel()
        a[pattern.at_pairs_transposed] = off_blocks.ravel()
        a[pattern.at_S_ed] = S_ed.ravel()
        a[pattern.at_S_ed_transposed] = S_ed.ravel()
        a[pattern.at_S_dd] = S_dd.ravel()
        if J_x is not None:
            a[pattern.at_J_x] += J_x.data
        a[pattern.at_diagonal] += damp
        data = a[pattern.transposed]
        data += a
        data *= 0.5
        del a
        kept = data != 0.0
        if kept.all():
            S = sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=(n_t, n_t))
        else:                                       # (every column holds its diagonal entry: none is empty)
            counts = np.add.reduceat(kept.astype(np.int64), pattern.indptr[:-1])
            indptr = np.concatenate([[0], np.cumsum(counts)]).astype(pattern.indptr.dtype)
            S = sp.csc_matrix((data[kept], pattern.indices[kept], indptr), shape=(n_t, n_t))
        S.has_sorted_indices = True
    return S


@dataclass
class _SparsePattern:
    """Where the parts of the reduced matrix go in its compressed columns (the union of the image blocks' pattern,
    the camera parameters' rows and columns, the observations of theta alone and the diagonal), worked out once for
    a problem's pairs of images and kept on the problem (:func:`assemble`: each iteration only fills the values).
    The values are those the sum of sparse matrices gave: the same pattern, the same roundings."""

    pair_keys: np.ndarray
    J_x_keys: np.ndarray | None
    indptr: np.ndarray
    indices: np.ndarray
    transposed: np.ndarray              # each entry's position of its transpose
    at_blocks: np.ndarray               # positions of the image blocks' entries, (n_images, w, w) raveled
    at_pairs: np.ndarray                # of the pairs' blocks (ia rows, ib columns)
    at_pairs_transposed: np.ndarray     # of their transposes (ib rows, ia columns), in the pairs' raveled order
    at_S_ed: np.ndarray
    at_S_ed_transposed: np.ndarray
    at_S_dd: np.ndarray
    at_J_x: np.ndarray
    at_diagonal: np.ndarray

    @classmethod
    def of(cls, problem: Problem, pair_keys: np.ndarray, J_x) -> "_SparsePattern":
        J_x_keys = None if J_x is None else J_x.col.astype(np.int64) * problem.n_theta + J_x.row
        kept = problem.sparse_pattern
        if (kept is not None and np.array_equal(kept.pair_keys, pair_keys)
                and (J_x_keys is None) == (kept.J_x_keys is None)
                and (J_x_keys is None or np.array_equal(kept.J_x_keys, J_x_keys))):
            return kept
        problem.sparse_pattern = pattern = cls._build(problem, pair_keys, J_x_keys)
        return pattern

    @classmethod
    def _build(cls, problem: Problem, pair_keys: np.ndarray, J_x_keys: np.ndarray | None) -> "_SparsePattern":
        n_img, n_e, n_d, n_t, w = problem.n_images, problem.n_e, problem.n_d, problem.n_theta, problem.image_width
        ia, ib = (pair_keys // n_img, pair_keys % n_img) if n_img else (pair_keys, pair_keys)
        inner = np.arange(w)

        def block_entries(a, b):                    # (rows, columns) of blocks (a rows, b columns), raveled
            rows = w * a[:, None, None] + inner[None, :, None]
            cols = w * b[:, None, None] + inner[None, None, :]
            return np.broadcast_to(rows, (len(a), w, w)).ravel(), np.broadcast_to(cols, (len(a), w, w)).ravel()
        e, d = np.arange(n_e), n_e + np.arange(n_d)
        images = np.arange(n_img)
        pair_rows, pair_cols = block_entries(ia, ib)
        # the parts in the order of __init__'s positions; the pairs' transposes in the pairs' raveled order (entry
        # (i, j) of pair p at row w ib + j, column w ia + i); S_ed and its transpose in S_ed's raveled order
        parts = [block_entries(images, images), (pair_rows, pair_cols), (pair_cols, pair_rows),
                 (np.repeat(e, n_d), np.tile(d, n_e)), (np.tile(d, n_e), np.repeat(e, n_d)),
                 (np.repeat(d, n_d), np.tile(d, n_d))]
        diagonal = np.arange(n_t, dtype=np.int64)
        parts.append((diagonal, diagonal))
        if J_x_keys is not None:
            parts.append((J_x_keys % n_t, J_x_keys // n_t))
        rows = np.concatenate([r for r, _ in parts]).astype(np.int64)
        cols = np.concatenate([c for _, c in parts]).astype(np.int64)
        indptr, indices, position = compressed_columns(rows, cols, n_t)
        bounds = np.cumsum([0] + [len(r) for r, _ in parts])
        where = [position[bounds[k]:bounds[k + 1]] for k in range(len(parts))]
        index = np.int32 if max(len(indices), n_t) < 2 ** 31 - 1 else np.int64    # (4 bytes an entry where they do)
        transposed = transposed_positions(indptr, indices)
        assert np.all(transposed >= 0)              # (every part's pattern is symmetric)
        where = [w_.astype(index) for w_ in where]
        return cls(pair_keys, J_x_keys, indptr.astype(index), indices.astype(index), transposed.astype(index),
                   at_blocks=where[0], at_pairs=where[1], at_pairs_transposed=where[2], at_S_ed=where[3],
                   at_S_ed_transposed=where[4], at_S_dd=where[5], at_diagonal=where[6],
                   at_J_x=where[7] if J_x_keys is not None else np.zeros(0, index))


def _spread_camera_blocks(wide_diag, wide_off, own, ia, ib, w, S_ed, S_dd) -> None:
    """Add the camera rows and columns of the per-image blocks (image then camera columns, ``own``: each
    image's camera columns, -1 pads) to S_ed and S_dd: each image's own block, and each pair of images
    (ia, ib) sharing a point with its transpose. Several images may share a camera: np.add.at sums them."""
    rows = w * np.arange(len(own))[:, None] + np.arange(w)[None, :]            # (n_images, w) image rows

    def add(image_rows, cams_a, cams_b, e_part, d_part):
        keep = cams_b >= 0
        r = np.broadcast_to(image_rows[:, :, None], e_part.shape)
        c = np.broadcast_to(cams_b[:, None, :], e_part.shape)
        mask = np.broadcast_to(keep[:, None, :], e_part.shape)
        np.add.at(S_ed, (r[mask], c[mask]), e_part[mask])
        both = (cams_a >= 0)[:, :, None] & keep[:, None, :]
        ra = np.broadcast_to(cams_a[:, :, None], d_part.shape)
        cb = np.broadcast_to(cams_b[:, None, :], d_part.shape)
        np.add.at(S_dd, (ra[both], cb[both]), d_part[both])
    add(rows, own, own, wide_diag[:, :w, w:], wide_diag[:, w:, w:])
    if len(ia):
        add(rows[ia], own[ia], own[ib], wide_off[:, :w, w:], wide_off[:, w:, w:])
        add(rows[ib], own[ib], own[ia], wide_off[:, w:, :w].transpose(0, 2, 1), wide_off[:, w:, w:].transpose(0, 2, 1))


def back_substitute(problem: Problem, lin: Linearisation, v_inv: list, d_theta: np.ndarray) -> np.ndarray:
    """Point corrections d_p = V^-1 (g_p - W^T d_theta), shape (n_points, 3)."""
    n_e, n_d = problem.n_e, problem.n_d
    d_e = d_theta[:n_e].reshape(-1, problem.image_width)
    working = working_columns(problem)
    if working is not None:                      # the corrections in the working columns of w_e (:mod:`.working`)
        d_e = image_maps(problem, working).vectors_to_working(d_e)
    d_d = d_theta[n_e:n_e + n_d]
    d_p = np.zeros((problem.n_points, 3))
    columns = problem.camera_columns()             # (n_cameras, 0) without camera parameters (n_d 0)

    def work(chunk, _) -> None:                 # each chunk writes its own points
        ch, Vi = chunk
        img = problem.obs_image[ch.o0:ch.o1]
        starts = problem.point_start[ch.p0:ch.p1] - ch.o0
        d_img = d_e[img] if ch.columns is None else d_e[img[:, None], ch.columns]
        wt = np.add.reduceat(np.einsum("oik,oi->ok", ch.w_e, d_img), starts, axis=0)
        if n_d and ch.w_d is not None:
            d_own = np.append(d_d, 0.0)[columns[problem.image_camera[img]]]   # -1 pads: 0
            wt += np.add.reduceat(np.einsum("okc,oc->ok", ch.w_d, d_own), starts, axis=0)
        elif n_d:
            wt += (ch.W_pd @ d_d).reshape(-1, 3)
        d_p[ch.points] = np.einsum("pij,pj->pi", Vi, ch.g_p - wt)
    over_chunks(list(zip(lin.chunks, v_inv)), work, lambda: None)
    return d_p


def evaluate_cost(problem: Problem, state: State) -> float:
    """0.5 v^T P v of all observation groups at ``state``."""
    return cost_and_residuals(problem, state)[0]


def cost_and_residuals(problem: Problem, state: State) -> tuple[float, np.ndarray]:
    """:func:`evaluate_cost` and the image residuals l - f it sums (observation units, sorted order, (n, 2)): a
    robust reweighting at an accepted step reads them instead of evaluating them again."""
    cost, residuals = points_cost_and_residuals(problem, state)
    return cost + parameter_cost(problem, state), residuals


def points_cost_and_residuals(problem: Problem, state: State) -> tuple[float, np.ndarray]:
    """The cost's part of the image observations and the observations of points (a sum over the points, as in
    :func:`linearise_points`), and the image residuals."""
    residuals = image_residuals(problem, state)
    v = residuals / problem.obs_sigma
    cost = 0.5 * float(np.sum(v * v))
    return cost + sum(block.cost(state.points) for block in problem.point_residuals), residuals


def parameter_cost(problem: Problem, state: State) -> float:
    """The cost's part of the observations of theta alone."""
    _, r_x = parameter_observations(problem, state)
    return 0.5 * float(np.sum(r_x * r_x))

