"""``legendre[:deg]``: Legendre self-calibration APs (Tang et al. 2012a).

Tang, R., Fritsch, D., Cramer, M., Schneider, W. (2012): A flexible
mathematical method for camera calibration in digital aerial photogrammetry.
PE&RS 78(10): 1069-1077. Products L_i(u) L_j(v) of Legendre polynomials of
degree <= deg in u = 2x/W, v = 2y/H (continuous orthogonality on the frame),
for Delta_x and Delta_y separately, less the six low-order fields absorbed by
interior and exterior orientation; Ebner's six low-order combinations are
kept (selfcal.ap._polynomial): 2 (deg + 1)^2 - 6 parameters, 66 for the
default degree 5. Ours: the treatment of the low-order terms follows Ebner
rather than Tang's exclusion list.
"""
from __future__ import annotations

from ._polynomial import PolynomialSet, legendre_polynomials
from .base import APModel, ImageFrame

DEFAULT_DEGREE = 5


class LegendreAP(APModel):
    family = "legendre"
    examples = ("legendre", "legendre:3")

    def __init__(self, frame: ImageFrame, degree: int = DEFAULT_DEGREE):
        super().__init__(frame)
        self.degree = degree
        self._set = PolynomialSet(legendre_polynomials(degree), frame.width_mm / 2, frame.height_mm / 2)

    @property
    def spec(self) -> str:
        return "legendre" if self.degree == DEFAULT_DEGREE else f"legendre:{self.degree}"

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
        degree = DEFAULT_DEGREE
        if option is not None:
            try:
                degree = int(option)
            except ValueError:
                raise ValueError(f"legendre degree must be an integer 2..10, found '{option}'") from None
        if not 2 <= degree <= 10:
            raise ValueError(f"legendre degree must be an integer 2..10, found {degree}")
        return cls(frame, degree)
