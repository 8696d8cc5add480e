"""The cofactor matrix of theta on the pattern of the reduced matrix, without the dense inverse.

A strip-structured block's reduced matrix S = [[A, B], [B^T, C]] is, after the reverse
Cuthill-McKee ordering of its image part A, a band of width w with a dense border (the
camera parameters that couple every image; see :func:`selfcal.adjust.linalg.band_structure`).
Cut into blocks of w unknowns, A is block tridiagonal, and so is the part of its inverse the
covariance needs: every pair of images that share a point is a non-zero of A, hence within the
band, hence within two neighbouring blocks. With the block Cholesky factor A = L L^T (diagonal
blocks L_i, sub-diagonal M_i = F_i L_i^-T) the recurrence of Takahashi et al. (1973) gives the
block-tridiagonal part Z of A^-1 from the last block back:

    Z_N = L_N^-T L_N^-1,
    Z_{i+1,i} = -Z_{i+1} M_i L_i^-1,      Z_i = L_i^-T L_i^-1 - Z_{i+1,i}^T M_i L_i^-1,

n w^2 flops in BLAS-3 blocks and n w numbers instead of n^2. The border follows from the
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


def _block_solve(L: np.ndarray, M: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve A x = rhs with A = L L^T block bidiagonal: rhs (nb, b, k)."""
    nb = L.shape[0]
    y = np.empty_like(rhs)
    y[0] = la.solve_triangular(L[0], rhs[0], lower=True, check_finite=False)
    for i in range(1, nb):
        y[i] = la.solve_triangular(L[i], rhs[i] - M[i - 1] @ y[i - 1], lower=True, check_finite=False)
    x = y
    x[-1] = la.solve_triangular(L[-1], y[-1], lower=True, trans="T", check_finite=False)
    for i in range(nb - 2, -1, -1):
        x[i] = la.solve_triangular(L[i], y[i] - M[i].T @ x[i + 1], lower=True, trans="T", check_finite=False)
    return x


class BandedCofactor:
    """Q_theta = S^-1 of a banded S with a border, known on S's pattern; indexable like an ndarray.

    Parameters
    ----------
    scaled : csc_matrix
        The Jacobi-scaled S (unit diagonal).
    scale : ndarray
        S = D^-1 scaled D^-1 with D = diag(scale): Q = D scaled^-1 D.
    perm, border : int arrays
        The band's unknowns in band order, and the border's unknowns.
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
        n_a, b = perm.size, max(int(width), 1)
        nb = -(-n_a // b)
        self._b = b
        A = scaled[perm][:, perm].tocoo()
        bi, bj = A.row // b, A.col // b
        D = np.zeros((nb, b, b))
        F = np.zeros((max(nb - 1, 0), b, b))
        on = bi == bj
        D[bi[on], A.row[on] % b, A.col[on] % b] = A.data[on]
        below = bi == bj + 1
        F[bj[below], A.row[below] % b, A.col[below] % b] = A.data[below]
        pad = nb * b - n_a
        if pad:
            D[-1, b - pad:, b - pad:] = np.eye(pad)
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
            Bp = np.zeros((nb * b, k))
            Bp[:n_a] = B
            X = _block_solve(L, M, Bp.reshape(nb, b, k)).reshape(nb * b, k)[:n_a]
            C = scaled[border][:, border].toarray() - B.T @ X
            Q_cc = la.inv(C, check_finite=False)
            Q_cc = 0.5 * (Q_cc + Q_cc.T)
        else:
            X, Q_cc = np.zeros((n_a, 0)), np.zeros((0, 0))
        # Takahashi's recurrence from the last block back; Z_i overwrites L_i, Z_{i+1,i} overwrites M_i
        eye = np.eye(b)
        inv_last = la.solve_triangular(L[-1], eye, lower=True, check_finite=False)
        L[-1] = inv_last.T @ inv_last
        for i in range(nb - 2, -1, -1):
            inv_i = la.solve_triangular(L[i], eye, lower=True, check_finite=False)
            G = M[i] @ inv_i
            M[i] = -L[i + 1] @ G
            L[i] = inv_i.T @ inv_i - M[i].T @ G
        self._Zd, self._Zs = L, M
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
            b = self._b
            bi, bj = hi // b, lo // b
            val = np.einsum("ij,ij->i", self._X[hi], self._XQ[lo])
            same, next_ = bi == bj, bi == bj + 1
            val[same] += self._Zd[bi[same], hi[same] % b, lo[same] % b]
            val[next_] += self._Zs[bj[next_], hi[next_] % b, lo[next_] % b]
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
