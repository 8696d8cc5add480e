"""Held-out folds of tie points in a linearised adjustment: what the adjustment without them predicts for their rays.

Cross-validation of a self-calibrating adjustment (:mod:`selfcal.stats.prediction`) holds out a fold of tie points
with all their rays, adjusts the rest, intersects the held-out points again from their own rays with the fold's
orientations and camera, and measures the rays' residuals. In the adjustment linearised at a state this needs no
re-adjustment. With a point's whitened rows J_θ (its observations' image and camera columns), J_p (its own three
unknowns), V = J_pᵀJ_p and the projection off the point P = I − J_p V⁻¹ J_pᵀ,

    C_j = Ã_jᵀÃ_j,   b_j = Ã_jᵀ r̃_j,   c_j = r̃_jᵀ r̃_j,      Ã_j = P J_θ,  r̃_j = P r_j

are the point's part of the reduced normal matrix S, of its right-hand side g and of the cost (the point
eliminated). The fold's adjustment is the solution of (S − C_f) δ = g − b_f, C_f = Σ_{j∈f} C_j (one Gauss-Newton
step from the state: exact for the linear model, and for a converged state within the curvature of the last
correction). Its held-out points, intersected again with δ_f, leave the residuals Ã_f δ_f − r̃_f, whose squared
sum is c_f − 2 δ_fᵀ b_f + δ_fᵀ C_f δ_f: no row needs to be kept, and any subset of the parameters (screening's
held ones, moved to their held values) is one more dense solve per fold.

The fold systems are dense (n_θ² per fold), so they are built for reduced systems up to :data:`FOLD_LIMIT`
unknowns. Control points are never held out (the control fixes the datum of every fold); the rays of check points
are, as those of tie points (a check point is a tie point of the adjustment): the prediction uses rays alone, never
a check point's surveyed coordinates, which stay independent of every choice made by it.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import scipy.linalg as la

from .linalg import DEFECT_TOLERANCE
from .problem import Problem, State
from .ap_columns import sparse_ap_rows, sparse_gram
from .kernels import (NO_SLOTS, accumulate_observations, camera_couplings, point_blocks_times, schur_image_blocks,
                      subtract_image_couplings)
from .residuals.image import chunk_rows, contexts, point_rays
from .schur import back_substitute, linearise, reduce

__all__ = ["FoldSystems", "fold_systems", "point_folds", "projected_rows", "FOLD_LIMIT"]

#: fold systems are built for reduced systems up to this many orientation and camera unknowns (each fold keeps a
#: dense n x n part: 10 folds of 2000 unknowns hold 320 MB)
FOLD_LIMIT = 2000


def point_folds(point_ids: np.ndarray, roles: np.ndarray, n_folds: int) -> np.ndarray:
    """The fold (0 .. n_folds - 1) of each point whose rays alone determine it (tie and check points: a check
    point's surveyed coordinates are not observations of the adjustment), -1 for control points: by a hash of the
    point's id, so that every candidate model and every subset of the block holds out the same points together."""
    folds = np.array([zlib.crc32(str(p).encode()) % n_folds for p in point_ids], dtype=np.int64)
    folds[np.asarray(roles) == "gcp"] = -1
    return folds


@dataclass
class FoldSystems:
    """The reduced normal equations of a linearised adjustment and each fold's part of them (module docstring)."""

    S: np.ndarray               # (n, n) reduced normal matrix at the state (all observations)
    g: np.ndarray               # (n,) its right-hand side
    C: np.ndarray               # (k, n, n) each fold's points' part of S
    b: np.ndarray               # (k, n) ... of g
    c: np.ndarray               # (k,) their reduced cost r̃ᵀr̃ at the state
    dof: np.ndarray             # (k,) their rays' degrees of freedom, sum of 2 m - 3 over the fold's points
    n_rays: np.ndarray          # (k,) their image observations
    omega: float                # v^T P v of the whole linearised adjustment at its own solution
    free_network: bool          # S has a datum defect: minimum-norm solutions
    stepped: State              # the state moved by the whole adjustment's solution (points back-substituted)

    @property
    def n_folds(self) -> int:
        return len(self.c)

    def solve(self, fold: int | None, hold: np.ndarray | None = None, move: np.ndarray | None = None) -> np.ndarray:
        """The correction of θ from the state by the adjustment without fold ``fold`` (None: with every fold),
        the parameters ``hold`` moved by ``move`` (their held values less the state's) and the others adjusted."""
        S = self.S if fold is None else self.S - self.C[fold]
        g = self.g if fold is None else self.g - self.b[fold]
        delta = np.zeros(len(g))
        if hold is not None and len(hold):
            delta[hold] = move
            g = g - S[:, hold] @ move
            rest = np.setdiff1d(np.arange(len(g)), hold)
            delta[rest] = _solve(S[np.ix_(rest, rest)], g[rest], self.free_network)
            return delta
        return _solve(S, g, self.free_network)

    def held_out_cost(self, fold: int, delta: np.ndarray) -> float:
        """The squared sum of the whitened residuals of fold ``fold``'s rays, its points intersected again, after
        the correction ``delta`` of θ."""
        return float(self.c[fold] - 2.0 * delta @ self.b[fold] + delta @ self.C[fold] @ delta)


def _solve(S: np.ndarray, g: np.ndarray, free_network: bool) -> np.ndarray:
    """S x = g: Cholesky of the Jacobi-scaled S; a free network's minimum-norm solution (the datum defect's
    eigenvalues left out)."""
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    Ss = S / d[:, None] / d[None, :]
    if not free_network:
        try:
            return la.cho_solve(la.cho_factor(Ss, lower=True, check_finite=False), g / d, check_finite=False) / d
        except la.LinAlgError:
            pass
    w, V = np.linalg.eigh(Ss)
    keep = w > DEFECT_TOLERANCE * w.max()
    return V[:, keep] @ ((V[:, keep].T @ (g / d)) / w[keep]) / d


def fold_systems(problem: Problem, state: State, folds: np.ndarray, n_folds: int,
                 free_network: bool = False, converged: tuple[np.ndarray, float] | None = None) -> FoldSystems:
    """The reduced normal equations of ``problem`` linearised at ``state`` and each fold's part of them.

    ``folds``: the fold of each of the block's points (:func:`point_folds`; -1: never held out). Points with fewer
    than two rays in the problem are never held out either. ``converged``: (S, Omega) of an adjustment converged at
    ``state`` (its reduced matrix and v^T P v; the right-hand side is then zero and the state its own solution), which
    saves a linearisation. Raises ValueError beyond :data:`FOLD_LIMIT` unknowns.
    """
    n = problem.n_theta
    if n > FOLD_LIMIT:
        raise ValueError(f"fold systems are built for up to {FOLD_LIMIT} orientation and camera unknowns, "
                         f"this adjustment has {n}")
    if converged is None:
        lin = linearise(problem, state)
        S, g, v_inv = reduce(problem, lin, 0.0, dense=True)
        S = np.asarray(S)
        eliminated = sum(float(np.einsum("pi,pij,pj->", ch.g_p, Vi, ch.g_p)) for ch, Vi in zip(lin.chunks, v_inv))
        step = _solve(S, g, free_network)
        stepped = problem.apply(state, step, back_substitute(problem, lin, v_inv, step))
        omega = 2.0 * lin.cost - eliminated - float(g @ step)
    else:
        (S, omega), g, stepped = converged, np.zeros(n), state
    counts = np.diff(problem.point_start)
    fold_at = np.where(counts >= 2, np.asarray(folds)[problem.point_order], -1)    # by position in the problem
    parts = [_FoldPart(problem) for _ in range(n_folds)]
    context = contexts(problem, state)
    sparse = sparse_ap_rows(problem)
    n_core = problem.cameras[0].n_core if sparse is not None else 0
    for cs in problem.structure().chunks:
        fold_of_obs = fold_at[cs.p0 + cs.ptl]
        held = fold_of_obs >= 0
        if not held.any():
            continue
        r, j_e, j_p, j_d, _ = chunk_rows(problem, state, cs, context)
        pair_fold = fold_of_obs[cs.pair_a]
        for f in np.unique(fold_of_obs[held]):
            o = np.flatnonzero(fold_of_obs == f)
            local = np.full(len(fold_of_obs), -1)
            local[o] = np.arange(len(o))
            pairs = pair_fold == f
            gram = None
            if sparse is not None:
                gram = (sparse.to_params.T @ sparse_gram(sparse, 0, 0, rows=cs.o0 + o) @ sparse.to_params, n_core)
            parts[f].add(r[o], j_e[o], np.ascontiguousarray(j_p[o]), np.ascontiguousarray(j_d[o]), cs.img[o],
                         cs.ptl[o], local[cs.pair_a[pairs]], local[cs.pair_b[pairs]], cs.pair_key[pairs], gram)
    C = np.empty((n_folds, n, n))           # (each fold's matrix written in place: the folds' n_θ² numbers once)
    for f, part in enumerate(parts):
        part.matrix(out=C[f])
    b = np.stack([part.g for part in parts])
    c = np.array([part.cost for part in parts])
    at_fold = [np.flatnonzero(fold_at == f) for f in range(n_folds)]
    dof = np.array([float(np.sum(2 * counts[at] - 3)) for at in at_fold])
    n_rays = np.array([int(counts[at].sum()) for at in at_fold])
    return FoldSystems(S, g, C, b, c, dof, n_rays, omega, free_network, stepped)


class _FoldPart:
    """One fold's part of the reduced normal equations, summed over its points as :func:`selfcal.adjust.schur.linearise`
    and :func:`~selfcal.adjust.schur.reduce` sum every point (with their kernels): the Gram blocks of its rays' rows,
    less W V^-1 W^T of its points; the right-hand side and the cost likewise."""

    def __init__(self, problem: Problem):
        n_img, width, n_d = problem.n_images, problem.image_width, problem.n_d
        self.n, self.n_e, self.n_d, self.width = problem.n_theta, problem.n_e, n_d, width
        self.pair_a, self.pair_b = problem.structure().image_pair_a, problem.structure().image_pair_b
        self.diag = np.zeros((n_img, width, width))
        self.off = np.zeros((len(self.pair_a), width, width))
        self.S_ed = np.zeros((problem.n_e, n_d))
        self.S_dd = np.zeros((n_d, n_d))
        self.g_e = np.zeros((n_img, width))
        self.g_d = np.zeros(n_d)
        self.cost = 0.0

    def add(self, r, j_e, j_p, j_d, img, point, pair_a, pair_b, pair_key, gram) -> None:
        """The rays of some of the fold's points (``point``: their point's position, grouped by point), their pairs
        of rays of the same point (indices into these rays, the image pair's key in the block structure), and the
        Gram matrix of their camera rows where it is known from sparse AP rows (gram, the columns from which on it
        covers) or None."""
        m, n_d = len(r), self.n_d
        new = np.r_[True, point[1:] != point[:-1]]
        ptl = np.cumsum(new) - 1
        n_p = int(ptl[-1]) + 1
        V, g_p, w_e = accumulate_observations(j_e, j_p, r, img, ptl, self.diag, self.g_e, n_p, NO_SLOTS)
        Vi = np.linalg.inv(V)
        self.cost += float(np.sum(r * r) - np.einsum("pi,pij,pj->", g_p, Vi, g_p))
        Y_t = schur_image_blocks(Vi, ptl, np.ascontiguousarray(w_e.transpose(0, 2, 1)), img, pair_a, pair_b,
                                 pair_key, self.diag, self.off, NO_SLOTS)   # V^-1 W^T per ray, (m, 3, width)
        np.subtract.at(self.g_e, img, np.einsum("oki,ok->oi", Y_t, g_p[ptl]))
        if not n_d:
            return
        W_pd = np.zeros((3 * n_p, n_d))
        if gram is None:
            rows = j_d.reshape(2 * m, n_d)
            self.S_dd += rows.T @ rows
            varying = np.zeros(0, np.int64)
        else:
            self.S_dd[gram[1]:, gram[1]:] += gram[0]
            varying = np.arange(gram[1])
        U_vd = np.zeros((len(varying), n_d))
        camera_couplings(j_d, j_e, j_p, r, img, ptl, varying, self.S_ed, W_pd, self.g_d, U_vd, NO_SLOTS, self.width)
        self.S_dd[varying, :] += U_vd
        self.S_dd[gram[1] if gram else 0:, varying] += U_vd[:, gram[1] if gram else 0:].T
        subtract_image_couplings(Y_t, W_pd, img, ptl, self.S_ed, NO_SLOTS, self.width)
        self.S_dd -= W_pd.T @ point_blocks_times(Vi, W_pd, False)
        self.g_d -= W_pd.T @ np.einsum("pij,pj->pi", Vi, g_p).ravel()

    def matrix(self, out: np.ndarray | None = None) -> np.ndarray:
        """The fold's part of the reduced matrix, dense (n_θ x n_θ), written into ``out`` where given."""
        n_img, w = self.diag.shape[:2]
        n_e, n_d = self.n_e, self.n_d
        C = np.zeros((self.n, self.n)) if out is None else out
        C[...] = 0.0
        blocks = np.zeros((n_img, n_img, w, w))
        blocks[np.arange(n_img), np.arange(n_img)] = self.diag
        blocks[self.pair_a, self.pair_b] = self.off
        blocks[self.pair_b, self.pair_a] = self.off.transpose(0, 2, 1)
        C[:n_e, :n_e] = blocks.transpose(0, 2, 1, 3).reshape(n_e, n_e)
        C[:n_e, n_e:n_e + n_d] = self.S_ed
        C[n_e:n_e + n_d, :n_e] = self.S_ed.T
        C[n_e:n_e + n_d, n_e:n_e + n_d] = self.S_dd
        C += C.T
        C *= 0.5
        return C

    @property
    def g(self) -> np.ndarray:
        out = np.zeros(self.n)
        out[:self.n_e] = self.g_e.ravel()
        out[self.n_e:self.n_e + self.n_d] = self.g_d
        return out


def projected_rows(problem: Problem, state: State, positions: np.ndarray):
    """The rows Ã = P J_θ (2 m, n_θ) of every ray of the points at ``positions`` (of the problem's order; each with
    two rays or more), whitened and projected off their points' own unknowns, x and y of each ray in turn; the rays
    (observation indices in problem order); the points' response R = -V^-1 W (3 points, n_θ: R δθ is how the points
    follow a change δθ, m); and each point's metres per whitened unit of a ray across it (1 / the largest singular
    value of its rays' point Jacobians, the median over its rays). Ã δθ is the change of the rays' adjusted
    coordinates when θ moves by δθ and the points follow (whitened units)."""
    positions = np.sort(np.asarray(positions, np.int64))
    rays = point_rays(problem, state, positions)
    o, counts, starts, owner, J, j_p, V, W = (rays.o, rays.counts, rays.starts, rays.owner, rays.J, rays.j_p,
                                              rays.V, rays.W)
    m, n = len(o), problem.n_theta
    response = np.linalg.inv(V) @ W                                    # (points, 3, n)
    A = J - np.einsum("oki,oit->okt", j_p, response[owner])
    across = np.linalg.svd(j_p, compute_uv=False)[:, 0]                # whitened units per metre, per ray
    scale = np.array([np.median(1.0 / across[s:s + c]) for s, c in zip(starts, counts)])
    return A.reshape(2 * m, n), o, -response.reshape(3 * len(positions), n), scale
