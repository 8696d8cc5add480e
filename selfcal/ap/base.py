"""The contract every additional-parameter (AP) family fulfils.

An AP family models the systematic image errors of Eq. (1) of seed 000 as a
*linear basis*,

    Delta_x(x, y) = p · sum_i a_i Bx_i(x, y)
    Delta_y(x, y) = p · sum_i a_i By_i(x, y)

where (x, y) are photo coordinates in millimetres (DESIGN.md §2), p is the pixel
size in millimetres, the basis functions are dimensionless and the
coefficients a_i are in **pixels**. Delta is what Eq. (1) adds to the ideal
projection: observed = ideal + Delta. Because the basis is evaluated at the
measured photo coordinates, Delta is linear in the coefficients and their
Jacobian is the basis matrix itself.

A family is a subclass of :class:`APModel` registered by name in
:mod:`selfcal.ap` (one file, one registry line).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

__all__ = ["ImageFrame", "APModel", "SparseBasis", "pattern_groups", "parse_ap_spec", "independent_functions",
           "TIE_TOLERANCE"]

#: two functions whose squared norms orthogonal to the ones kept so far agree to this share are tied
#: (:func:`independent_functions`); rounding moves them by about 1e-13
TIE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class ImageFrame:
    """The image format an AP model lives on: photo coordinates span
    x in [-width_mm/2, width_mm/2], y in [-height_mm/2, height_mm/2]."""

    width_mm: float
    height_mm: float
    pixel_size_mm: float

    def normalised(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Photo coordinates scaled to [-1, 1] over the frame."""
        return 2.0 * np.asarray(x_mm) / self.width_mm, 2.0 * np.asarray(y_mm) / self.height_mm


@dataclass(frozen=True)
class SparseBasis:
    """The basis matrices of a family whose functions have local support, as sparse rows times a fixed map:
    row i of Bx is the vector with ``values[i, 0]`` at the raw columns ``columns[pattern[i], 0]`` (zero
    elsewhere) times ``to_params``; By likewise with index 1. Observations of one pattern share their raw
    columns (for a wavelet basis: those in one cell of the translations), so products over them are dense
    blocks of a few raw columns instead of all parameters."""

    pattern: np.ndarray          # (n,) int: each observation's pattern
    columns: np.ndarray          # (n_patterns, 2, K) int: the raw columns of a pattern's x and y rows
    values: np.ndarray           # (n, 2, K): each observation's x and y rows at them
    to_params: np.ndarray        # (n_raw, n_params): raw columns to the parameters

    def times_map(self, start: int = 0, stop: int | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """Rows start:stop of (Bx, By) as one (stop - start, 2, n_params) array, written into ``out`` if given:
        each pattern's rows times the map's rows of its raw columns, one product per pattern and axis."""
        stop = len(self.pattern) if stop is None else stop
        out = np.empty((stop - start, 2, self.to_params.shape[1])) if out is None else out
        pattern = self.pattern[start:stop]
        for rows in pattern_groups(pattern):
            for k in range(2):
                out[rows, k] = self.values[start + rows, k] @ self.to_params[self.columns[pattern[rows[0]], k]]
        return out

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """(Bx, By), each (n, n_params)."""
        rows = self.times_map()
        return rows[:, 0], rows[:, 1]


def pattern_groups(pattern: np.ndarray) -> list[np.ndarray]:
    """The positions of each pattern's rows in ``pattern`` (a :class:`SparseBasis`'s, or a part of it), one
    array per pattern present, in pattern order."""
    order = np.argsort(pattern, kind="stable")
    first = np.flatnonzero(np.r_[True, pattern[order][1:] != pattern[order][:-1]])
    return np.split(order, first[1:])


def independent_functions(gram: np.ndarray, n_dependent: int) -> np.ndarray:
    """Which of n functions to keep (bool, n) when ``n_dependent`` of them are (nearly) dependent on the others.

    ``gram`` is their (n, n) Gram matrix. The functions are scaled to unit norm and orthogonalised greedily:
    each step keeps the function with the largest norm orthogonal to those kept so far (a pivoted Cholesky
    factorisation of the Gram matrix), and the last ``n_dependent`` are left out. Squared norms that agree to
    :data:`TIE_TOLERANCE` (relative) are tied, and the function listed first is kept. In exact arithmetic
    LAPACK's pivoted QR (geqp3, which also takes the first of equal norms) chooses the same functions. In
    floating point its choice among functions whose norms tie up to rounding depends on the machine's BLAS and
    the order of its sums; this choice does not, so an adjustment names the same parameters on every machine."""
    n = gram.shape[0]
    n_kept = n - max(int(n_dependent), 0)
    if n_kept >= n:
        return np.ones(n, bool)
    kept = np.zeros(n, bool)
    norms = np.sqrt(np.maximum(np.diag(gram), 0.0))
    scale = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 0.0)
    G = gram * scale[:, None] * scale[None, :]
    remaining = np.diag(G).copy()               # squared norms orthogonal to the kept functions
    L = np.zeros((n, n_kept))
    for step in range(n_kept):
        candidates = np.where(kept, -np.inf, remaining)
        best = candidates.max()
        j = int(np.flatnonzero(candidates >= best - TIE_TOLERANCE * abs(best))[0])
        kept[j] = True
        if best <= 0.0:
            continue
        column = (G[:, j] - L[:, :step] @ L[j, :step]) / np.sqrt(best)
        L[:, step] = column
        remaining -= column * column
    return kept


