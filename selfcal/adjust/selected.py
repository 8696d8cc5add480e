"""The cofactor matrix of theta on the pattern of the reduced matrix, without the dense inverse.

A strip-structured block's reduced matrix S = [[A, B], [B^T, C]] is, after the reverse
Cuthill-McKee ordering of its image part A, a band of width w with a dense border (the
camera parameters that couple every image; see :func:`selfcal.adjust.linalg.band_structure`).
Cut into the level sets of a breadth-first search from the ordering's start (each level touches
only the levels before and after it; failing that, blocks of w unknowns), A is block tridiagonal,
and so is the part of its inverse the covariance needs: every pair of images that share a point
is a non-zero of A, hence within one level or two neighbouring ones. With the block Cholesky
factor A = L L^T (diagonal blocks L_i, sub-diagonal M_i = F_i L_i^-T) the recurrence of
Takahashi et al. (1973) gives the block-tridiagonal part Z of A^-1 from the last block back:

    Z_N = L_N^-T L_N^-1,
    Z_{i+1,i} = -Z_{i+1} M_i L_i^-1,      Z_i = L_i^-T L_i^-1 - Z_{i+1,i}^T M_i L_i^-1,

about 8 n b^2 flops in BLAS-3 blocks of mean size b <= w and n w numbers instead of n^2 (the
levels halve the flops of blocks of w on the strip blocks: 2000 images 5.5 s instead of 10.6 s). The border follows from the
block inverse: X = A^-1 B, Q_cc = (C - B^T X)^-1, Q_ac = -X Q_cc, Q_aa = A^-1 + X Q_cc X^T.

:class:`BandedCofactor` holds Z, X and Q_cc and answers Q_theta[rows, cols] like an ndarray:
entries on the known pattern (every image-image pair within neighbouring blocks, every entry
in a border row or column: the camera parameters' full columns) directly, any other entry
exactly by solving S x = e for its column (one solve per column asked for).
"""
from __future__ import annotations

import copy

import numpy as np
import scipy.linalg as la

__all__ = ["BandedCofactor"]


def _block_solve(L: list, M: list, rhs: list) -> list:
    """Solve A x = rhs with A = L L^T block bidiagonal (diagonal blocks L[i], sub-diagonal M[i])."""
    nb = len(L)
    y = [la.solve_triangular(L[0], rhs[0], lower=True, check_finite=False)]
    for i in range(1, nb):
        y.append(la.solve_triangular(L[i], rhs[i] - M[i - 1] @ y[i - 1], lower=True, check_finite=False))
    x = y
    x[-1] = la.solve_triangular(L[-1], y[-1], lower=True, trans="T", check_finite=False)
    for i in range(nb - 2, -1, -1):
        x[i] = la.solve_triangular(L[i], y[i] - M[i].T @ x[i + 1], lower=True, trans="T", check_finite=False)
    return x


def _cholesky_inverse(L: np.ndarray, out: np.ndarray) -> None:
    """(L L^T)^-1 of a lower triangular L into ``out`` (LAPACK's potri: its lower triangle, mirrored)."""
    inverse, info = la.lapack.dpotri(L, lower=1)
    if info:
        raise la.LinAlgError(f"the block's Cholesky factor is singular (potri info {info})")
    np.copyto(out, np.tril(inverse))
    out += np.tril(out, -1).T


