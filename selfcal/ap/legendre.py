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

from ._polynomial import PolynomialAP, legendre_polynomials

DEFAULT_DEGREE = 5


class LegendreAP(PolynomialAP):
    family = "legendre"
    examples = ("legendre", "legendre:3")

    def __init__(self, frame, option: int | None = None):
        super().__init__(frame, None if option == DEFAULT_DEGREE else option)

    @property
    def degree(self) -> int:
        return DEFAULT_DEGREE if self.option is None else self.option

    @classmethod
    def polynomials(cls, option):
        return legendre_polynomials(DEFAULT_DEGREE if option is None else option)

    @classmethod
    def parse_option(cls, option: str) -> int:
        try:
            degree = int(option)
        except ValueError:
            raise ValueError(f"legendre degree must be an integer 2..10, found '{option}'") from None
        if not 2 <= degree <= 10:
            raise ValueError(f"legendre degree must be an integer 2..10, found {degree}")
        return degree
