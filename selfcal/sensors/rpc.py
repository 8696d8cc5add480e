"""The rational polynomial (RPC, rational function) sensor model, with its analytic Jacobian.

A vendor RPC maps ground to image (the *inverse* model of DIMAP, the only one used here):
with normalised ground coordinates

    L = (lon - long_off) / long_scale,   P = (lat - lat_off) / lat_scale,   H = (h - height_off) / height_scale

(lon, lat in degrees, h in metres above the WGS 84 ellipsoid), the normalised image coordinates are
ratios of cubic polynomials,

    r = Num_L(P, L, H) / Den_L(P, L, H),     c = Num_S(P, L, H) / Den_S(P, L, H),

and the file's image coordinates line = r * line_scale + line_off, samp = c * samp_scale + samp_off.
Each polynomial has 20 coefficients in the RPC00B (NITF STDI-0002) order of :data:`RPC00B_TERMS`:

    1, L, P, H, LP, LH, PH, L², P², H², PLH, L³, LP², LH², L²P, P³, PH², L²H, P²H, H³.

Pixel convention (DESIGN.md §2): selfcal's (row, col) put the upper-left corner of the first pixel at
(0, 0), its centre at (0.5, 0.5). The RPC's line/samp are in the convention of the file it came from;
:attr:`RpcModel.pixel_origin` is the file's coordinate of the centre of the first pixel (1 for Pleiades
DIMAP, 0 for OSSIM .geom keyword lists), set by the reader, and

    row = line - pixel_origin + 0.5,     col = samp - pixel_origin + 0.5.

Ground-to-image is explicit (:meth:`RpcModel.project`); image-to-ground at a given height
(:meth:`RpcModel.localize`) solves the forward model for (lon, lat) by Newton's method.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RPC00B_TERMS", "RpcModel", "rpc00b_terms", "LOCALIZE_TOLERANCE_PX", "LOCALIZE_STEP_TOLERANCE_DEG",
           "LOCALIZE_MAX_ITERATIONS"]

#: the 20 monomials of an RPC00B polynomial, in file order (L = longitude, P = latitude, H = height)
RPC00B_TERMS = ("1", "L", "P", "H", "LP", "LH", "PH", "L2", "P2", "H2",
                "PLH", "L3", "LP2", "LH2", "L2P", "P3", "PH2", "L2H", "P2H", "H3")
#: localize stops when both image coordinates of the forward model are this close to the target
LOCALIZE_TOLERANCE_PX = 1e-9
#: ... or when the Newton step is below this (degrees, about 0.1 µm on the ground)
LOCALIZE_STEP_TOLERANCE_DEG = 1e-12
#: points still outside the tolerance after this many Newton steps get NaN
LOCALIZE_MAX_ITERATIONS = 30


def rpc00b_terms(L, P, H, derivatives: bool = False):
    """The 20 RPC00B monomials (..., 20) at normalised (L, P, H); with ``derivatives`` also their
    partial derivatives with respect to L, P and H, each (..., 20)."""
    L, P, H = np.broadcast_arrays(*(np.asarray(v, float) for v in (L, P, H)))
    one, zero = np.ones_like(L), np.zeros_like(L)
    terms = np.stack([one, L, P, H, L * P, L * H, P * H, L * L, P * P, H * H,
                      P * L * H, L ** 3, L * P * P, L * H * H, L * L * P, P ** 3, P * H * H, L * L * H, P * P * H,
                      H ** 3], -1)
    if not derivatives:
        return terms
    d_L = np.stack([zero, one, zero, zero, P, H, zero, 2 * L, zero, zero,
                    P * H, 3 * L * L, P * P, H * H, 2 * L * P, zero, zero, 2 * L * H, zero, zero], -1)
    d_P = np.stack([zero, zero, one, zero, L, zero, H, zero, 2 * P, zero,
                    L * H, zero, 2 * L * P, zero, L * L, 3 * P * P, H * H, zero, 2 * P * H, zero], -1)
    d_H = np.stack([zero, zero, zero, one, zero, L, P, zero, zero, 2 * H,
                    L * P, zero, zero, 2 * L * H, zero, zero, 2 * P * H, L * L, P * P, 3 * H * H], -1)
    return terms, (d_L, d_P, d_H)


def _coefficients(values, name: str) -> np.ndarray:
    values = np.asarray(values, float)
    if values.shape != (20,):
        raise ValueError(f"{name} needs 20 RPC00B coefficients, found shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name} has non-finite coefficients")
    return values


@dataclass(frozen=True, eq=False)
class RpcModel:
    """A ground-to-image rational polynomial model (RPC00B).

    Attributes
    ----------
    line_off, line_scale, samp_off, samp_scale : float
        Image normalisation, in the file's pixel convention (see ``pixel_origin``).
    lat_off, lat_scale, long_off, long_scale : float
        Ground normalisation in degrees (WGS 84 geodetic latitude and longitude).
    height_off, height_scale : float
        Height normalisation in metres above the ellipsoid.
    line_num, line_den, samp_num, samp_den : (20,) arrays
        Coefficients of the line and sample numerators and denominators, in the RPC00B order
        1, L, P, H, LP, LH, PH, L², P², H², PLH, L³, LP², LH², L²P, P³, PH², L²H, P²H, H³ with
        L the normalised longitude, P the normalised latitude, H the normalised height.
    pixel_origin : float
        The file's image coordinate of the centre of the first pixel (DIMAP: 1, OSSIM .geom: 0); the
        model returns selfcal's (row, col) = (line, samp) - pixel_origin + 0.5, whose first pixel centre is
        (0.5, 0.5). There is no default: the reader of each format states it.
    """

    line_off: float
    line_scale: float
    samp_off: float
    samp_scale: float
    lat_off: float
    lat_scale: float
    long_off: float
    long_scale: float
    height_off: float
    height_scale: float
    line_num: np.ndarray
    line_den: np.ndarray
    samp_num: np.ndarray
    samp_den: np.ndarray
    pixel_origin: float

    def __post_init__(self):
        for name in ("line_num", "line_den", "samp_num", "samp_den"):
            object.__setattr__(self, name, _coefficients(getattr(self, name), name))
        for name in ("line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale"):
            value = float(getattr(self, name))
            if not np.isfinite(value) or value == 0.0:
                raise ValueError(f"{name} must be finite and non-zero, not {value}")
            object.__setattr__(self, name, value)
        for name in ("line_off", "samp_off", "lat_off", "long_off", "height_off", "pixel_origin"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValueError(f"{name} must be finite, not {value}")
            object.__setattr__(self, name, value)

    @property
    def pixel_shift(self) -> float:
        """selfcal coordinate minus file coordinate: 0.5 - pixel_origin (px)."""
        return 0.5 - float(self.pixel_origin)

    def normalised_ground(self, lon_deg, lat_deg, h_m):
        """(L, P, H): longitude, latitude and height normalised by the model's offsets and scales."""
        return ((np.asarray(lon_deg, float) - self.long_off) / self.long_scale,
                (np.asarray(lat_deg, float) - self.lat_off) / self.lat_scale,
                (np.asarray(h_m, float) - self.height_off) / self.height_scale)

    def project(self, lon_deg, lat_deg, h_m, jacobian: bool = False):
        """Image coordinates (row, col) in px (selfcal convention) of ground points (broadcast arrays).

        With ``jacobian=True`` also returns J (..., 2, 3): the derivatives of (row, col) with respect
        to (lon_deg, lat_deg, h_m), in px/deg, px/deg and px/m.
        """
        L, P, H = self.normalised_ground(lon_deg, lat_deg, h_m)
        if not jacobian:
            terms = rpc00b_terms(L, P, H)
            r = (terms @ self.line_num) / (terms @ self.line_den)
            c = (terms @ self.samp_num) / (terms @ self.samp_den)
            return self._image(r, c)
        terms, d_terms = rpc00b_terms(L, P, H, derivatives=True)
        r, dr = _ratio(terms, d_terms, self.line_num, self.line_den)
        c, dc = _ratio(terms, d_terms, self.samp_num, self.samp_den)
        ground_scales = np.array([self.long_scale, self.lat_scale, self.height_scale])
        J = np.stack([dr * self.line_scale, dc * self.samp_scale], -2) / ground_scales
        row, col = self._image(r, c)
        return row, col, J

    def _image(self, r, c):
        shift = self.pixel_shift
        return r * self.line_scale + self.line_off + shift, c * self.samp_scale + self.samp_off + shift

    def localize(self, row_px, col_px, h_m, tolerance_px: float = LOCALIZE_TOLERANCE_PX,
                 max_iterations: int = LOCALIZE_MAX_ITERATIONS):
        """Ground (lon_deg, lat_deg) of image points (row, col) (selfcal convention) at heights h_m.

        Newton's method on the forward model, started at (long_off, lat_off): each point stops when
        both its image coordinates are within ``tolerance_px`` of the target or its step is below
        LOCALIZE_STEP_TOLERANCE_DEG; points that do not within ``max_iterations`` steps (or meet a
        singular Jacobian) get NaN. Inputs broadcast against each other.
        """
        row_px, col_px, h_m = np.broadcast_arrays(*(np.asarray(v, float) for v in (row_px, col_px, h_m)))
        shape = row_px.shape
        target = np.stack([row_px.ravel(), col_px.ravel()], -1)
        h = h_m.ravel()
        ground = np.tile([self.long_off, self.lat_off], (len(h), 1))
        active = np.all(np.isfinite(target), axis=1) & np.isfinite(h)
        converged = np.zeros(len(h), bool)
        for _ in range(max_iterations):
            if not active.any():
                break
            idx = np.flatnonzero(active)
            row, col, J = self.project(ground[idx, 0], ground[idx, 1], h[idx], jacobian=True)
            misfit = target[idx] - np.stack([row, col], -1)
            done = np.all(np.abs(misfit) <= tolerance_px, axis=1)
            converged[idx[done]] = True
            active[idx[done]] = False
            keep = ~done
            idx, misfit, J2 = idx[keep], misfit[keep], J[keep][:, :, :2]
            det = J2[:, 0, 0] * J2[:, 1, 1] - J2[:, 0, 1] * J2[:, 1, 0]
            singular = ~(np.abs(det) > 0) | ~np.isfinite(det)
            active[idx[singular]] = False
            idx, misfit, J2, det = idx[~singular], misfit[~singular], J2[~singular], det[~singular]
            step = np.stack([J2[:, 1, 1] * misfit[:, 0] - J2[:, 0, 1] * misfit[:, 1],
                             -J2[:, 1, 0] * misfit[:, 0] + J2[:, 0, 0] * misfit[:, 1]], -1) / det[:, None]
            ground[idx] += step
            small = np.all(np.abs(step) <= LOCALIZE_STEP_TOLERANCE_DEG, axis=1)
            converged[idx[small]] = True
            active[idx[small]] = False
        ground[~converged] = np.nan
        return ground[:, 0].reshape(shape), ground[:, 1].reshape(shape)


def _ratio(terms, d_terms, num, den):
    """n/d and its derivatives with respect to (L, P, H), (..., 3)."""
    n, d = terms @ num, terms @ den
    value = n / d
    grad = np.stack([(dt @ num - value * (dt @ den)) / d for dt in d_terms], -1)
    return value, grad
