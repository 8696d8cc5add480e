"""``brown``: Brown's physical model (Brown 1971, 1976) in Fraser's (1997) form.

    Delta_x = x(k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 x^2) + 2 p2 x y + b1 x + b2 y
    Delta_y = y(k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 y^2)

Fraser, C. S. (1997): Digital camera self-calibration. ISPRS J. 52: 149-159.
Ours: (x, y) are taken about the frame centre (the engine estimates the
principal point separately and the basis must stay linear) and normalised by
the half-diagonal r0 of the frame, so that the coefficients are in pixels at
the frame corner; :meth:`BrownAP.physical` converts them to the usual units
(k1 in mm^-2, ..., about the frame centre).
"""
from __future__ import annotations

import numpy as np

from .base import APModel, ImageFrame

NAMES = ["k1", "k2", "k3", "p1", "p2", "b1", "b2"]


class BrownAP(APModel):
    family = "brown"
    examples = ("brown",)

    def __init__(self, frame: ImageFrame):
        super().__init__(frame)
        self.r0 = 0.5 * float(np.hypot(frame.width_mm, frame.height_mm))

    @property
    def spec(self) -> str:
        return "brown"

    @property
    def parameter_names(self) -> list[str]:
        return list(NAMES)

    def basis(self, x_mm, y_mm):
        u = np.asarray(x_mm, float) / self.r0
        v = np.asarray(y_mm, float) / self.r0
        r2 = u * u + v * v
        zero = np.zeros_like(u)
        bx = np.stack([u * r2, u * r2**2, u * r2**3, r2 + 2 * u * u, 2 * u * v, u, v], axis=1)
        by = np.stack([v * r2, v * r2**2, v * r2**3, 2 * u * v, r2 + 2 * v * v, zero, zero], axis=1)
        return bx, by

    def basis_derivatives(self, x_mm, y_mm):
        u = np.asarray(x_mm, float) / self.r0
        v = np.asarray(y_mm, float) / self.r0
        r2 = u * u + v * v
        s = 1.0 / self.r0
        zero, one = np.zeros_like(u), np.ones_like(u)
        # d/du and d/dv of each basis function, then per mm
        dbx_du = np.stack([r2 + 2 * u * u, r2**2 + 4 * u * u * r2, r2**3 + 6 * u * u * r2**2, 6 * u, 2 * v, one, zero], 1)
        dbx_dv = np.stack([2 * u * v, 4 * u * v * r2, 6 * u * v * r2**2, 2 * v, 2 * u, zero, one], 1)
        dby_du = np.stack([2 * u * v, 4 * u * v * r2, 6 * u * v * r2**2, 2 * v, 2 * u, zero, zero], 1)
        dby_dv = np.stack([r2 + 2 * v * v, r2**2 + 4 * v * v * r2, r2**3 + 6 * v * v * r2**2, 2 * u, 6 * v, zero, zero], 1)
        return s * dbx_du, s * dbx_dv, s * dby_du, s * dby_dv

    def physical(self, coefficients_px) -> dict[str, float]:
        """Coefficients in the usual units (Delta in mm, x and y in mm about the frame centre)."""
        a = np.asarray(coefficients_px, float) * self.frame.pixel_size_mm
        r0 = self.r0
        return {"k1_mm-2": a[0] / r0**3, "k2_mm-4": a[1] / r0**5, "k3_mm-6": a[2] / r0**7,
                "p1_mm-1": a[3] / r0**2, "p2_mm-1": a[4] / r0**2, "b1": a[5] / r0, "b2": a[6] / r0}

    def from_physical(self, values: dict[str, float]) -> np.ndarray:
        """Inverse of :meth:`physical`: coefficients in pixels."""
        r0 = self.r0
        a = np.array([values["k1_mm-2"] * r0**3, values["k2_mm-4"] * r0**5, values["k3_mm-6"] * r0**7,
                      values["p1_mm-1"] * r0**2, values["p2_mm-1"] * r0**2, values["b1"] * r0, values["b2"] * r0])
        return a / self.frame.pixel_size_mm

    @classmethod
    def from_spec(cls, option, frame, observed_xy_mm=None, **settings):
        if option is not None:
            raise ValueError(f"AP model 'brown' takes no option, found 'brown:{option}'")
        return cls(frame)
