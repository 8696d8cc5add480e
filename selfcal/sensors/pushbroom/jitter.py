"""Attitude jitter of a line scanner as 1-D wavelet scaling functions in time (issue 42).

A line image's attitude is corrected by its sensor's polynomial in time (seed 001's bias and drift, Eq. 6;
usgscsm's degree up to 3, jigsaw's CKDEGREE). What oscillates faster (jitter: a fraction of a pixel to a
few pixels at several hertz) is modelled per image and per attitude axis as

    correction_a(t) = polynomial_a(t) + sum_k c_ak phi_k(tau),   tau = row / rows in [0, 1],

with phi_k(tau) = phi(tau G + k) the scaling functions of one of :mod:`selfcal.wavelets`' families at
level L (G = 2^L cells over the image's lines), every translation k whose effective support meets [0, G]:
the multi-resolution space V_L of seed 000's wavelet APs, in time instead of over the image plane.

Datum: the polynomial of the sensor is in the span of the scaling functions (a partition of unity and its
moments), so every function is made orthogonal, over the image's lines, to the powers of s = 2 tau - 1 up to
the sensor's degree, and the functions that become dependent are left out (as the line APs of
:mod:`selfcal.ap.line` do: :func:`selfcal.ap.base.independent_functions`). The polynomial keeps the slow part;
the coefficients c (rad, the functions being of order 1) are the jitter.

With ``+details`` the same space is spanned as V_(L-1) + W_(L-1): the scaling functions of level L - 1 and the
wavelets psi of level L - 1 (the details between the two resolutions, seed 000's split of scales), so that each
coefficient says at which scale the jitter is: the fit is the same (an orthogonal family's V_L), the terms and
their tests are by scale (``jitter_terms.csv``: ``L6k+3`` a scaling function, ``D6k+3`` a detail).

Names: ``wavelet1d:NAME`` (level chosen by the data: :mod:`selfcal.workflows.jitter`) or
``wavelet1d:NAME:LEVEL``, either with ``+details``; ``auto`` is ``wavelet1d:db4`` with the level chosen
(``auto+details`` the same with details).
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass, field, replace

import numpy as np

from ...ap.line import orthogonal_beyond
from ...errors import UsageError
from ...wavelets import check_wavelet_name, get_wavelet

__all__ = ["JitterSpec", "TimeWaveletBasis", "parse_jitter", "time_basis", "JITTER_LEVELS", "DEFAULT_WAVELET",
           "SAMPLES_PER_CELL"]

#: the suffix of a jitter basis split by scale (V_L as V_(L-1) + W_(L-1))
DETAILS = "+details"
#: the levels a jitter basis may have: 2^L cells over the image's lines
JITTER_LEVELS = range(0, 11)
#: the family of ``--jitter auto``
DEFAULT_WAVELET = "db4"
#: the lines are sampled this densely (per cell) for the orthogonalisation
SAMPLES_PER_CELL = 32
#: :meth:`TimeWaveletBasis.local` keeps its results for this many arrays of tau
LOCAL_CACHE_SIZE = 16
_LOCAL_LOCK = threading.Lock()
#: a power of s that the raw functions reproduce to this relative RMS costs one function
REPRODUCTION_TOLERANCE = 0.01


@dataclass(frozen=True)
class JitterSpec:
    """``--jitter``: the wavelet family and the level (None: chosen by the data), the attitude axes it corrects
    (None: every axis the sensor corrects) and the a-priori sigma of each coefficient (rad; None: free)."""

    wavelet: str = DEFAULT_WAVELET
    level: int | None = None
    axes: tuple[str, ...] | None = None
    sigma_rad: float | tuple[float, ...] | None = None

    details: bool = False

    @property
    def text(self) -> str:
        return f"wavelet1d:{self.wavelet}" + ("" if self.level is None else f":{self.level}") + \
            (DETAILS if self.details else "")

    def at_level(self, level: int) -> "JitterSpec":
        return JitterSpec(self.wavelet, int(level), self.axes, self.sigma_rad, self.details)


def parse_jitter(text: str | None) -> JitterSpec | None:
    """``none`` (None), ``auto`` or ``wavelet1d:NAME[:LEVEL]``, the last two with ``+details``; UsageError for
    anything else."""
    if text is None or text.strip().lower() in ("", "none"):
        return None
    text = text.strip()
    if text.lower().endswith(DETAILS):
        spec = parse_jitter(text[:-len(DETAILS)])
        if spec is None or spec.level == 0:
            raise UsageError(f"--jitter {text}: +details follows auto or wavelet1d:NAME[:LEVEL] of level 1 or more "
                             f"(the details of level L - 1 with its scaling functions span level L)")
        return replace(spec, details=True)
    if text.lower() == "auto":
        return JitterSpec()
    family, _, rest = text.partition(":")
    name, _, level = rest.partition(":")
    if family != "wavelet1d" or not name:
        raise UsageError(f"--jitter {text}: none, auto or wavelet1d:NAME[:LEVEL], with +details or without (NAME = "
                         f"dbN, symN, meyer, blN; LEVEL {JITTER_LEVELS.start}-{JITTER_LEVELS.stop - 1}: 2^LEVEL "
                         f"cells over an image's lines)")
    try:
        name = check_wavelet_name(name)
    except ValueError as exc:
        raise UsageError(f"--jitter {text}: {exc}") from None
    if level and (not level.isdigit() or int(level) not in JITTER_LEVELS):
        raise UsageError(f"--jitter {text}: the level is a whole number {JITTER_LEVELS.start}-"
                         f"{JITTER_LEVELS.stop - 1} (2^LEVEL cells over an image's lines), found {level!r}")
    return JitterSpec(name, int(level) if level else None)


@dataclass(frozen=True)
class TimeWaveletBasis:
    """The kept, orthogonalised scaling functions of one level over tau = row / rows in [0, 1] (with ``details``:
    the scaling functions and the wavelets of the level below, the same space)."""

    wavelet: str
    level: int
    degree: int                                     # the sensor's polynomial it is orthogonal to
    translations: tuple[int, ...]                   # k of every raw function (of each kind, with details)
    keep: np.ndarray = field(repr=False)            # indices of the raw functions kept
    projection: np.ndarray = field(repr=False)      # (degree + 1, n_raw): the polynomial taken off each
    details: bool = False                           # phi and psi of level - 1 instead of phi of level

    @property
    def cells(self) -> int:
        return 2 ** self.level

    @property
    def _scale(self) -> int:
        """2^l of the raw functions' level l (level, or level - 1 with details)."""
        return 2 ** (self.level - 1) if self.details else 2 ** self.level

    @property
    def _kinds(self) -> int:
        return 2 if self.details else 1

    @property
    def _amplitude(self) -> float:
        """The raw functions' factor: 1, and 2^-1/2 with details, whose functions cover twice the lines; the scaling
        functions and wavelets of an orthogonal family then have the L2 norm of level L's, so the same a-priori sigma
        of every coefficient is the same prior on the correction (and the fit the same as level L's)."""
        return float(np.sqrt(0.5)) if self.details else 1.0

    @property
    def size(self) -> int:
        return len(self.keep)

    @property
    def names(self) -> list[str]:
        n, level = len(self.translations), self.level - (1 if self.details else 0)
        return [f"{'L' if i < n else 'D'}{level}k{self.translations[i % n]:+d}" for i in self.keep]

    @property
    def n_powers(self) -> int:
        """The powers of s the functions are made orthogonal to (the sensor's polynomial: degree + 1)."""
        return self.degree + 1

    @functools.cached_property
    def reach(self) -> int:
        """How many raw functions may be non-zero at one tau: the length of the scaling function's table (beyond
        its effective support, which chose the translations, it has small tails; Daubechies' phi on [0, 2N - 1]
        is zero at both ends, so an open interval of that length holds them all), and one where its ends are not
        zero (Meyer's and Battle-Lemarie's tables cut their tails)."""
        w = get_wavelet(self.wavelet)
        return self._kinds * (int(np.ceil(w.x[-1] - w.x[0])) + (0 if self._open_ends else 1))

    @functools.cached_property
    def _open_ends(self) -> bool:
        w = get_wavelet(self.wavelet)
        return bool(w.phi_table[0] == 0.0 and w.phi_table[-1] == 0.0 and
                    (not self.details or (w.psi_table[0] == 0.0 and w.psi_table[-1] == 0.0)))

    @functools.cached_property
    def slot_peaks(self) -> np.ndarray:
        """(reach,): the largest |value| of the raw function kind of each of :meth:`local`'s slots (phi's, then psi's
        with details)."""
        w = get_wavelet(self.wavelet)
        per = self.reach // self._kinds
        peaks = [np.max(np.abs(w.phi_table))] + ([np.max(np.abs(w.psi_table))] if self.details else [])
        return self._amplitude * np.repeat(peaks, per)

    @functools.cached_property
    def kept_projection(self) -> np.ndarray:
        """(n_powers, size): the polynomial taken off each kept function."""
        return np.ascontiguousarray(self.projection[:, self.keep])

    def _raw(self, tau: np.ndarray) -> np.ndarray:
        w = get_wavelet(self.wavelet)
        x = tau * self._scale
        functions = (w.phi, w.psi) if self.details else (w.phi,)
        return self._amplitude * np.stack([f(x + k) for f in functions for k in self.translations], -1)

    def powers(self, tau) -> np.ndarray:
        """(n, n_powers): the powers of s = 2 tau - 1 the functions are orthogonal to."""
        s = 2.0 * np.atleast_1d(np.asarray(tau, float)) - 1.0
        out = np.empty((len(s), self.degree + 1))
        out[:, 0] = 1.0
        for k in range(1, self.degree + 1):
            np.multiply(out[:, k - 1], s, out=out[:, k])
        return out

    def __call__(self, tau) -> np.ndarray:
        """B (n, size) at tau = row / rows (dimensionless)."""
        tau = np.atleast_1d(np.asarray(tau, float))
        return (self._raw(tau) - self.powers(tau) @ self.projection)[:, self.keep]

    def local(self, tau) -> tuple[np.ndarray, np.ndarray]:
        """The raw functions that may be non-zero at each tau, :attr:`reach` of them: (index (n, reach) among the
        kept functions, -1 for none or one left out; their values (n, reach), 0.0 where the index is -1).
        B = sum of these values at their indices - :meth:`powers` @ :attr:`kept_projection`: a few functions per
        tau instead of all (what makes the jitter's Jacobian rows compact: :class:`WorkingColumns`)."""
        tau = np.atleast_1d(np.asarray(tau, float))
        key = (tau.size, hash(tau.tobytes()))
        with _LOCAL_LOCK:
            hit = self._local_cache.get(key)
        if hit is not None:
            return hit
        w = get_wavelet(self.wavelet)
        x = tau * self._scale
        per, n = self.reach // self._kinds, len(self.translations)
        first = np.floor(w.x[0] - x).astype(np.int64) + (1 if self._open_ends else 0)    # x + k > x0 (or >=)
        k = first[:, None] + np.arange(per)[None, :]
        raw = k - self.translations[0]
        position = np.full(self._kinds * n, -1, np.int64)
        position[self.keep] = np.arange(self.size)
        inside = (raw >= 0) & (raw < n)
        raw = np.clip(raw, 0, n - 1)
        index = np.where(inside, position[raw], -1)
        values = np.where(index >= 0, w.phi(x[:, None] + k), 0.0)
        if self.details:                    # the wavelets of the same translations, after the scaling functions
            detail = np.where(inside, position[n + raw], -1)
            index = np.concatenate([index, detail], axis=1)
            values = self._amplitude * np.concatenate([values, np.where(detail >= 0, w.psi(x[:, None] + k), 0.0)],
                                                      axis=1)
        with _LOCAL_LOCK:                   # (the threads of a pass evaluate images side by side)
            if len(self._local_cache) >= LOCAL_CACHE_SIZE:
                self._local_cache.pop(next(iter(self._local_cache)))
            self._local_cache[key] = (index, values)
        return index, values

    @functools.cached_property
    def _local_cache(self) -> dict:
        """:meth:`local` of the last few tau (an image's lines are the same in every evaluation of an adjustment)."""
        return {}

    def combine(self, tau, coefficients) -> np.ndarray:
        """B(tau) @ coefficients.T, (n, k) for ``coefficients`` (k, size), from :meth:`local`."""
        c = np.atleast_2d(np.asarray(coefficients, float))
        index, values = self.local(tau)
        padded = np.concatenate([c, np.zeros((len(c), 1))], axis=1)         # index -1: the zero column
        raw = np.einsum("nl,knl->nk", values, padded[:, index])
        return raw - self.powers(tau) @ (self.kept_projection @ c.T)

    def working_map(self, offset: int, power_columns: np.ndarray, power_scale: np.ndarray) -> np.ndarray:
        """T (width, width), width = offset + 3 size, of an image block whose first ``offset`` columns are the sensor's
        own and the coefficients of three axes follow: the working columns are the own columns, then per axis the
        kept raw functions, and a row of the image parameters is the working row times T. The powers taken off each
        function are the own columns ``power_columns`` (3, n_powers) times ``power_scale`` (n_powers,): d f /
        d(constant increment of axis a) s^k = power_scale[k] * (own column power_columns[a, k]), so that
        B_j = raw_j - sum_k s^k projection_kj costs an observation no column of its own."""
        m = self.size
        width = offset + 3 * m
        T = np.zeros((width, width))
        T[:offset, :offset] = np.eye(offset)
        for a in range(3):
            columns = offset + a * m + np.arange(m)
            T[columns, columns] = 1.0
            for k in range(self.n_powers):
                T[power_columns[a, k], columns] -= power_scale[k] * self.kept_projection[k]
        return T