def parse_ap_spec(spec: str) -> tuple[str, str | None]:
    """Split ``"family[:option]"`` into its parts: ``"wavelet:db4"`` -> (``"wavelet"``, ``"db4"``)."""
    family, _, option = spec.strip().partition(":")
    return family.lower(), (option or None)


class APModel(ABC):
    """A linear basis of additional parameters on one image frame."""

    #: registry name of the family
    family: str = ""
    #: specs the contract tests build (e.g. ``("legendre", "legendre:3")``)
    examples: tuple[str, ...] = ()
    #: the settings it takes besides its option (``("grid",)`` for wavelets on a grid)
    settings: tuple[str, ...] = ()
    #: where it lives: ``"frame"`` (photo coordinates over an image) or ``"line"`` (a detector line)
    domain: str = "frame"

    def __init__(self, frame: ImageFrame):
        self.frame = frame

    @property
    @abstractmethod
    def spec(self) -> str:
        """The name that recreates this model, e.g. ``"wavelet:db4"``."""

    @property
    @abstractmethod
    def parameter_names(self) -> list[str]:
        """One name per coefficient, in basis order."""

    @property
    def n_params(self) -> int:
        return len(self.parameter_names)

    @abstractmethod
    def basis(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Basis matrices (Bx, By), each of shape (n, n_params), at photo coordinates."""

    def sparse_basis(self, x_mm: np.ndarray, y_mm: np.ndarray) -> SparseBasis | None:
        """The basis at photo coordinates as a :class:`SparseBasis`, or None: the rows are dense (the default)."""
        return None

    def basis_derivatives(self, x_mm: np.ndarray, y_mm: np.ndarray):
        """Derivatives of the basis per millimetre of photo coordinate.

        Returns
        -------
        dBx_dx, dBx_dy, dBy_dx, dBy_dy : ndarray, each (n, n_params)

        Used to invert Delta (undistortion maps, exports); the contract tests
        compare them with finite differences.
        """
        raise NotImplementedError(f"{type(self).__name__} has no basis derivatives")

    def support_counts(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray | None:
        """For a basis of local functions, how many of the points (photo coordinates) lie in each coefficient's
        support, (n_params,); None for a basis of global functions (the default: polynomials, Fourier terms)."""
        return None

    def displacement_px(self, x_mm, y_mm, coefficients_px) -> tuple[np.ndarray, np.ndarray]:
        """Delta in pixels along the photo axes (x right, y up) at photo coordinates."""
        bx, by = self.basis(np.atleast_1d(x_mm), np.atleast_1d(y_mm))
        a = np.asarray(coefficients_px, float)
        return bx @ a, by @ a

    def to_dict(self) -> dict:
        """Everything needed to rebuild the basis (the coefficients are not part of it)."""
        return {"spec": self.spec}

    @classmethod
    @abstractmethod
    def from_spec(cls, option: str | None, frame: ImageFrame, observed_xy_mm: np.ndarray | None = None,
                  **settings) -> "APModel":
        """Build the model named ``family:option`` for a frame (and its observations, for adaptive bases)."""

    @classmethod
    def check_option(cls, option: str | None) -> None:
        """ValueError unless ``family:option`` names a model; by default it is built on a nominal frame (families
        whose basis takes long to build check their option without building it)."""
        cls.from_spec(option, ImageFrame(36.0, 24.0, 0.006))

    @classmethod
    def from_dict(cls, data: dict, frame: ImageFrame) -> "APModel":
        _, option = parse_ap_spec(data["spec"])
        return cls.from_spec(option, frame)