def _levels(A, perm: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Block-tridiagonal order and block starts of A: the level sets of a breadth-first search from
    the reverse Cuthill-McKee start (a level touches only its neighbours; on the strip blocks their
    sizes give half the flops of blocks of the bandwidth), else blocks of ``width`` in ``perm`` order."""
    from scipy.sparse.csgraph import breadth_first_order

    n_a = perm.size
    start = perm[-1] if n_a else 0
    order, parent = breadth_first_order(A, int(start), directed=False, return_predecessors=True)
    if order.size == n_a:
        level = np.zeros(n_a, np.int64)
        for node in order[1:]:                          # parents come first in breadth-first order
            level[node] = level[parent[node]] + 1
        new = order[np.argsort(level[order], kind="stable")]
        bounds = np.concatenate([[0], np.cumsum(np.bincount(level))])
        return new, bounds
    b = max(int(width), 1)
    return perm, np.append(np.arange(0, n_a, b), n_a)


class BandedCofactor:
    """Q_theta = S^-1 of a banded S with a border, known on S's pattern; indexable like an ndarray.

    Parameters
    ----------
    scaled : csc_matrix
        The Jacobi-scaled S (unit diagonal).
    scale : ndarray
        S = D^-1 scaled D^-1 with D = diag(scale): Q = D scaled^-1 D.
    perm, border : int arrays
        The band's unknowns in reverse Cuthill-McKee order, and the border's unknowns.
    width : int
        The band's half bandwidth in ``perm`` order.
    solve : callable
        b -> S^-1 b (unscaled), for entries off the known pattern.
    """

    ndim = 2
    dtype = np.dtype(float)
    __array_ufunc__ = None          # numpy_scalar * Q comes to __rmul__, not through a dense array

    def __init__(self, scaled, scale: np.ndarray, perm: np.ndarray, border: np.ndarray, width: int, solve):
        n = scaled.shape[0]
        self.shape = (n, n)
        self._scale = scale
        self._solve = solve
        self._factor = 1.0
        local, bounds = _levels(scaled[perm][:, perm].tocsr(), np.arange(perm.size), width)
        perm = perm[local]                              # the unknowns in block order
        n_a, nb = perm.size, bounds.size - 1
        sizes = np.diff(bounds)
        A = scaled[perm][:, perm].tocoo()
        block = np.searchsorted(bounds, np.arange(n_a), side="right") - 1
        offset = np.arange(n_a) - bounds[block]
        bi, bj = block[A.row], block[A.col]
        if np.any(np.abs(bi - bj) > 1):
            raise ValueError("the blocks are not block tridiagonal")
        D = [np.zeros((sizes[i], sizes[i])) for i in range(nb)]
        F = [np.zeros((sizes[i + 1], sizes[i])) for i in range(nb - 1)]
        # the entries of each diagonal block, then of each sub-diagonal one, grouped once (a mask per block
        # went over all the entries for every block: 1.3 s at 5000 images, 29 blocks of 7 million entries)
        on = np.flatnonzero(bi == bj)
        on = on[np.argsort(bi[on], kind="stable")]
        on_cuts = np.searchsorted(bi[on], np.arange(nb + 1))
        below = np.flatnonzero(bi == bj + 1)
        below = below[np.argsort(bj[below], kind="stable")]
        below_cuts = np.searchsorted(bj[below], np.arange(nb))
        for i in range(nb):
            e = on[on_cuts[i]:on_cuts[i + 1]]
            D[i][offset[A.row[e]], offset[A.col[e]]] = A.data[e]
            if i < nb - 1:
                e = below[below_cuts[i]:below_cuts[i + 1]]
                F[i][offset[A.row[e]], offset[A.col[e]]] = A.data[e]
        # block Cholesky: D_i - M_{i-1} M_{i-1}^T = L_i L_i^T, M_i = F_i L_i^-T
        L, M = D, F                                         # overwritten block by block
        for i in range(nb):
            if i:
                L[i] -= M[i - 1] @ M[i - 1].T
            L[i] = la.cholesky(L[i], lower=True, check_finite=False)
            if i < nb - 1:
                M[i] = la.solve_triangular(L[i], F[i].T, lower=True, check_finite=False).T
        # border
        k = border.size
        if k:
            B = scaled[perm][:, border].toarray()
            X = np.concatenate(_block_solve(L, M, [B[bounds[i]:bounds[i + 1]] for i in range(nb)]))
            C = scaled[border][:, border].toarray() - B.T @ X
            Q_cc = la.inv(C, check_finite=False)
            Q_cc = 0.5 * (Q_cc + Q_cc.T)
        else:
            X, Q_cc = np.zeros((n_a, 0)), np.zeros((0, 0))
        # Takahashi's recurrence from the last block back, each block written where it is kept (flat storage:
        # block i's entry (a, b) at off_d[i] + a * sizes[i] + b, Z_{i+1,i}'s at off_s[i] + ...; concatenated
        # afterwards, the copy's first touch of 600 MB took 2 s at 5000 images). (L_i L_i^T)^-1 by LAPACK's
        # Cholesky inverse and G = M_i L_i^-1 by a triangular solve: 5.7 b^3 flops a block instead of 9 b^3.
        self._sizes, self._block, self._offset = sizes, block, offset
        self._off_d = np.concatenate([[0], np.cumsum(sizes * sizes)])[:-1]
        self._off_s = np.concatenate([[0], np.cumsum(sizes[1:] * sizes[:-1])])[:-1]
        self._Zd = np.empty(int(np.sum(sizes * sizes)))
        self._Zs = np.empty(int(np.sum(sizes[1:] * sizes[:-1])))

        def Z(i: int) -> np.ndarray:
            return self._Zd[self._off_d[i]:self._off_d[i] + sizes[i] ** 2].reshape(sizes[i], sizes[i])

        def Z_below(i: int) -> np.ndarray:
            return self._Zs[self._off_s[i]:self._off_s[i] + sizes[i + 1] * sizes[i]].reshape(sizes[i + 1], sizes[i])
        _cholesky_inverse(L[-1], out=Z(nb - 1))
        for i in range(nb - 2, -1, -1):
            G = la.solve_triangular(L[i], M[i].T, lower=True, trans="T", check_finite=False).T     # M_i L_i^-1
            Z_sub = Z_below(i)
            np.matmul(Z(i + 1), G, out=Z_sub)
            Z_sub *= -1.0                                                                       # Z_{i+1,i}
            _cholesky_inverse(L[i], out=Z(i))
            Z(i)[...] -= Z_sub.T @ G
            L[i] = M[i] = np.empty((0, 0))                                          # done with: their memory goes
        self._X, self._XQ, self._Q_cc = X, X @ Q_cc, Q_cc
        self._pos = np.full(n, -1, np.int64)
        self._pos[perm] = np.arange(n_a)
        self._bpos = np.full(n, -1, np.int64)
        self._bpos[border] = np.arange(k)

    # -- ndarray-like access -------------------------------------------------------------------
    def __mul__(self, factor: float) -> "BandedCofactor":
        out = copy.copy(self)
        out._factor = self._factor * float(factor)
        return out

    __rmul__ = __mul__

    def diagonal(self) -> np.ndarray:
        k = np.arange(self.shape[0])
        return self._entries(k, k)

    def toarray(self) -> np.ndarray:
        """The dense matrix (n solves and n^2 numbers: what this class exists to avoid)."""
        k = np.arange(self.shape[0])
        return self._entries(k[:, None], k[None, :])

    def __array__(self, dtype=None, copy=None):
        out = self.toarray()
        return out if dtype is None else out.astype(dtype)

    def __getitem__(self, key):
        if not isinstance(key, tuple):
            key = (key, slice(None))
        if len(key) != 2:
            raise IndexError("a cofactor matrix takes two indices")
        n = self.shape[0]
        parts = [np.arange(n)[k] if isinstance(k, slice) else np.asarray(k) for k in key]
        if isinstance(key[0], slice) or isinstance(key[1], slice):    # slices combine as an outer product
            r, c = parts
            if isinstance(key[0], slice):
                r = r.reshape(r.shape + (1,) * c.ndim)
            else:
                c = c.reshape((1,) * r.ndim + c.shape)
            parts = [r, c]
        r, c = np.broadcast_arrays(*parts)
        if np.any(r < 0) or np.any(c < 0):
            r, c = np.where(r < 0, r + n, r), np.where(c < 0, c + n, c)
        out = self._entries(r.ravel(), c.ravel()).reshape(r.shape)
        return out[()] if out.ndim == 0 else out

    # -- the entries ---------------------------------------------------------------------------
    def _entries(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        r, c = np.broadcast_arrays(np.asarray(r, np.int64), np.asarray(c, np.int64))
        shape = r.shape
        r, c = r.ravel(), c.ravel()
        out = np.empty(r.size)
        known = np.ones(r.size, bool)
        br, bc = self._bpos[r], self._bpos[c]
        sel = bc >= 0                                       # a border column: known in every row
        out[sel] = self._border_column(r[sel], bc[sel])
        sel = (bc < 0) & (br >= 0)
        out[sel] = self._border_column(c[sel], br[sel])
        inner = (br < 0) & (bc < 0)
        if inner.any():
            pr, pc = self._pos[r[inner]], self._pos[c[inner]]
            hi, lo = np.maximum(pr, pc), np.minimum(pr, pc)
            bi, bj = self._block[hi], self._block[lo]
            oh, ol = self._offset[hi], self._offset[lo]
            val = np.einsum("ij,ij->i", self._X[hi], self._XQ[lo])
            same, next_ = bi == bj, bi == bj + 1
            val[same] += self._Zd[self._off_d[bi[same]] + oh[same] * self._sizes[bi[same]] + ol[same]]
            val[next_] += self._Zs[self._off_s[bj[next_]] + oh[next_] * self._sizes[bj[next_]] + ol[next_]]
            out[inner] = val
            known[np.flatnonzero(inner)[~(same | next_)]] = False
        out *= self._scale[r] * self._scale[c]
        if not known.all():                                 # off the pattern: S x = e for those columns
            cols, where = np.unique(c[~known], return_inverse=True)
            E = np.zeros((self.shape[0], cols.size))
            E[cols, np.arange(cols.size)] = 1.0
            Xc = self._solve(E)
            out[~known] = Xc[r[~known], where]
        return (self._factor * out).reshape(shape)

    def _border_column(self, rows: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Scaled entries Q[rows, border[k]]."""
        out = np.empty(rows.size)
        br = self._bpos[rows]
        sel = br >= 0
        out[sel] = self._Q_cc[br[sel], k[sel]]
        out[~sel] = -self._XQ[self._pos[rows[~sel]], k[~sel]]
        return out
