"""``fourier[:order]``: bivariate Fourier APs (Tang et al. 2012b).

Tang, R., Fritsch, D., Cramer, M. (2012): New rigorous and flexible Fourier
self-calibration models for airborne camera calibration. ISPRS J. 71: 76-85.
With u = 2x/W, v = 2y/H in [-1, 1] and the univariate functions
f_0 = 1, f_{2k-1} = cos(k pi u), f_{2k} = sin(k pi u) (k = 1..order), the
basis is every product f_i(u) f_j(v) for Delta_x and Delta_y separately,
except the constant (absorbed by the principal point):
2 ((2 order + 1)^2 - 1) parameters, 16 for the default order 1. Ours: the
selection of terms (Tang et al. derive theirs from the Laplace equation).
"""
from __future__ import annotations

import numpy as np

from .base import APModel, ImageFrame

DEFAULT_ORDER = 1


class FourierAP(APModel):
    family = "fourier"
    examples = ("fourier", "fourier:2")

    def __init__(self, frame: ImageFrame, order: int = DEFAULT_ORDER):
        super().__init__(frame)
        self.order = order
        n = 2 * order + 1
        self.terms = [(i, j) for j in range(n) for i in range(n) if (i, j) != (0, 0)]

    @property
    def spec(self) -> str:
        return "fourier" if self.order == DEFAULT_ORDER else f"fourier:{self.order}"

    @property
    def parameter_names(self) -> list[str]:
        return [f"x[{i},{j}]" for i, j in self.terms] + [f"y[{i},{j}]" for i, j in self.terms]

    def _functions(self, t, derivative=False):
        cols = [np.zeros_like(t) if derivative else np.ones_like(t)]
        for k in range(1, self.order + 1):
            w = k * np.pi
            if derivative:
                cols += [-w * np.sin(w * t), w * np.cos(w * t)]
            else:
                cols += [np.cos(w * t), np.sin(w * t)]
        return np.stack(cols, axis=1)

    def _evaluate(self, x_mm, y_mm, dx=False, dy=False):
        a, b = self.frame.width_mm / 2, self.frame.height_mm / 2
        Fu = self._functions(np.asarray(x_mm, float) / a, dx) * (1.0 / a if dx else 1.0)
        Fv = self._functions(np.asarray(y_mm, float) / b, dy) * (1.0 / b if dy else 1.0)
        T = np.stack([Fu[:, i] * Fv[:, j] for i, j in self.terms], axis=1)
        Z = np.zeros_like(T)
        return np.concatenate([T, Z], axis=1), np.concatenate([Z, T], axis=1)

    def basis(self, x_mm, y_mm):
        return self._evaluate(x_mm, y_mm)

    def basis_derivatives(self, x_mm, y_mm):
        bxx, byx = self._evaluate(x_mm, y_mm, dx=True)
        bxy, byy = self._evaluate(x_mm, y_mm, dy=True)
        return bxx, bxy, byx, byy

    @classmethod
    def from_spec(cls, option, frame, observed_xy_mm=None, **settings):
        order = DEFAULT_ORDER
        if option is not None:
            try:
                order = int(option)
            except ValueError:
                raise ValueError(f"fourier order must be an integer 1..5, found '{option}'") from None
        if not 1 <= order <= 5:
            raise ValueError(f"fourier order must be an integer 1..5, found {order}")
        return cls(frame, order)
