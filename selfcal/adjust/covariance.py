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

from dataclasses import dataclass

import numpy as np

from .linalg import shared_product
from .parallel import over_chunks
from .schur import Linearisation
from .problem import Problem
from .kernels import NO_SLOTS, add_point_image_products, point_blocks_times, point_cofactor_pairs
from .working import image_maps, working_columns

__all__ = ["point_cofactors", "some_point_cofactors", "PointCofactors", "PointTerms", "ThetaBlocks", "theta_blocks",
           "image_blocks", "observation_columns", "lower_cholesky",
           "times_lower", "block_grams"]


def image_blocks(Q, problem: Problem, columns: np.ndarray | None = None,
                 pair_keys: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Q_theta's image blocks: (n_images, w, w) of each image, and (n_pairs, w, w) of each pair of
    images that share a point (``problem.structure().pair_keys``, or ``pair_keys`` (ia * n_images + ib):
    Q(ia, ib)). ``columns`` (n_images, w): each image's columns of theta (-1: none, its rows and columns of the
    blocks are zero); by default its own image parameters. ``Q`` is a dense ndarray or a
    BandedCofactor: both take NumPy's fancy indexing."""
    if columns is None:
        columns = problem.image_theta()
    if pair_keys is None:
        pair_keys = problem.structure().pair_keys
    n_img = problem.n_images
    pair_a, pair_b = pair_keys // max(n_img, 1), pair_keys % max(n_img, 1)
    valid = columns >= 0
    safe = np.where(valid, columns, 0)

    def blocks(a, b):
        out = Q[safe[a][:, :, None], safe[b][:, None, :]]
        return np.ascontiguousarray(out * (valid[a][:, :, None] & valid[b][:, None, :]))
    Q_diag = blocks(np.arange(problem.n_images), np.arange(problem.n_images))
    w = columns.shape[1]
    Q_pair = blocks(pair_a, pair_b) if len(pair_keys) else np.zeros((0, w, w))
    return Q_diag, Q_pair


def observation_columns(problem: Problem) -> np.ndarray:
    """Each image's columns of theta that its observations touch when the cameras are compact: its own
    parameters, then its camera's (-1 pads a narrower camera), (n_images, width + camera width)."""
    cameras = problem.camera_columns()[problem.image_camera]
    return np.concatenate([problem.image_theta(), np.where(cameras >= 0, problem.n_e + cameras, -1)], axis=1)


@dataclass
class ThetaBlocks:
    """What the object points' passes read of Q_theta (module docstring): the image blocks (:func:`image_blocks`,
    of the pairs of images that a set of points joins) and, with camera parameters that are not compact, the
    camera parameters' block and their columns in the image rows. A share of the points on a Dask cluster gets
    these instead of Q_theta (:mod:`selfcal.adjust.distributed`)."""

    compact: bool                # compact cameras: the image blocks hold each image's camera columns too
    Q_diag: np.ndarray           # (n_images, w, w)
    Q_pair: np.ndarray           # (n_pairs, w, w), in the order of the pair keys asked for
    Q_dd: np.ndarray | None      # (n_d, n_d)
    Q_ed: np.ndarray | None      # (n_e, n_d)


def theta_blocks(Q, problem: Problem, pair_keys: np.ndarray | None = None) -> ThetaBlocks:
    """The :class:`ThetaBlocks` of Q_theta (a dense ndarray or a BandedCofactor) for the pairs of images
    ``pair_keys`` (ia * n_images + ib; by default the problem's own)."""
    n_e, n_d = problem.n_e, problem.n_d
    compact = bool(n_d) and problem.compact_cameras
    Q_diag, Q_pair = image_blocks(Q, problem, observation_columns(problem) if compact else None, pair_keys)
    Q_dd = Q_ed = None
    if n_d and not compact:
        Q_dd = np.asarray(Q[n_e:n_e + n_d, n_e:n_e + n_d])
        Q_ed = np.ascontiguousarray(Q[:n_e, n_e:n_e + n_d])
    return ThetaBlocks(compact, Q_diag, Q_pair, Q_dd, Q_ed)


