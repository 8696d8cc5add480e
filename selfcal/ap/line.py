"""Additional parameters along the detector line of a pushbroom camera (beyond seeds 000 and 001).

``wavelet1d:NAME`` models the systematic error of each CCD chip of a camera's virtual array as
1-D scaling functions of :mod:`selfcal.wavelets` (the families of the frame WAPs): on chip c,
spanning columns [a_c, b_c), t = (col - a_c) / (b_c - a_c) · G_c with G_c cells, the basis is
phi(t + k) for every translation k whose effective support meets [0, G_c] (zero off the chip),
and the along-track and across-track displacements of the detectors have coefficient sets of
their own (pixels):

    detector(col) = nominal(col) + p (sum_i a_i B_i(col), sum_i b_i B_i(col)).

The grid G (``--grid``) is the number of cells over the whole line, shared among the chips by
their widths (at least 2 per chip).

Datum: a constant and a linear function along the line are in the span of every chip's basis
(partition of unity), and they are what the attitude and the focal length do to the detector
line (a constant along-track offset is pitch, along-track linear yaw, across-track constant roll,
across-track linear the focal length). Every basis function is therefore made orthogonal, over
the line, to {1, s} (s = (col - centre) / columns), as the frame WAPs are to the camera fields,
and the functions that become dependent are left out (the last of a greedy orthogonalisation of the
sampled basis, ties to the first listed: :func:`selfcal.ap.base.independent_functions`;
``REPRODUCTION_TOLERANCE``). The attitude keeps the constant and linear parts.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..wavelets import check_wavelet_name, get_wavelet
from .base import independent_functions

__all__ = ["LineWaveletAP", "create_line_ap", "SAMPLES_PER_CELL", "REPRODUCTION_TOLERANCE"]

#: the line is sampled this densely (per grid cell) for the orthogonalisation
SAMPLES_PER_CELL = 64
#: a field of {1, s} that the raw basis reproduces to this relative RMS over the line makes one
#: orthogonalised function (nearly) dependent: the last of a greedy orthogonalisation is left out for it
REPRODUCTION_TOLERANCE = 0.01


@dataclass(frozen=True)
class LineWaveletAP:
    wavelet: str
    columns: int
    center_col: float
    chips: tuple[tuple[int, int], ...]           # [first, end) columns of every chip
    cells: tuple[int, ...]                        # grid cells per chip
    translations: tuple[tuple[int, ...], ...]     # k of every raw function, per chip
    keep: np.ndarray = field(repr=False)          # indices of the raw functions kept
    projection: np.ndarray = field(repr=False)    # (2, n_raw): coefficients of {1, s} taken off each

    family = "wavelet1d"
    settings = ("grid",)
    domain = "line"

    @classmethod
    def check_option(cls, option) -> None:
        """ValueError unless ``wavelet1d:option`` names a wavelet (checked without building the basis)."""
        if not option:
            raise ValueError("unknown pushbroom AP model 'wavelet1d' (known: wavelet1d:NAME, NAME = dbN, symN, "
                             "meyer, blN)")
        check_wavelet_name(option)
    examples = ()            # the frame contract tests do not apply; tests/test_line_ap.py tests the line basis

    @property
    def spec(self) -> str:
        return f"wavelet1d:{self.wavelet}"

    @property
    def size(self) -> int:
        """Number of coefficients: along and across for every kept function."""
        return 2 * len(self.keep)

    @property
    def n_params(self) -> int:
        return self.size

    @property
    def parameter_names(self) -> list[str]:
        return self.names

    def to_dict(self) -> dict:
        return {"spec": self.spec, "columns": self.columns, "chips": [list(c) for c in self.chips],
                "cells": list(self.cells)}

    @property
    def names(self) -> list[str]:
        labels = [f"c{c + 1}k{k:+d}" for c, ks in enumerate(self.translations) for k in ks]
        kept = [labels[i] for i in self.keep]
        return [f"along_{n}" for n in kept] + [f"across_{n}" for n in kept]

    def _raw(self, col: np.ndarray) -> np.ndarray:
        w = get_wavelet(self.wavelet)
        out = []
        for (first, end), cells, ks in zip(self.chips, self.cells, self.translations):
            inside = (col >= first) & (col < end)
            t = (col - first) / (end - first) * cells
            out += [np.where(inside, w.phi(t + k), 0.0) for k in ks]
        return np.stack(out, -1)

    def _fields(self, col: np.ndarray) -> np.ndarray:
        s = (col - self.center_col) / self.columns
        return np.stack([np.ones_like(s), s], -1)

    def basis(self, col) -> np.ndarray:
        """B (n, m): the kept, orthogonalised functions at columns col (dimensionless)."""
        col = np.atleast_1d(np.asarray(col, float))
        B = self._raw(col) - self._fields(col) @ self.projection
        return B[:, self.keep]

    def displacement_px(self, col, coefficients) -> np.ndarray:
        """(n, 2): the along- and across-track detector displacement in pixels."""
        B = self.basis(col)
        m = len(self.keep)
        return np.stack([B @ coefficients[:m], B @ coefficients[m:]], -1)


def orthogonal_beyond(raw: np.ndarray, fields: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Sampled basis functions ``raw`` (n, m) made orthogonal to the sampled ``fields`` (n, f) that another part of
    the model represents: (the indices of the functions kept, the projection (f, m) taken off each). Each field that
    the raw span reproduces to ``tolerance`` (relative RMS) costs one function, the last of a greedy
    orthogonalisation (:func:`selfcal.ap.base.independent_functions`)."""
    projection = np.linalg.lstsq(fields, raw, rcond=None)[0]
    orthogonal = raw - fields @ projection
    # the fields' part outside the raw span, from the normal equations of the raw functions (translates of a
    # scaling function: a well-conditioned Gram matrix), not lstsq's SVD of the samples (1.6 s at 8,192 samples of
    # 262 functions, for each of a jitter choice's levels)
    fit = np.linalg.lstsq(raw.T @ raw, raw.T @ fields, rcond=None)[0]
    misfit = np.linalg.norm(fields - raw @ fit, axis=0) / np.linalg.norm(fields, axis=0)
    n_dependent = int(np.sum(misfit < tolerance))
    return np.flatnonzero(independent_functions(orthogonal.T @ orthogonal, n_dependent)), projection


