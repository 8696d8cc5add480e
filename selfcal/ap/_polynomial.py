"""Bivariate orthogonal-polynomial AP sets (Ebner, Grün, Legendre) built one way.

Coordinates are normalised to the frame, u = 2x/W and v = 2y/H in [-1, 1].
Each set uses univariate polynomials P_0 .. P_n orthogonal on [-1, 1] (over
grid nodes for Ebner and Grün, continuously for Legendre) and all products
P_i(u) P_j(v), i, j <= n, for Delta_x and Delta_y separately, except the
low-order fields that the interior and exterior orientation absorb:

* constants (principal point), scale (principal distance), rotation (kappa)
  and the two projective fields of omega and phi.

Of the twelve low-order fields (1, u, v, P2(u), uv, P2(v) in each coordinate)
six remain, in Ebner's (1976) combinations:

    e1 = (u, -v)            affinity
    e2 = (v, u)             shear
    e3 = (-2 P2(u), uv)     e4 = (uv, -2 P2(v))
    e5 = (P2(v), 0)         e6 = (0, P2(u))

so a set of degree n has 2 (n + 1)^2 - 6 parameters: Ebner 12 (n = 2),
Grün 44 (n = 4), Legendre 66 (n = 5).
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import polynomial as P

from .base import APModel, ImageFrame

__all__ = ["gram_polynomials", "legendre_polynomials", "PolynomialSet", "PolynomialAP"]


def gram_polynomials(nodes: int) -> list[np.ndarray]:
    """Monic polynomials P_0..P_{nodes-1} orthogonal over ``nodes`` equally spaced points in [-1, 1] (coefficients, low first)."""
    t = np.linspace(-1.0, 1.0, nodes)
    polys: list[np.ndarray] = []
    for degree in range(nodes):
        p = np.zeros(degree + 1)
        p[-1] = 1.0
        for q in polys:
            p = P.polysub(p, (np.dot(P.polyval(t, p), P.polyval(t, q)) / np.dot(P.polyval(t, q), P.polyval(t, q))) * q)
        polys.append(np.trim_zeros(p, "b") if np.any(p) else p)
    return polys


def legendre_polynomials(degree: int) -> list[np.ndarray]:
    """Legendre polynomials L_0..L_degree as power-series coefficients (low first)."""
    from numpy.polynomial import legendre as Lg
    return [Lg.leg2poly(np.eye(degree + 1)[k]) for k in range(degree + 1)]


_LOW = {(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)}


class PolynomialSet:
    """The basis of one orthogonal-polynomial AP set on a frame of half sizes (a, b) in mm."""

    def __init__(self, polys: list[np.ndarray], half_width_mm: float, half_height_mm: float):
        self.polys = polys
        self.deriv = [P.polyder(p) if len(p) > 1 else np.zeros(1) for p in polys]
        self.a, self.b = half_width_mm, half_height_mm
        n = len(polys) - 1
        self.terms = [(i, j) for j in range(n + 1) for i in range(n + 1) if (i, j) not in _LOW]
        self.names = [f"e{k}" for k in range(1, 7)]
        self.names += [f"x[{i},{j}]" for i, j in self.terms] + [f"y[{i},{j}]" for i, j in self.terms]

    def _values(self, u, coeffs):
        return np.stack([P.polyval(u, c) for c in coeffs], axis=1)

    def evaluate(self, x_mm, y_mm, dx=False, dy=False):
        """(Bx, By), each (n, n_params), or their derivative per mm in x (dx) or y (dy)."""
        u = np.asarray(x_mm, float) / self.a
        v = np.asarray(y_mm, float) / self.b
        Pu = self._values(u, self.deriv if dx else self.polys) * (1.0 / self.a if dx else 1.0)
        Pv = self._values(v, self.deriv if dy else self.polys) * (1.0 / self.b if dy else 1.0)
        n = len(u)
        zero = np.zeros(n)
        # low-order combinations (products written out so that derivatives follow the same rule)
        U, V = Pu[:, 1], Pv[:, 1]
        U0, V0 = Pu[:, 0], Pv[:, 0]
        P2u, P2v = Pu[:, 2] * V0, U0 * Pv[:, 2]
        uv = U * V
        u1, v1 = U * V0, U0 * V
        low_x = np.stack([u1, v1, -2.0 * P2u, uv, P2v, zero], axis=1)
        low_y = np.stack([-v1, u1, uv, -2.0 * P2v, zero, P2u], axis=1)
        T = np.stack([Pu[:, i] * Pv[:, j] for i, j in self.terms], axis=1)
        Z = np.zeros_like(T)
        return (np.concatenate([low_x, T, Z], axis=1), np.concatenate([low_y, Z, T], axis=1))


class PolynomialAP(APModel):
    """An AP family of one orthogonal-polynomial set: the subclass gives its univariate polynomials
    (:meth:`polynomials`), its spec and how an option chooses them."""

    def __init__(self, frame: ImageFrame, option: int | None = None):
        super().__init__(frame)
        self.option = option
        self._set = PolynomialSet(self.polynomials(option), frame.width_mm / 2, frame.height_mm / 2)

    @classmethod
    def polynomials(cls, option: int | None) -> list[np.ndarray]:
        raise NotImplementedError

    @property
    def spec(self) -> str:
        return self.family if self.option is None else f"{self.family}:{self.option}"

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
    def parse_option(cls, option: str) -> int:
        raise ValueError(f"AP model '{cls.family}' takes no option, found '{cls.family}:{option}'")

    @classmethod
    def from_spec(cls, option, frame, observed_xy_mm=None, **settings):
        return cls(frame, None if option is None else cls.parse_option(option))
