"""Factorising the reduced normal matrix, and naming what makes it singular.

The reduced matrix S is scaled to unit diagonal (Jacobi scaling) before its
Cholesky factorisation, so that unknowns in metres, radians and pixels meet on
equal terms. Small systems use dense LAPACK; large ones a banded Cholesky with a
dense border when the image graph has a narrow band (strip-structured blocks) and
the band is cheaper than CHOLMOD, else CHOLMOD (scikit-sparse, installed by
``make install`` with Debian's OpenBLAS under it: CHOLMOD's supernodes are BLAS calls, and
the reference BLAS or a generic ATLAS made them 3x slower). Measured on one machine in one run
(benchmarks/bench_scaling.py --linalg, two BLAS threads, factorisation and one solve): strips of
1000 / 2000 / 5000 images 0.21 / 0.40 / 4.19 s banded, 0.15 / 0.31 / 1.35 s by CHOLMOD,
0.40 / 1.38 / 6.46 s by SuperLU; a random image graph (no band) of 1000 / 2000 images
0.77 / 3.04 s by CHOLMOD, 4.55 / 36.8 s by SuperLU. On one BLAS thread the banded path still wins
at 1000 images (0.23 against 0.29 s) and loses at 2000 (0.60 against 0.42 s). SciPy's SuperLU
remains only for an installation without scikit-sparse, and says so: :attr:`Factor.method` names
the path taken and the adjustment notes it.
"""
from __future__ import annotations

import contextlib
import functools

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["SingularSystem", "Factor", "factorise", "rank_one_update", "pseudo_factorise", "null_directions", "band_structure",
           "DENSE_LIMIT", "DENSE_ASSEMBLY_LIMIT", "dense_assembly", "PSEUDO_INVERSE_LIMIT", "DEFECT_TOLERANCE", "CHOLMOD_AVAILABLE"]

#: reduced systems up to this size are assembled and factorised densely, larger ones sparse (CHOLMOD or the
#: banded path). Reduction, factorisation and solve of strip blocks, measured in one run on two BLAS threads:
#: 1203 unknowns (200 images) 0.102 s dense against 0.107 s sparse, 1803 (300 images) 0.34 against 0.10 s,
#: 3027 (504 images) 0.97 against 0.21 s: the dense assembly writes n^2 numbers several times over
DENSE_ASSEMBLY_LIMIT = 1500


def dense_assembly(n_theta: int, pseudo_inverse: bool = False) -> bool:
    """Whether a reduced system of ``n_theta`` unknowns is assembled dense: up to DENSE_ASSEMBLY_LIMIT, and for the
    pseudo-inverse steps of a free network, whose eigendecomposition reads S dense."""
    return n_theta <= DENSE_ASSEMBLY_LIMIT or pseudo_inverse


#: up to this size Q_theta is the dense inverse (a sparse S made dense for it) and a singular S is analysed by
#: its eigenvectors; beyond, Q_theta is a selected inverse where S has a band (:meth:`Factor.cofactor`)
DENSE_LIMIT = 6000
#: free networks up to this many orientation and camera unknowns take minimum-norm Gauss-Newton steps through a
#: dense eigendecomposition of S in every undamped iteration (0.02 s at 441 unknowns, about 1 s at 2000)
PSEUDO_INVERSE_LIMIT = 2000
#: eigenvalues of the Jacobi-scaled S below this share of the largest are the datum defect
DEFECT_TOLERANCE = 1e-10

try:  # scikit-sparse is an extra (selfcal[cholmod]): it builds against the system's SuiteSparse
    from sksparse.cholmod import CholmodNotPositiveDefiniteError, analyze as _cholmod_analyze, cholesky as _cholmod
except ImportError:  # pragma: no cover - an installation without it
    _cholmod = _cholmod_analyze = None
    CholmodNotPositiveDefiniteError = None

#: whether large systems without a narrow band are factorised by CHOLMOD (else by SuperLU: 1-2x slower)
CHOLMOD_AVAILABLE = _cholmod is not None


class SingularSystem(np.linalg.LinAlgError):
    """The normal matrix is singular or not positive definite."""