@functools.lru_cache(maxsize=64)
def time_basis(wavelet: str, level: int, degree: int, details: bool = False) -> TimeWaveletBasis:
    """The jitter basis of ``wavelet`` at ``level``, orthogonal to the powers of s up to ``degree`` (with
    ``details``: the scaling functions and wavelets of ``level`` - 1)."""
    w = get_wavelet(wavelet)
    details = bool(details) and int(level) > 0
    cells = 2 ** (int(level) - (1 if details else 0))
    lo, hi = w.support
    if details:                         # the translations whose phi or psi meets the lines (psi's effective support
        big = np.flatnonzero(np.abs(w.psi_table) >= w.threshold * np.abs(w.psi_table).max())      # as phi's)
        lo, hi = min(lo, float(w.x[big[0]])), max(hi, float(w.x[big[-1]]))
    translations = tuple(range(int(np.floor(lo - cells)) + 1, int(np.ceil(hi))))
    n_raw = (2 if details else 1) * len(translations)
    draft = TimeWaveletBasis(wavelet, int(level), int(degree), translations, np.arange(n_raw),
                             np.zeros((degree + 1, n_raw)), details)
    n = SAMPLES_PER_CELL * max(cells, 8)
    tau = (np.arange(n) + 0.5) / n
    keep, projection = orthogonal_beyond(draft._raw(tau), draft.powers(tau), REPRODUCTION_TOLERANCE)
    if not keep.size:
        raise UsageError(f"--jitter wavelet1d:{wavelet}:{level}: no function of that level is left beyond the "
                         f"sensor's polynomial of degree {degree}; choose a higher level")
    return TimeWaveletBasis(wavelet, int(level), int(degree), translations, keep, projection, details)
