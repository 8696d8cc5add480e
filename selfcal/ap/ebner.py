"""``ebner``: Ebner's (1976) 12 orthogonal second-order bivariate polynomials.

Ebner, H. (1976): Self calibrating block adjustment. Bildmessung und
Luftbildwesen 44: 128-139. Orthogonal over a 3x3 grid of image points; in
normalised coordinates u = 2x/W, v = 2y/H the grid is {-1, 0, 1}^2 and
P2(t) = t^2 - 2/3. Parameters e1..e6 are Ebner's b1..b6 (affinity, shear,
two quadratic combinations, P2(v) in Delta_x, P2(u) in Delta_y); the
products x[1,2], x[2,1], x[2,2], y[...] are his b7..b12. Ours: the
normalisation to the frame (Ebner uses the grid spacing b in mm).
"""
from __future__ import annotations

from ._polynomial import PolynomialAP, gram_polynomials


class EbnerAP(PolynomialAP):
    family = "ebner"
    examples = ("ebner",)

    @classmethod
    def polynomials(cls, option):
        return gram_polynomials(3)