@dataclass
class PointTerms:
    """A chunk's products that the point cofactors and the leverages (:mod:`selfcal.stats.reliability`) share."""

    Z_e: np.ndarray              # (m, w, 3) each observation's image (and compact camera) coupling times V^-1
    Z: np.ndarray | None         # (3 n_pc, n_d) V^-1 W_pd per point, None without camera parameters
    A: np.ndarray | None         # (3 n_pc, n_d) per point: sum over its observations of Z_e^T Q_ed(image)
    ZL: list | None              # Z L_dd (Q_dd = L_dd L_dd^T) in column blocks (times_lower), or None and:
    H: np.ndarray | None         # (3 n_pc, n_d) A + Z Q_dd, without that factor or when asked for (``full_product``)
    Q_pp: np.ndarray             # (n_pc, 3, 3) the points' cofactor blocks


class PointCofactors:
    """The parts of Q_theta that the object points need (module docstring), read once, and per chunk of
    points their cofactor blocks with the products they are made of (:class:`PointTerms`)."""

    def __init__(self, problem: Problem, Q, full_product: bool = False):
        """``Q``: Q_theta (a dense ndarray or a BandedCofactor), or its :class:`ThetaBlocks` for the problem's
        pairs of images."""
        n_d = problem.n_d
        self.problem = problem
        # compact cameras (BAL: one camera of 3 parameters per image): an observation touches its image's and its
        # camera's columns only, so both are one block per image, summed over the pairs of each point's
        # observations like the image parameters alone (no dense point x camera coupling, no Q_dd products)
        parts = Q if isinstance(Q, ThetaBlocks) else theta_blocks(Q, problem)
        self.compact = parts.compact
        self.Q_diag, self.Q_pair = parts.Q_diag, parts.Q_pair
        # image rows in working columns (:mod:`.working`): the image blocks of Q_theta as T Q T^T
        self.working = working_columns(problem)
        maps = None
        if self.working is not None:
            maps = image_maps(problem, self.working)
            structure = problem.structure()
            self.Q_diag = maps.blocks_to_working(self.Q_diag)
            self.Q_pair = maps.pairs_to_working(self.Q_pair, structure.image_pair_a, structure.image_pair_b)
        self.rows_width = problem.image_width if self.working is None else self.working.width
        self.Q_dd = self.Q_ed = self.L_dd = None
        if n_d and not self.compact:
            Q_dd, Q_ed = parts.Q_dd, parts.Q_ed                               # (n_d, n_d), (n_e, n_d)
            assert Q_dd is not None and Q_ed is not None                      # (theta_blocks keeps them here)
            if maps is not None:                                               # (n_images * working, n_d)
                Q_ed = maps.rows_to_working(Q_ed.reshape(problem.n_images, problem.image_width, n_d)).reshape(-1, n_d)
            self.Q_dd, self.Q_ed = Q_dd, Q_ed
            # Q_dd = L L^T: the products with Q_dd are triangular ones, unless the caller needs A + Z Q_dd itself
            self.L_dd = None if full_product else lower_cholesky(Q_dd)

    def chunk(self, ch, cs, Vi: np.ndarray) -> PointTerms:
        n_d = self.problem.n_d
        n_pc = ch.p1 - ch.p0
        Z_e = (ch.couplings() if self.compact else ch.w_e) @ Vi[cs.ptl]                                             # (m, w, 3)
        Qp = Vi.copy()
        slots = NO_SLOTS if self.compact else ch.slots
        point_cofactor_pairs(Z_e, cs.img, cs.ptl, cs.pair_a, cs.pair_b, cs.pair_key, self.Q_diag, self.Q_pair, Qp,
                             slots)
        Z = A = ZL = H = None
        if n_d and not self.compact:
            Z = point_blocks_times(Vi, ch.W_pd, False)                     # Z[p] = Vi[p] W_pd[p]
            A = np.zeros((3 * n_pc, n_d))
            add_point_image_products(Z_e, cs.img, cs.ptl, self.Q_ed, A, slots, self.rows_width)
            # per point Z Q_dd Z^T + A Z^T + Z A^T, made symmetric below: the blocks (Z Q_dd + 2 A) Z^T, one
            # product per point
            if self.L_dd is None:
                H = Z @ self.Q_dd
                H += A
                Qp += _block_products(H + A, Z, n_pc)
            else:
                ZL = times_lower(Z, self.L_dd)
                Qp += block_grams(ZL, n_pc) + _block_products(2.0 * A, Z, n_pc)
        return PointTerms(Z_e, Z, A, ZL, H, 0.5 * (Qp + Qp.transpose(0, 2, 1)))