def create_line_ap(spec: str, columns: int, center_col: float, chip_starts=(), grid: int = 12) -> LineWaveletAP:
    """``wavelet1d:NAME`` for a line of ``columns`` detectors in chips starting at ``chip_starts``."""
    family, _, name = spec.partition(":")
    if family != LineWaveletAP.family or not name:
        raise ValueError(f"unknown pushbroom AP model '{spec}' (known: wavelet1d:NAME, NAME = dbN, symN, meyer, blN)")
    w = get_wavelet(name)
    edges = [0, *sorted(int(c) for c in chip_starts), int(columns)]
    chips = tuple((a, b) for a, b in zip(edges[:-1], edges[1:]))
    cells = tuple(max(2, int(round(grid * (b - a) / columns))) for a, b in chips)
    lo, hi = w.support
    translations = tuple(tuple(range(int(np.floor(lo - g)) + 1, int(np.ceil(hi)))) for g in cells)
    draft = LineWaveletAP(name, int(columns), float(center_col), chips, cells, translations,
                          np.arange(sum(len(k) for k in translations)), np.zeros((2, 0)))
    samples = np.concatenate([np.linspace(a, b, SAMPLES_PER_CELL * g, endpoint=False) + 0.5 * (b - a) /
                              (SAMPLES_PER_CELL * g) for (a, b), g in zip(chips, cells)])
    keep, projection = orthogonal_beyond(draft._raw(samples), draft._fields(samples), REPRODUCTION_TOLERANCE)
    return LineWaveletAP(name, int(columns), float(center_col), chips, cells, translations, keep, projection)

