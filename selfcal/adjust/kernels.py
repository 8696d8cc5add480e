"""Compiled inner loops of the normal equations (Numba).

The assembly of the reduced normal equations, the point cofactors and the
observation leverages are sums over observations and over pairs of
observations of the same point, each term a product of 6x3 and 3x3 blocks.
NumPy can vectorise them only by materialising every term; these loops
accumulate directly. Each kernel is a plain loop over flat arrays with the
same meaning as the NumPy expression quoted in its docstring, and the tests
compare them against a dense reference.

Numba earns its place by the benchmark: it removes the largest share of an
iteration's time (see benchmarks/bench_spine.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: the ``cols`` of a kernel whose image rows are in the image's own columns (no working columns)
NO_SLOTS = np.zeros((0, 0), np.int64)

__all__ = ["NO_SLOTS", "accumulate_observations", "schur_image_blocks", "point_cofactor_pairs", "leverage_pairs", "camera_couplings", "point_blocks_times", "subtract_image_couplings", "rows_dot_blocks",
           "camera_couplings_compact", "leverage_camera_cross", "compact_rows",
           "add_point_image_products", "spd_inverse_3x3", "best_ray_pairs", "image_quadratic", "compressed_columns",
           "transposed_positions"]


@njit(cache=True, nogil=True)
def accumulate_observations(j_e, j_p, r, img, ptl, U_ee, g_e, n_pc, cols):
    """Per-image and per-point normal blocks of whitened rows; the image blocks are summed into the caller's.

    U_ee[i] += sum_o j_e[o]^T j_e[o] over observations of image i, g_e[i] += j_e^T r (in place, not a zeroed
    (n_images, w, w) copy per chunk added to the total: each chunk's points lie anywhere in the block);
    V[p] += j_p^T j_p, g_p[p] += j_p^T r over observations of point p;
    w_e[o] = j_e[o]^T j_p[o] (the 6x3 coupling of the observation's image and point).
    ``cols`` (m, slots): the image column of each of j_e's slots (working columns, :mod:`.working`); an empty
    (0, 0) array: j_e's columns are the image's. With slots, U_ee gets the products of slot pairs a <= b only (both
    rows at once, zero slots skipped): the caller symmetrises the sum (:func:`selfcal.adjust.working.symmetrised`).
    Returns V, g_p, w_e.
    """
    m, _, ne = j_e.shape
    slotted = cols.shape[0] > 0
    V = np.zeros((n_pc, 3, 3))
    g_p = np.zeros((n_pc, 3))
    w_e = np.zeros((m, ne, 3))
    for o in range(m):
        i = img[o]
        p = ptl[o]
        if slotted:
            row = cols[o]
            for a in range(ne):
                x0 = j_e[o, 0, a]
                x1 = j_e[o, 1, a]
                if x0 == 0.0 and x1 == 0.0:
                    continue
                g_e[i, row[a]] += x0 * r[o, 0] + x1 * r[o, 1]
                for b in range(3):
                    w_e[o, a, b] = x0 * j_p[o, 0, b] + x1 * j_p[o, 1, b]
                U_a = U_ee[i, row[a]]
                for b in range(a, ne):
                    U_a[row[b]] += x0 * j_e[o, 0, b] + x1 * j_e[o, 1, b]
        for k in range(2):
            rk = r[o, k]
            if not slotted:
                for a in range(ne):
                    ea = j_e[o, k, a]
                    g_e[i, a] += ea * rk
                    for b in range(ne):
                        U_ee[i, a, b] += ea * j_e[o, k, b]
                    for b in range(3):
                        w_e[o, a, b] += ea * j_p[o, k, b]
            for a in range(3):
                pa = j_p[o, k, a]
                g_p[p, a] += pa * rk
                for b in range(3):
                    V[p, a, b] += pa * j_p[o, k, b]
    return V, g_p, w_e


@njit(cache=True, nogil=True)
def schur_image_blocks(V_inv, ptl, w_t, img, pair_a, pair_b, pair_key, diag, off, cols):
    """Subtract W V^-1 W^T from the image blocks; returns Y_t = V^-1 W^T per observation, (m, 3, ne).

    w_t[o] (3, ne) is observation o's coupling with its point, transposed (each row contiguous: the inner loops
    run along it, 35 % faster than along the coupling's 3 columns on BAL problem-49).
    Y_t[o] = V_inv[ptl[o]] w_t[o]; diag[img[o]] -= Y_t[o]^T w_t[o] for every observation;
    off[pair_key[q]] -= Y_t[a]^T w_t[b] for every pair q = (a, b), a < b, of observations of the same point.
    ``cols``: as in :func:`accumulate_observations` (the blocks in working columns; ``diag`` then gets the slot
    pairs a <= b only, for the caller to symmetrise; ``off`` every pair).
    """
    m, _, ne = w_t.shape
    slotted = cols.shape[0] > 0
    Y_t = np.empty((m, 3, ne))
    for o in range(m):
        p = ptl[o]
        for k in range(3):
            v0 = V_inv[p, k, 0]
            v1 = V_inv[p, k, 1]
            v2 = V_inv[p, k, 2]
            for a in range(ne):
                Y_t[o, k, a] = v0 * w_t[o, 0, a] + v1 * w_t[o, 1, a] + v2 * w_t[o, 2, a]
        i = img[o]
        for a in range(ne):
            y0 = Y_t[o, 0, a]
            y1 = Y_t[o, 1, a]
            y2 = Y_t[o, 2, a]
            if slotted:
                if y0 == 0.0 and y1 == 0.0 and y2 == 0.0:
                    continue
                D_a = diag[i, cols[o, a]]
                for b in range(a, ne):
                    D_a[cols[o, b]] -= y0 * w_t[o, 0, b] + y1 * w_t[o, 1, b] + y2 * w_t[o, 2, b]
            else:
                for b in range(ne):
                    diag[i, a, b] -= y0 * w_t[o, 0, b] + y1 * w_t[o, 1, b] + y2 * w_t[o, 2, b]
    for q in range(pair_a.shape[0]):
        oa = pair_a[q]
        ob = pair_b[q]
        key = pair_key[q]
        for a in range(ne):
            y0 = Y_t[oa, 0, a]
            y1 = Y_t[oa, 1, a]
            y2 = Y_t[oa, 2, a]
            if slotted:
                if y0 == 0.0 and y1 == 0.0 and y2 == 0.0:
                    continue
                O_a = off[key, cols[oa, a]]
                for b in range(ne):
                    O_a[cols[ob, b]] -= y0 * w_t[ob, 0, b] + y1 * w_t[ob, 1, b] + y2 * w_t[ob, 2, b]
            else:
                for b in range(ne):
                    off[key, a, b] -= y0 * w_t[ob, 0, b] + y1 * w_t[ob, 1, b] + y2 * w_t[ob, 2, b]
    return Y_t


@njit(cache=True, nogil=True)
def spd_inverse_3x3(V, out):
    """out[n] = V[n]^-1 through the Cholesky factor V = L L^T (V^-1 = L^-T L^-1), from V's lower triangle.

    Returns the first block that is not numerically positive definite (a pivot <= 0), or -1: the caller then
    inverts all blocks by LU, as before this kernel (NumPy's batched inverse took 2.2 ms for 3,900 points, this
    loop a few hundredths of that)."""
    for n in range(V.shape[0]):
        d0 = V[n, 0, 0]
        if not d0 > 0.0:
            return n
        l00 = np.sqrt(d0)
        l10 = V[n, 1, 0] / l00
        l20 = V[n, 2, 0] / l00
        d1 = V[n, 1, 1] - l10 * l10
        if not d1 > 0.0:
            return n
        l11 = np.sqrt(d1)
        l21 = (V[n, 2, 1] - l20 * l10) / l11
        d2 = V[n, 2, 2] - l20 * l20 - l21 * l21
        if not d2 > 0.0:
            return n
        l22 = np.sqrt(d2)
        m00 = 1.0 / l00                         # M = L^-1, lower triangular
        m11 = 1.0 / l11
        m22 = 1.0 / l22
        m10 = -l10 * m00 / l11
        m21 = -l21 * m11 / l22
        m20 = -(l20 * m00 + l21 * m10) / l22
        out[n, 0, 0] = m00 * m00 + m10 * m10 + m20 * m20
        out[n, 1, 1] = m11 * m11 + m21 * m21
        out[n, 2, 2] = m22 * m22
        out[n, 0, 1] = out[n, 1, 0] = m10 * m11 + m20 * m21
        out[n, 0, 2] = out[n, 2, 0] = m20 * m22
        out[n, 1, 2] = out[n, 2, 1] = m21 * m22
    return -1


@njit(cache=True, nogil=True)
def point_cofactor_pairs(Z_e, img, ptl, pair_a, pair_b, pair_key, Q_diag, Q_pair, out, cols):
    """out[p] += sum over ordered pairs (a, b) of point p of Z_e[a]^T Q(img a, img b) Z_e[b].

    ``pair_a``, ``pair_b`` hold the unordered pairs a < b; the diagonal (a = b)
    and both orders are added here. Q(i, i) = Q_diag[i]; Q(img a, img b) = Q_pair[pair_key[q]]: the blocks of
    Q_theta on the pattern of the reduced matrix (see :func:`selfcal.adjust.covariance.image_blocks`).
    ``cols``: as in :func:`accumulate_observations` (the blocks in working columns).
    """
    m, ne, _ = Z_e.shape
    slotted = cols.shape[0] > 0
    tmp = np.zeros((ne, 3))
    for o in range(m):
        i = img[o]
        p = ptl[o]
        for a in range(ne):
            ca = cols[o, a] if slotted else a
            for j in range(3):
                s = 0.0
                for b in range(ne):
                    s += Q_diag[i, ca, cols[o, b] if slotted else b] * Z_e[o, b, j]
                tmp[a, j] = s
        for i in range(3):
            for j in range(3):
                s = 0.0
                for a in range(ne):
                    s += Z_e[o, a, i] * tmp[a, j]
                out[p, i, j] += s
    for q in range(pair_a.shape[0]):
        oa = pair_a[q]
        ob = pair_b[q]
        key = pair_key[q]
        p = ptl[oa]
        for a in range(ne):
            ca = cols[oa, a] if slotted else a
            for j in range(3):
                s = 0.0
                for b in range(ne):
                    s += Q_pair[key, ca, cols[ob, b] if slotted else b] * Z_e[ob, b, j]
                tmp[a, j] = s
        for i in range(3):
            for j in range(3):
                s = 0.0
                for a in range(ne):
                    s += Z_e[oa, a, i] * tmp[a, j]
                out[p, i, j] += s          # (a, b)
                out[p, j, i] += s          # (b, a): its transpose


@njit(cache=True, nogil=True)
def leverage_pairs(Z_e, img, pair_a, pair_b, pair_key, Q_diag, Q_pair, G, cols):
    """G[a] += Q(img a, img b) Z_e[b] for every ordered pair of the same point, diagonal included
    (Q_diag, Q_pair, ``cols`` as in :func:`point_cofactor_pairs`)."""
    m, ne, _ = Z_e.shape
    slotted = cols.shape[0] > 0
    for o in range(m):
        i = img[o]
        for a in range(ne):
            ca = cols[o, a] if slotted else a
            for j in range(3):
                s = 0.0
                for b in range(ne):
                    s += Q_diag[i, ca, cols[o, b] if slotted else b] * Z_e[o, b, j]
                G[o, a, j] += s
    for q in range(pair_a.shape[0]):
        oa = pair_a[q]
        ob = pair_b[q]
        key = pair_key[q]
        for a in range(ne):
            ca = cols[oa, a] if slotted else a
            cb = cols[ob, a] if slotted else a
            for j in range(3):
                s1 = 0.0
                s2 = 0.0
                for b in range(ne):
                    s1 += Q_pair[key, ca, cols[ob, b] if slotted else b] * Z_e[ob, b, j]
                    s2 += Q_pair[key, cols[oa, b] if slotted else b, cb] * Z_e[oa, b, j]
                G[oa, a, j] += s1
                G[ob, a, j] += s2


@njit(cache=True, nogil=True)
def image_quadratic(j_e, Q_diag, img, cols):
    """h[o, k] = j_e[o, k] Q_diag[img o] j_e[o, k]^T, (m, 2) (``cols`` as in :func:`accumulate_observations`)."""
    m, _, ne = j_e.shape
    slotted = cols.shape[0] > 0
    h = np.zeros((m, 2))
    for o in range(m):
        Qi = Q_diag[img[o]]
        for k in range(2):
            s = 0.0
            for a in range(ne):
                ea = j_e[o, k, a]
                if ea == 0.0:
                    continue
                row = Qi[cols[o, a] if slotted else a]
                t = 0.0
                for b in range(ne):
                    t += row[cols[o, b] if slotted else b] * j_e[o, k, b]
                s += ea * t
            h[o, k] = s
    return h


@njit(cache=True, nogil=True)
def camera_couplings(j_d, j_e, j_p, r, img, ptl, varying, U_ed, W_pd, g_d, U_vd, cols, row_width):
    """Accumulate, in one pass over the camera-parameter rows j_d (m, 2, n_d):

    U_ed[row_width i + a] += sum over observations of image i of j_e[o, :, a] j_d[o]  (the image x camera block),
    W_pd[3 p + a] += sum over observations of point p of j_p[o, :, a] j_d[o]  (point x camera coupling),
    g_d += j_d^T r, and U_vd[v] += j_d[:, :, varying[v]]^T j_d (the rows of U_dd that change).
    ``cols``: as in :func:`accumulate_observations` (slot a is row cols[o, a] of its image's ``row_width``).

    The NumPy form reads the large j_d four times (sparse products and a transpose);
    here every row of j_d is loaded once and the accumulators stay in cache.
    """
    m = j_d.shape[0]
    n_d = j_d.shape[2]
    ne = j_e.shape[2]
    slotted = cols.shape[0] > 0
    for o in range(m):
        i6 = row_width * img[o]
        p3 = 3 * ptl[o]
        x, y = j_d[o, 0], j_d[o, 1]
        rx, ry = r[o, 0], r[o, 1]
        for d in range(n_d):                # both rows of the observation in one update of each sum
            g_d[d] += rx * x[d] + ry * y[d]
        for a in range(ne):
            cx, cy = j_e[o, 0, a], j_e[o, 1, a]
            if cx != 0.0 or cy != 0.0:
                out = U_ed[i6 + (cols[o, a] if slotted else a)]
                for d in range(n_d):
                    out[d] += cx * x[d] + cy * y[d]
        for a in range(3):
            cx, cy = j_p[o, 0, a], j_p[o, 1, a]
            out = W_pd[p3 + a]
            for d in range(n_d):
                out[d] += cx * x[d] + cy * y[d]
        for v in range(varying.shape[0]):
            cx, cy = x[varying[v]], y[varying[v]]
            if cx != 0.0 or cy != 0.0:
                out = U_vd[v]
                for d in range(n_d):
                    out[d] += cx * x[d] + cy * y[d]


@njit(cache=True, nogil=True)
def point_blocks_times(B, W_pd, transpose):
    """out[3 p + l] = sum_k B[p, k, l] W_pd[3 p + k] (``transpose``) or B[p, l, k] W_pd[3 p + k]:
    each point's 3 rows of W_pd (3 n_p, n) multiplied by its 3x3 block, B^T or B."""
    n = W_pd.shape[1]
    out = np.empty_like(W_pd)
    for p in range(B.shape[0]):
        w0, w1, w2 = W_pd[3 * p], W_pd[3 * p + 1], W_pd[3 * p + 2]
        for l in range(3):
            if transpose:
                c0, c1, c2 = B[p, 0, l], B[p, 1, l], B[p, 2, l]
            else:
                c0, c1, c2 = B[p, l, 0], B[p, l, 1], B[p, l, 2]
            row = out[3 * p + l]
            for d in range(n):              # one pass over the output row: three rows read, one written
                row[d] = c0 * w0[d] + c1 * w1[d] + c2 * w2[d]
    return out


@njit(cache=True, nogil=True)
def subtract_image_couplings(Y_t, W_pd, img, ptl, S_ed, cols, row_width):
    """S_ed[row_width i + a] -= sum over observations of image i of sum_k Y_t[o, k, a] W_pd[3 p + k]:
    the image x camera part of W V^-1 W^T (Y_t = V^-1 w_e^T per observation, :func:`schur_image_blocks`).
    ``cols``: as in :func:`camera_couplings`."""
    n = W_pd.shape[1]
    ne = Y_t.shape[2]
    slotted = cols.shape[0] > 0
    for o in range(Y_t.shape[0]):
        i6 = row_width * img[o]
        p3 = 3 * ptl[o]
        w0, w1, w2 = W_pd[p3], W_pd[p3 + 1], W_pd[p3 + 2]
        for a in range(ne):
            c0, c1, c2 = Y_t[o, 0, a], Y_t[o, 1, a], Y_t[o, 2, a]
            row = S_ed[i6 + (cols[o, a] if slotted else a)]
            for d in range(n):              # one read-modify-write of the row for the three terms
                row[d] -= c0 * w0[d] + c1 * w1[d] + c2 * w2[d]


@njit(cache=True, nogil=True)
def add_point_image_products(Z_e, img, ptl, Q_ed, out, cols, row_width):
    """out[3 p + c] += sum over observations of point p of sum_a Z_e[o, a, c] Q_ed[row_width i + a] (i the
    observation's image): per point, Z_e^T times its images' rows of Q_ed (n_e, n), summed (``cols`` as in
    :func:`camera_couplings`)."""
    n = Q_ed.shape[1]
    ne = Z_e.shape[1]
    slotted = cols.shape[0] > 0
    for o in range(Z_e.shape[0]):
        i6 = row_width * img[o]
        p3 = 3 * ptl[o]
        for c in range(3):
            row = out[p3 + c]
            for a in range(ne):
                z = Z_e[o, a, c]
                if z != 0.0:
                    q = Q_ed[i6 + (cols[o, a] if slotted else a)]
                    for d in range(n):
                        row[d] += z * q[d]


@njit(cache=True, nogil=True, fastmath=True)
def rows_dot_blocks(X, index, Mt):
    """out[o] = X[o] @ Mt[index[o]].T for X (m, a, n) and Mt (k, c, n), without materialising
    Mt[index]: every entry is a dot product over the long axis n (vectorised; ``fastmath`` only
    lets the sum be reassociated)."""
    m, na, n = X.shape
    nc = Mt.shape[1]
    out = np.zeros((m, na, nc))
    for o in range(m):
        Mo = Mt[index[o]]
        for a in range(na):
            for c in range(nc):
                s = 0.0
                for b in range(n):
                    s += X[o, a, b] * Mo[c, b]
                out[o, a, c] = s
    return out


@njit(cache=True, nogil=True)
def camera_couplings_compact(j_c, j_e, j_p, r, img, cam, cols, U_ed, U_dd, g_d):
    """:func:`camera_couplings` for rows that touch one camera each, in compact form.

    ``j_c`` (m, 2, w) holds observation o's derivatives with respect to the free
    parameters of its camera ``cam[o]``, whose columns of the camera part are
    ``cols[cam[o]]`` (-1 pads a camera with fewer than w). Accumulates U_ed, the
    (block diagonal) U_dd and g_d, and returns w_d (m, 3, w) = j_p[o]^T j_c[o], the
    coupling of each observation's point with its camera (the non-zero parts of W_pd).
    """
    m, _, w = j_c.shape
    ne = j_e.shape[2]
    w_d = np.zeros((m, 3, w))
    for o in range(m):
        i6 = ne * img[o]
        cc = cols[cam[o]]
        for k in range(2):
            rk = r[o, k]
            for c in range(w):
                d = cc[c]
                if d < 0:
                    continue
                x = j_c[o, k, c]
                g_d[d] += rk * x
                for a in range(ne):
                    U_ed[i6 + a, d] += j_e[o, k, a] * x
                for a in range(3):
                    w_d[o, a, c] += j_p[o, k, a] * x
                for c2 in range(w):
                    d2 = cc[c2]
                    if d2 >= 0:
                        U_dd[d, d2] += x * j_c[o, k, c2]
    return w_d


@njit(cache=True, nogil=True, fastmath=True)
def leverage_camera_cross(j_e, j_d, img, ptl, Q_ed, Z, jp_term, h, cols):
    """The image x camera cross terms of the leverages, without the (m, 2, n_d) product j_e Q_ed:

    jp_term[o] += j_e[o] Q_ed[img o] Z[ptl o]^T      (2 x 3)
    h[o, k]    += 2 j_e[o, k] Q_ed[img o] j_d[o, k]^T

    Q_ed (n_img, ne, n_d), Z (n_pc, 3, n_d), j_d (m, 2, n_d). Per observation u = j_e[o] Q_ed[img o]
    (2 x n_d) is formed once and dotted with the point's three rows of Z and with j_d (5 n_d ne
    multiply-adds fewer than Q_ed times [Z^T, j_d^T] first); ``fastmath`` only lets the sums be
    reassociated. ``cols``: as in :func:`accumulate_observations` (Q_ed's rows in working columns).
    """
    m, _, n = j_d.shape
    ne = j_e.shape[2]
    slotted = cols.shape[0] > 0
    u = np.zeros((2, n))
    for o in range(m):
        Qi = Q_ed[img[o]]
        Zp = Z[ptl[o]]
        for k in range(2):
            uk = u[k]
            uk[:] = 0.0
            for e in range(ne):
                c = j_e[o, k, e]
                if c != 0.0:
                    q = Qi[cols[o, e] if slotted else e]
                    for d in range(n):
                        uk[d] += c * q[d]
            for c in range(3):
                s = 0.0
                z = Zp[c]
                for d in range(n):
                    s += uk[d] * z[d]
                jp_term[o, k, c] += s
            s = 0.0
            x = j_d[o, k]
            for d in range(n):
                s += uk[d] * x[d]
            h[o, k] += 2.0 * s


@njit(cache=True, nogil=True)
def compact_rows(flat, width, take, keep):
    """In place: row i of the (n, width) array in ``flat`` becomes old row take[i] restricted to the columns
    ``keep``, written as a (len(take), len(keep)) array at the start of ``flat``. Both index arrays must be
    strictly increasing: every value is then read before the position it sits at is written."""
    k = keep.size
    for i in range(take.size):
        src = take[i] * width
        dst = i * k
        for j in range(k):
            flat[dst + j] = flat[src + keep[j]]


@njit(cache=True, nogil=True)
def best_ray_pairs(start, origin, direction, threshold, pair_rays):
    """For each point (its rays ``start[p]:start[p+1]`` of ``origin`` and unit ``direction``, sorted by point) with
    three rays or more: the intersection of the pair among its first ``pair_rays`` rays that its rays agree with
    best, and its score, the sum over the point's rays of min(angle / ``threshold``, 1)^2 (a ray the point lies
    behind counts 1). Pairs whose rays are parallel or meet behind either camera are not tried; ties keep the
    first pair. (candidate (n_points, 3), score (n_points,): inf where no pair was tried)."""
    n_points = start.size - 1
    candidate = np.full((n_points, 3), np.nan)
    best = np.full(n_points, np.inf)
    for p in range(n_points):
        lo, hi = start[p], start[p + 1]
        if hi - lo < 3:
            continue
        k = min(hi - lo, pair_rays)
        for i in range(lo, lo + k):
            for j in range(i + 1, lo + k):
                c = direction[i, 0] * direction[j, 0] + direction[i, 1] * direction[j, 1] + direction[i, 2] * direction[j, 2]
                denominator = 1.0 - c * c
                if denominator <= 1e-8:
                    continue
                w0 = origin[i] - origin[j]
                pa = direction[i, 0] * w0[0] + direction[i, 1] * w0[1] + direction[i, 2] * w0[2]
                qb = direction[j, 0] * w0[0] + direction[j, 1] * w0[1] + direction[j, 2] * w0[2]
                s = (c * qb - pa) / denominator
                t = (qb - c * pa) / denominator
                if s <= 0.0 or t <= 0.0:
                    continue
                x = 0.5 * (origin[i] + s * direction[i] + origin[j] + t * direction[j])
                score = 0.0
                for r in range(lo, hi):
                    o0, o1, o2 = x[0] - origin[r, 0], x[1] - origin[r, 1], x[2] - origin[r, 2]
                    along = o0 * direction[r, 0] + o1 * direction[r, 1] + o2 * direction[r, 2]
                    if along <= 0.0:
                        score += 1.0
                        continue
                    a0, a1, a2 = o0 - along * direction[r, 0], o1 - along * direction[r, 1], o2 - along * direction[r, 2]
                    angle = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2) / along
                    score += min(angle / threshold, 1.0) ** 2
                if score < best[p]:
                    best[p] = score
                    candidate[p] = x
    return candidate, best


@njit(cache=True, nogil=True)
def compressed_columns(rows, cols, n):
    """The compressed-column pattern of the entries (rows[k], cols[k]) of an n x n matrix, duplicates once:
    (indptr, indices, position), ``position[k]`` the place of entry k among ``indices`` (a duplicate's the same).
    A counting sort by column and a sort of each column's rows: what ``np.unique`` of the keys col * n + row gives,
    without sorting all of them together (5 s for the 2000-image block's reduced matrix, 3.5 million keys)."""
    m = rows.size
    count = np.zeros(n + 1, np.int64)
    for k in range(m):
        count[cols[k] + 1] += 1
    start = np.cumsum(count)
    slot = start[:-1].copy()
    bucket = np.empty(m, np.int64)                  # entry ids, column by column
    for k in range(m):
        bucket[slot[cols[k]]] = k
        slot[cols[k]] += 1
    indptr = np.zeros(n + 1, np.int64)
    indices = np.empty(m, np.int64)
    position = np.empty(m, np.int64)
    kept = 0
    for c in range(n):
        ids = bucket[start[c]:start[c + 1]]
        order = np.argsort(rows[ids], kind="mergesort")
        previous = -1
        for k in ids[order]:
            if rows[k] != previous:
                indices[kept] = rows[k]
                kept += 1
                previous = rows[k]
            position[k] = kept - 1
        indptr[c + 1] = kept
    return indptr, indices[:kept].copy(), position


@njit(cache=True, nogil=True)
def transposed_positions(indptr, indices):
    """For each entry of a compressed-column pattern that is symmetric (rows sorted in each column), the position
    of its transpose (the entry at its column's row, its row's column); -1 where the pattern has none."""
    n = indptr.size - 1
    out = np.full(indices.size, -1, np.int64)
    for c in range(n):
        for k in range(indptr[c], indptr[c + 1]):
            r = indices[k]
            lo, hi = indptr[r], indptr[r + 1]
            while lo < hi:                          # the first row >= c in column r
                mid = (lo + hi) // 2
                if indices[mid] < c:
                    lo = mid + 1
                else:
                    hi = mid
            if lo < indptr[r + 1] and indices[lo] == c:
                out[k] = lo
    return out