class Factor:
    """A factorisation of S that solves S x = b for vectors and matrices.

    ``method`` names the factorisation: "dense" (LAPACK), "banded" (band with a dense border),
    "cholmod" or "superlu" (sparse). ``lower`` is the dense Cholesky factor of the scaled S when
    there is one; ``scaled`` the scaled sparse S otherwise (for :meth:`inverse` and :meth:`cofactor`).
    """

    #: a pseudo-inverse's (:func:`pseudo_factorise`): the number of datum directions of S, and a basis of them
    #: (n, defect) in S's own units; 0 and None for a regular S
    defect: int = 0
    null: np.ndarray | None = None

    def __init__(self, solve, scale: np.ndarray, method: str, lower: np.ndarray | None = None, scaled=None):
        self._solve = solve
        self.scale = scale
        self.method = method
        self._lower = lower
        self._scaled = scaled

    def cofactor(self, dense_limit: int = DENSE_LIMIT):
        """Q_theta = S^-1 as the covariance needs it.

        A dense ndarray (:meth:`inverse`) up to ``dense_limit`` unknowns (a sparse S beyond
        ``DENSE_ASSEMBLY_LIMIT`` made dense for it: 0.2 s at 2600 unknowns against 0.5 s for the
        selected inverse) and for a sparse S without a narrow band; for a banded S beyond it a
        :class:`~selfcal.adjust.selected.BandedCofactor`: the entries on S's pattern and the
        border's full columns by Takahashi's recurrence, n w^2 flops and n w numbers instead of
        the n^2 of the dense inverse (2000 images: 12003 unknowns, 1.1 GB per dense copy).
        """
        if self._scaled is None or self.scale.size <= dense_limit:
            return self.inverse()
        pattern = _pattern_cache(self._scaled)
        if "band" not in pattern:
            pattern["band"] = band_structure(self._scaled)
        band = pattern["band"]
        if band is None:
            return self.inverse()
        from .selected import BandedCofactor
        border, perm, width = band
        return BandedCofactor(self._scaled, self.scale, perm, border, width, self.solve)

    def solve(self, b: np.ndarray) -> np.ndarray:
        s = self.scale if b.ndim == 1 else self.scale[:, None]
        return s * self._solve(s * b)

    def inverse(self) -> np.ndarray:
        """The dense inverse S^-1 (the cofactor matrix of theta).

        From the Cholesky factor by LAPACK's potri (n^3/3 flops), not by n
        solves: a sparse factorisation solving for the identity column by
        column took 10 of the 16 s of a 1000-image adjustment, and 70 of 77 s
        at 2000 images. A sparse S is made dense for it (what it returns is
        dense anyway).
        """
        lower = self._lower
        if lower is None:
            dense = self._scaled.toarray()
            lower, info = la.lapack.dpotrf(dense, lower=1, overwrite_a=1, clean=0)
            if info != 0:
                raise SingularSystem(f"not positive definite (dpotrf info {info})")
        inverse, info = la.lapack.dpotri(lower, lower=1, overwrite_c=self._lower is None)
        if info != 0:
            raise SingularSystem(f"singular (dpotri info {info})")
        # the upper triangle from the lower, and the scaling, in place by strips: one n x n array in all
        n, step = inverse.shape[0], 512
        for j0 in range(0, n, step):
            j1 = min(j0 + step, n)
            diagonal = np.tril(inverse[j0:j1, j0:j1])
            inverse[j0:j1, j0:j1] = diagonal + np.tril(diagonal, -1).T
            inverse[j0:j1, j1:] = inverse[j1:, j0:j1].T
        inverse *= self.scale[:, None]
        inverse *= self.scale[None, :]
        return inverse