def point_cofactors(problem: Problem, lin: Linearisation, v_inv: list, Q) -> np.ndarray:
    """Cofactor blocks Q_pp of all points, shape (n_points, 3, 3); ``Q``: Q_theta (see module docstring)."""
    parts = PointCofactors(problem, Q)
    out = np.zeros((problem.n_points, 3, 3))

    def work(chunk, _) -> None:
        ch, cs, Vi = chunk
        out[ch.points] = parts.chunk(ch, cs, Vi).Q_pp
    over_chunks(list(zip(lin.chunks, problem.structure().chunks, v_inv)), work, lambda: None)
    return out


def some_point_cofactors(problem: Problem, lin: Linearisation, v_inv: list, Q, points: np.ndarray) -> np.ndarray:
    """The cofactor blocks (len(points), 3, 3) of the block's points ``points`` alone: the chunks that hold them
    (:func:`point_cofactors` passes over all)."""
    parts = PointCofactors(problem, Q)
    points = np.asarray(points, np.int64)
    out = np.full((len(points), 3, 3), np.nan)
    for ch, cs, Vi in zip(lin.chunks, problem.structure().chunks, v_inv):
        hit = np.flatnonzero(np.isin(points, ch.points))
        if hit.size:
            blocks = parts.chunk(ch, cs, Vi).Q_pp
            where = {int(p): k for k, p in enumerate(ch.points)}
            out[hit] = blocks[[where[int(points[k])] for k in hit]]
    return out


def lower_cholesky(Q: np.ndarray) -> np.ndarray | None:
    """L with Q = L L^T, or None if Q is not numerically positive definite."""
    try:
        return np.linalg.cholesky(Q)
    except np.linalg.LinAlgError:
        return None


def times_lower(X: np.ndarray, L: np.ndarray) -> list[np.ndarray]:
    """X L for a lower triangular L, as LOWER_BLOCKS column blocks X L[:, c0:c1] (C-ordered; side by side they
    are X L). Block j needs only X's columns from c0 on (L is zero above its diagonal), so four blocks cost 5/8
    of a general product's flops, in NumPy products, which release the interpreter lock: the two threads of a
    pass over the chunks (:mod:`.parallel`) run theirs side by side. SciPy's triangular product (dtrmm, half
    the flops) holds the lock, and two threads calling it ran one after the other."""
    k = L.shape[0]
    bounds = np.linspace(0, k, max(min(LOWER_BLOCKS, k), 1) + 1).round().astype(int)
    with shared_product(0.5 * X.shape[0] * k ** 2):
        return [X[:, c0:] @ L[c0:, c0:c1] for c0, c1 in zip(bounds[:-1], bounds[1:])]


#: column blocks of times_lower
LOWER_BLOCKS = 4


def _block_products(X: np.ndarray, Y: np.ndarray, n: int) -> np.ndarray:
    """The 3x3 products X_p Y_p^T of each point's three rows of X and Y, (n, 3, 3) (an einsum: NumPy's stacked
    matmul of so small matrices took 1.7x longer)."""
    return np.einsum("pin,pjn->pij", X.reshape(n, 3, -1), Y.reshape(n, 3, -1))


def block_grams(blocks: list[np.ndarray], n: int) -> np.ndarray:
    """The 3x3 Gram matrices of each point's three rows of the matrix whose column blocks are ``blocks``."""
    out = np.zeros((n, 3, 3))
    for block in blocks:
        rows = block.reshape(n, 3, -1)
        out += rows @ rows.transpose(0, 2, 1)
    return out

