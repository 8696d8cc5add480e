"""``gruen``: Grün's (1978) 44 orthogonal fourth-order bivariate polynomials.

Grün, A. (1978): Progress in photogrammetric point determination by
compensation of systematic errors and detection of gross errors. ISP
Symposium, Commission III, Moscow. The polynomials are orthogonal over a 5x5
grid of image points: here the monic Gram polynomials P0..P4 over
{-1, -1/2, 0, 1/2, 1} in u = 2x/W, v = 2y/H, all products P_i(u) P_j(v)
(i, j <= 4) for Delta_x and Delta_y, less the six fields that interior and
exterior orientation absorb, with Ebner's six low-order combinations kept
(see selfcal.ap._polynomial). Ours: this construction reproduces the
structure and count of Grün's set; the parameter naming is ours.
"""
from __future__ import annotations

from ._polynomial import PolynomialAP, gram_polynomials


class GruenAP(PolynomialAP):
    family = "gruen"
    examples = ("gruen",)

    @classmethod
    def polynomials(cls, option):
        return gram_polynomials(5)
