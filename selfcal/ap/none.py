"""``none``: no additional parameters (the uncompensated case of seed 000)."""
from __future__ import annotations

import numpy as np

from .base import APModel, ImageFrame


class NoAP(APModel):
    family = "none"
    examples = ("none",)

    def __init__(self, frame: ImageFrame | None = None):
        """No additional parameters on ``frame``; None for a sensor whose images have no frame (a detector line,
        an RPC image), and then the model has no :attr:`frame` at all."""
        if frame is not None:
            super().__init__(frame)

    @property
    def spec(self) -> str:
        return "none"

    @property
    def parameter_names(self) -> list[str]:
        return []

    def basis(self, x_mm, y_mm):
        n = np.shape(x_mm)[0]
        return np.zeros((n, 0)), np.zeros((n, 0))

    def basis_derivatives(self, x_mm, y_mm):
        n = np.shape(x_mm)[0]
        zero = np.zeros((n, 0))
        return zero, zero, zero, zero

    @classmethod
    def from_spec(cls, option, frame: ImageFrame, observed_xy_mm=None, **settings):
        if option is not None:
            raise ValueError(f"AP model 'none' takes no option, found 'none:{option}'")
        return cls(frame)
