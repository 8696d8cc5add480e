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

from ._polynomial import PolynomialSet, gram_polynomials
from .base import APModel, ImageFrame


class GruenAP(APModel):
    family = "gruen"
    examples = ("gruen",)

    def __init__(self, frame: ImageFrame):
        super().__init__(frame)
        self._set = PolynomialSet(gram_polynomials(5), frame.width_mm / 2, frame.height_mm / 2)

    @property
    def spec(self) -> str:
        return "gruen"

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
            raise ValueError(f"AP model 'gruen' takes no option, found 'gruen:{option}'")
        return cls(frame)
