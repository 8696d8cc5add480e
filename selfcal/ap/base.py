"""The contract every additional-parameter (AP) family fulfils.

An AP family models the systematic image errors of Eq. (1) of seed 000 as a
*linear basis*,

    Delta_x(x, y) = p · sum_i a_i Bx_i(x, y)
    Delta_y(x, y) = p · sum_i a_i By_i(x, y)

where (x, y) are photo coordinates in millimetres (DESIGN.md §2), p is the pixel
size in millimetres, the basis functions are dimensionless and the
coefficients a_i are in **pixels**. Delta is what Eq. (1) adds to the ideal
projection: observed = ideal + Delta. Because the basis is evaluated at the
measured photo coordinates, Delta is linear in the coefficients and their
Jacobian is the basis matrix itself.

A family is a subclass of :class:`APModel` registered by name in
:mod:`selfcal.ap` (one file, one registry line).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

__all__ = ["ImageFrame", "APModel", "parse_ap_spec"]


@dataclass(frozen=True)
class ImageFrame:
    """The image format an AP model lives on: photo coordinates span
    x in [-width_mm/2, width_mm/2], y in [-height_mm/2, height_mm/2]."""

    width_mm: float
    height_mm: float
    pixel_size_mm: float

    def normalised(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Photo coordinates scaled to [-1, 1] over the frame."""
        return 2.0 * np.asarray(x_mm) / self.width_mm, 2.0 * np.asarray(y_mm) / self.height_mm


def parse_ap_spec(spec: str) -> tuple[str, str | None]:
    """Split ``"family[:option]"`` into its parts: ``"wavelet:db4"`` -> (``"wavelet"``, ``"db4"``)."""
    family, _, option = spec.strip().partition(":")
    return family.lower(), (option or None)


class APModel(ABC):
    """A linear basis of additional parameters on one image frame."""

    #: registry name of the family
    family: str = ""
    #: specs the contract tests build (e.g. ``("legendre", "legendre:3")``)
    examples: tuple[str, ...] = ()
    #: the settings it takes besides its option (``("grid",)`` for wavelets on a grid)
    settings: tuple[str, ...] = ()
    #: where it lives: ``"frame"`` (photo coordinates over an image) or ``"line"`` (a detector line)
    domain: str = "frame"

    def __init__(self, frame: ImageFrame):
        self.frame = frame

    @property
    @abstractmethod
    def spec(self) -> str:
        """The name that recreates this model, e.g. ``"wavelet:db4"``."""

    @property
    @abstractmethod
    def parameter_names(self) -> list[str]:
        """One name per coefficient, in basis order."""

    @property
    def n_params(self) -> int:
        return len(self.parameter_names)

    @abstractmethod
    def basis(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Basis matrices (Bx, By), each of shape (n, n_params), at photo coordinates."""

    def basis_derivatives(self, x_mm: np.ndarray, y_mm: np.ndarray):
        """Derivatives of the basis per millimetre of photo coordinate.

        Returns
        -------
        dBx_dx, dBx_dy, dBy_dx, dBy_dy : ndarray, each (n, n_params)

        Used to invert Delta (undistortion maps, exports); the contract tests
        compare them with finite differences.
        """
        raise NotImplementedError(f"{type(self).__name__} has no basis derivatives")

    def displacement_px(self, x_mm, y_mm, coefficients_px) -> tuple[np.ndarray, np.ndarray]:
        """Delta in pixels along the photo axes (x right, y up) at photo coordinates."""
        bx, by = self.basis(np.atleast_1d(x_mm), np.atleast_1d(y_mm))
        a = np.asarray(coefficients_px, float)
        return bx @ a, by @ a

    def to_dict(self) -> dict:
        """Everything needed to rebuild the basis (the coefficients are not part of it)."""
        return {"spec": self.spec}

    @classmethod
    @abstractmethod
    def from_spec(cls, option: str | None, frame: ImageFrame, observed_xy_mm: np.ndarray | None = None,
                  **settings) -> "APModel":
        """Build the model named ``family:option`` for a frame (and its observations, for adaptive bases)."""

    @classmethod
    def check_option(cls, option: str | None) -> None:
        """ValueError unless ``family:option`` names a model; by default it is built on a nominal frame (families
        whose basis takes long to build check their option without building it)."""
        cls.from_spec(option, ImageFrame(36.0, 24.0, 0.006))

    @classmethod
    def from_dict(cls, data: dict, frame: ImageFrame) -> "APModel":
        _, option = parse_ap_spec(data["spec"])
        return cls.from_spec(option, frame)