def factorise(S: np.ndarray | sp.csr_matrix | sp.csc_matrix, rcond: float = 1e-13) -> Factor:
    """Cholesky factorisation of a symmetric positive definite S (dense or sparse).

    Raises
    ------
    SingularSystem
        When S is not positive definite, or its scaled diagonal pivots fall below
        ``rcond`` (numerically singular).
    """
    diag = S.diagonal() if sp.issparse(S) else np.diag(S).copy()
    if np.any(~np.isfinite(diag)):
        raise SingularSystem("the normal matrix has non-finite entries")
    if np.any(diag <= 0):
        raise SingularSystem(f"{int(np.sum(diag <= 0))} unknown(s) have no observation at all")
    scale = 1.0 / np.sqrt(diag)
    if not sp.issparse(S):
        Ss = S * scale[:, None] * scale[None, :]
        try:
            c, lower = la.cho_factor(Ss, lower=True, check_finite=False)
        except la.LinAlgError as exc:
            raise SingularSystem(f"not positive definite ({exc})") from None
        pivots = np.diag(c) ** 2
        if pivots.min() < rcond:
            raise SingularSystem(f"numerically singular (smallest scaled pivot {pivots.min():.1e})")
        return Factor(lambda b: la.cho_solve((c, lower), b, check_finite=False), scale, "dense", lower=c)
    Ss = S.tocsc(copy=True)
    Ss.data *= scale[Ss.indices] * np.repeat(scale, np.diff(Ss.indptr))
    pattern = _pattern_cache(Ss)
    if "band" not in pattern:
        pattern["band"] = band_structure(Ss)
    band = pattern["band"]
    if band is not None and (_cholmod is None or _band_flops(band) <= BAND_FLOPS):
        return Factor(_bordered_banded(Ss, band, rcond), scale, "banded", scaled=Ss)
    if _cholmod is not None:
        try:
            if "cholmod" not in pattern:
                pattern["cholmod"] = _cholmod_analyze(Ss)
            f = pattern["cholmod"].cholesky(Ss)
        except CholmodNotPositiveDefiniteError as exc:
            raise SingularSystem(f"not positive definite ({exc})") from None
        d = f.D()
        if d.min() < rcond:
            raise SingularSystem(f"numerically singular (smallest scaled pivot {d.min():.1e})")
        return Factor(f, scale, "cholmod", scaled=Ss)
    try:
        lu = spla.splu(Ss, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
    except RuntimeError as exc:
        raise SingularSystem(f"singular ({exc})") from None
    u = np.abs(lu.U.diagonal())
    if u.min() < rcond or np.any(lu.U.diagonal() <= 0):
        raise SingularSystem(f"not positive definite or singular (smallest pivot {u.min():.1e})")
    return Factor(lu.solve, scale, "superlu", scaled=Ss)


_PATTERN: dict = {}


def _pattern_cache(Ss: sp.csc_matrix) -> dict:
    """What depends only on the sparsity pattern of S (the band ordering, CHOLMOD's symbolic analysis),
    kept for the last pattern seen: every iteration of an adjustment factorises the same pattern
    (on the 5000-image block this saves 1 of the 4.7 s of a factorisation)."""
    import hashlib

    digest = hashlib.blake2b(Ss.indptr.tobytes(), digest_size=16)
    digest.update(Ss.indices.tobytes())
    key = (Ss.shape, digest.hexdigest())
    if _PATTERN.get("key") != key:
        _PATTERN.clear()
        _PATTERN["key"] = key
    return _PATTERN


def _follow_null_space(Ss: np.ndarray, Z: np.ndarray, steps: int = 2) -> np.ndarray | None:
    """The null space of the scaled S from the previous iteration's basis ``Z`` (orthonormal): the datum
    directions turn with the state (a free network's similarity acts on the current estimate), so Z is
    refined by inverse iteration with a shift far below the defect tolerance. Each step multiplies Z's
    components along the other eigenvectors by shift / eigenvalue. The shift starts at 1e-12 of a bound on
    the largest eigenvalue and grows by 100 (to 1e-8) while S_s + shift I is not positive definite: far from
    the solution the Schur complement's rounding makes S_s's null eigenvalues up to about 4e-10 of the largest
    in either sign (BAL problem-49, second iteration; the next eigenvalue 2.3e-5). None when no shift works."""
    bound = float(np.abs(Ss).sum(axis=1).max())            # the row sums bound the largest eigenvalue
    for relative in (1e-12, 1e-10, 1e-8):
        try:
            c = la.cho_factor(Ss + relative * bound * np.eye(len(Ss)), lower=True, check_finite=False)
        except la.LinAlgError:
            continue
        for _ in range(steps):
            Z = np.linalg.qr(la.cho_solve(c, Z, check_finite=False))[0]
        return Z
    return None


def pseudo_factorise(S: np.ndarray | sp.csr_matrix | sp.csc_matrix, null: np.ndarray | None = None,
                     defect_tol: float = DEFECT_TOLERANCE) -> Factor:
    """The minimum-norm solution of a singular S x = b (free network): S's pseudo-inverse in the Jacobi-scaled
    metric, so that x has no component along the datum directions (inner constraints on the orientation and
    camera unknowns). ``Factor.defect`` is the number of datum directions, ``Factor.null`` (n, defect) a basis
    of them in S's own units, to pass back as ``null`` in the next iteration.

    Without ``null``: a dense eigendecomposition of the scaled S, whose eigenvalues below ``defect_tol`` times
    the largest are the datum defect. With ``null`` (a basis of the previous iteration's, or the similarity's
    directions, :func:`selfcal.adjust.datum.similarity_directions`): a Cholesky
    factorisation of S_s + Z Z^T, Z that basis orthonormalised in the current scaling, and the solution's Z
    part removed; exact when Z spans S's null space, as (S_s + Z Z^T)^-1 is then S_s's pseudo-inverse on
    Z's complement, where the gradient lies. Ten times cheaper than the eigendecomposition (0.03 s against
    0.37 s at 1200 unknowns). When S_s Z is no longer below 1e-6 (the state moved the datum directions), Z
    follows them by inverse iteration (:func:`_follow_null_space`); only if that fails, or the factorisation
    does, is the eigendecomposition repeated.

    Raises SingularSystem when S has an unknown without any observation.
    """
    S = S.toarray() if sp.issparse(S) else np.asarray(S)
    diag = np.diag(S).copy()
    if np.any(~np.isfinite(diag)):
        raise SingularSystem("the normal matrix has non-finite entries")
    if np.any(diag <= 0):
        raise SingularSystem(f"{int(np.sum(diag <= 0))} unknown(s) have no observation at all")
    scale = 1.0 / np.sqrt(diag)
    Ss = S * scale[:, None] * scale[None, :]
    if null is not None and null.shape[1]:
        Z: np.ndarray | None                                # None where _follow_null_space finds no shift
        Z = np.linalg.qr(null / scale[:, None])[0]
        if not np.linalg.norm(Ss @ Z) < 1e-6 * np.sqrt(Z.shape[1]):
            Z = _follow_null_space(Ss, Z)
        if Z is not None and np.linalg.norm(Ss @ Z) < 1e-6 * np.sqrt(Z.shape[1]):
            try:
                c = la.cho_factor(Ss + Z @ Z.T, lower=True, check_finite=False)
            except la.LinAlgError:
                c = None
            if c is not None and np.diag(c[0]).min() ** 2 > 1e-13:
                def solve(b):
                    y = la.cho_solve(c, b, check_finite=False)
                    return y - Z @ (Z.T @ y)
                factor = Factor(solve, scale, "pseudo-inverse")
                factor.defect, factor.null = Z.shape[1], Z * scale[:, None]
                return factor
    with shared_product(EIGH_FLOPS * Ss.shape[0] ** 3):    # (1203 unknowns: 0.24-0.27 s on one thread, 0.15 on two)
        w, V = np.linalg.eigh(Ss)
    keep = w > defect_tol * w.max()
    Vk, wk = V[:, keep], w[keep]
    factor = Factor(lambda b: Vk @ ((Vk.T @ b) / (wk if b.ndim == 1 else wk[:, None])), scale, "pseudo-inverse")
    factor.defect, factor.null = int((~keep).sum()), V[:, ~keep] * scale[:, None]
    return factor


#: blocks of up to this many images are adjusted with one BLAS thread: their dense products and factorisations
#: (reduced systems up to about 2000 unknowns) are too small to share between threads, and waking the second
#: thread for each call costs more than it saves on this kind of machine (BAL problem-49: 2.0-2.4 s against
#: 2.4-2.9 s with two threads; the 28- and 200-image blocks neither gain nor lose). Larger blocks keep the
#: BLAS's own threads (the dense and banded factorisations of thousands of unknowns use them).
SINGLE_THREAD_IMAGES = 300
#: multiply-adds of a symmetric eigendecomposition with its vectors, per cubed unknown (about)
EIGH_FLOPS = 4.0
#: inside such a block, one dense product of at least this many multiply-adds gets the caller's threads back
#: (:func:`shared_product`): the leverages' j_d L of 32,000 rows by 257 WAP columns took 84 ms on one thread, 53 ms
#: on two, while a whole workflow on two threads throughout was 2 s slower
SHARED_PRODUCT_FLOPS = 5e8

_caller_threads: list[int] = []        # the callers' BLAS threads of the one-thread contexts entered, innermost last


@functools.cache
def _blas():
    """threadpoolctl's controller of the BLAS libraries NumPy and SciPy loaded, found once (each
    ``threadpool_limits`` call searches the process's libraries again: 3 ms)."""
    from threadpoolctl import ThreadpoolController
    return ThreadpoolController().select(user_api="blas")


@contextlib.contextmanager
def blas_threads(n_images: int):
    """A context in which BLAS runs on one thread if the block has at most SINGLE_THREAD_IMAGES images (the
    caller's setting is restored after it); otherwise a context that changes nothing."""
    if n_images > SINGLE_THREAD_IMAGES:
        yield
        return
    blas = _blas()
    caller = max((lib.num_threads for lib in blas.lib_controllers), default=1)
    with blas.limit(limits=1):
        _caller_threads.append(caller)
        try:
            yield
        finally:
            _caller_threads.pop()


@contextlib.contextmanager
def blas_on_one_thread():
    """BLAS on one thread, and no product takes the caller's threads back (:func:`shared_product`): for the
    threads of a pass over the chunks (:mod:`selfcal.adjust.parallel`), which are the parallelism there."""
    blas = _blas()
    caller = max((lib.num_threads for lib in blas.lib_controllers), default=1)
    with contextlib.ExitStack() as stack:
        if caller > 1:
            stack.enter_context(blas.limit(limits=1))
        _caller_threads.append(1)
        try:
            yield
        finally:
            _caller_threads.pop()


def shared_product(multiply_adds: float):
    """A context for one dense product of ``multiply_adds``: inside :func:`blas_threads`' one-thread limit, a
    product of at least SHARED_PRODUCT_FLOPS runs on the caller's threads; anything else is left as it is."""
    if multiply_adds < SHARED_PRODUCT_FLOPS or not _caller_threads or _caller_threads[-1] <= 1:
        return contextlib.nullcontext()
    return _blas().limit(limits=_caller_threads[-1])


#: a column with more non-zeros than this share of the rows is put in the border (camera parameters)
BORDER_SHARE = 0.1
#: the banded path is taken when the reverse Cuthill-McKee bandwidth is below this share of the size
BAND_SHARE = 0.25
#: with CHOLMOD installed, the banded path is taken while its n w^2 flops stay below this (narrow strips, such as
#: two strips of 132 images: n w^2 = 5.7e6). An iteration's factorisation of the strip blocks of 504 images
#: (n w^2 = 1.2e9) took 0.08 s banded against 0.056 s by CHOLMOD on two BLAS threads, of 1000 images (4.5e9)
#: 0.27-0.29 against 0.145-0.153 s (on one thread banded won there: 0.21 against 0.29 s), of 2000 images (1.6e10)
#: 0.40 against 0.31 s, of 5000 images (1.6e11) 4.19 against 1.35 s (CHOLMOD on OpenBLAS; on ATLAS it lost up to
#: 2000 images)
BAND_FLOPS = 1e9


def band_structure(Ss: sp.csc_matrix):
    """(border, perm, width) of S when its image part has a narrow band, else None.

    ``border``: the columns with more than BORDER_SHARE of the rows non-zero (the parameters that
    couple every image); ``perm``: the others in reverse Cuthill-McKee order; ``width``: the half
    bandwidth of S[perm][:, perm].
    """
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n = Ss.shape[0]
    counts = np.diff(Ss.indptr)
    border = np.flatnonzero(counts > BORDER_SHARE * n)
    inner = np.setdiff1d(np.arange(n), border)
    if inner.size < 1000 or border.size > 0.1 * n:
        return None
    A = Ss[inner][:, inner].tocsr()
    order = reverse_cuthill_mckee(A, symmetric_mode=True)
    P = A[order][:, order].tocoo()
    width = int(np.max(P.row - P.col, initial=0))
    if width > BAND_SHARE * inner.size:
        return None
    return border, inner[order], width


def _band_flops(band) -> float:
    border, perm, width = band
    return float(perm.size) * float(width + 1) ** 2


def _bordered_banded(Ss: sp.csc_matrix, band, rcond: float):
    """Solve function of S by a banded Cholesky factorisation with a dense border.

    The image part of a strip-structured block becomes a narrow band under the reverse
    Cuthill-McKee ordering; the few columns that couple every image (interior orientation,
    APs, shift/drift) would make the band as wide as the matrix, so they form a border:
    with S = [[A, B], [B^T, C]], A = L L^T (LAPACK pbtrf on the band) and the Schur
    complement C - B^T A^-1 B factorised densely. On the 1000-image block this takes 0.09 s
    against SuperLU's 0.2 s, the 2000-image block 0.2 s against 0.7 s.
    """
    border, perm, width = band
    P = Ss[perm][:, perm].tocoo()
    lower = P.row >= P.col
    offset = (P.row - P.col)[lower]
    stored = np.zeros((width + 1, perm.size))
    stored[offset, P.col[lower]] = P.data[lower]
    try:
        chol = la.cholesky_banded(stored, lower=True, check_finite=False)
    except la.LinAlgError as exc:
        raise SingularSystem(f"not positive definite ({exc})") from None
    if (chol[0] ** 2).min() < rcond:
        raise SingularSystem(f"numerically singular (smallest scaled pivot {(chol[0] ** 2).min():.1e})")
    # position k of the band holds unknown perm[k]

    def band_solve(b):
        return la.cho_solve_banded((chol, True), b, check_finite=False)

    B = Ss[perm][:, border].toarray()
    X = band_solve(B) if border.size else np.zeros((perm.size, 0))
    C = Ss[border][:, border].toarray() - B.T @ X
    if border.size:
        try:
            c_factor = la.cho_factor(C, lower=True, check_finite=False)
        except la.LinAlgError as exc:
            raise SingularSystem(f"not positive definite in the border ({exc})") from None
        if (np.diag(c_factor[0]) ** 2).min() < rcond:
            raise SingularSystem("numerically singular (the parameters coupling every image)")

    def solve(b):
        y = band_solve(b[perm])
        out = np.empty_like(b, dtype=float)
        if border.size:
            x_c = la.cho_solve(c_factor, b[border] - B.T @ y, check_finite=False)
            y = y - X @ x_c
            out[border] = x_c
        out[perm] = y
        return out
    return solve


def null_directions(S: np.ndarray | sp.csr_matrix | sp.csc_matrix, names: list[str], tol: float = 1e-10,
                    top: int = 6) -> list[str]:
    """Describe the (near) null space of S: for each direction, the unknowns it moves most.

    Used to turn a singular system into a message a user can act on
    ("the datum is not fixed", "c and Z0 cannot be separated").
    """
    S = S.toarray() if sp.issparse(S) else np.asarray(S)
    if S.shape[0] > DENSE_LIMIT:
        return ["(system too large for a null-space analysis)"]
    d = np.diag(S).copy()
    d[d <= 0] = 1.0
    s = 1.0 / np.sqrt(d)
    w, v = np.linalg.eigh(S * s[:, None] * s[None, :])
    out = []
    for k in np.flatnonzero(w < tol * max(w.max(), 1.0))[:5]:
        vec = v[:, k]
        order = np.argsort(-np.abs(vec))[:top]
        parts = ", ".join(f"{names[i]} ({vec[i]:+.2f})" for i in order)
        out.append(f"eigenvalue {w[k]:.1e}: {parts}")
    return out


def rank_one_update(a: np.ndarray, alpha: float, x: np.ndarray, y: np.ndarray) -> None:
    """a += alpha x y^T in place, by BLAS dger on a's Fortran-ordered view (no temporary of a's size: the sweeps of
    the screening's eliminations, a few hundred per round on matrices of a few hundred unknowns)."""
    from scipy.linalg.blas import dger
    if a.flags.f_contiguous:
        out = dger(alpha, x, y, a=a, overwrite_a=1)
    elif a.flags.c_contiguous:
        out = dger(alpha, y, x, a=a.T, overwrite_a=1)
    else:
        a += alpha * np.outer(x, y)
        return
    assert np.shares_memory(out, a)
