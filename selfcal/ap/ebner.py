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

from ._polynomial import PolynomialSet, gram_polynomials
from .base import APModel, ImageFrame


class EbnerAP(APModel):
    family = "ebner"
    examples = ("ebner",)

    def __init__(self, frame: ImageFrame):
        super().__init__(frame)
        self._set = PolynomialSet(gram_polynomials(3), frame.width_mm / 2, frame.height_mm / 2)

    @property
    def spec(self) -> str:
        return "ebner"

    @property
    def parameter_names(self) -> list[str]:
        return self._set.names

    def basis(self, x_mm, y_mm):
        return self._set.evaluate(x_mm, y_mm)

    def basis_derivatives(self, x_mm, y_mm):
        bxx, byx = self._set.evaluate(x_mm, y_mm, dx=True)
        bxy, byy = self._set.evaluate(x_mm, y_mm, dy=True)
        return bxx, bxy, byx, byy

    @classmethod
    def from_spec(cls, option, frame, observed_xy_mm=None, **settings):
        if option is not None:
            raise ValueError(f"AP model 'ebner' takes no option, found 'ebner:{option}'")
        return cls(frame)
