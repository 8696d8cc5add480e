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

In an adjustment (:class:`RpcSensor`, ``model = "rpc"``) each image's RPC carries the error of its
telemetry, which over the short arc of one scene is an offset and a small drift in image space
(Grodecki & Dial 2003): an affine correction of the image coordinates,

    row = row_rpc + a0 + a1 row_rpc + a2 col_rpc,
    col = col_rpc + b0 + b1 row_rpc + b2 col_rpc,

(``bias = "affine"``, 6 parameters per image) or its shift terms only (``bias = "shift"``: a0, b0; the
others held at zero). a0, b0 are in px, a1, a2, b1, b2 unitless (px per px). Object points are ECEF.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal, overload

import numpy as np
from numpy.typing import ArrayLike

from ..geometry.earth import ecef_from_geodetic, geodetic_from_ecef, geodetic_jacobian
from .base import BoundSensor, ImageGeometry, Parameter, Sensor

__all__ = ["RPC00B_TERMS", "RpcModel", "rpc00b_terms", "LOCALIZE_TOLERANCE_PX", "LOCALIZE_STEP_TOLERANCE_DEG",
           "LOCALIZE_MAX_ITERATIONS", "BIAS_PARAMETERS", "RpcBias", "RpcCamera", "bias_design", "RpcSensor", "SENSOR",
           "shifted_rpc", "rpc_extent_px"]

#: the 20 monomials of an RPC00B polynomial, in file order (L = longitude, P = latitude, H = height)
RPC00B_TERMS = ("1", "L", "P", "H", "LP", "LH", "PH", "L2", "P2", "H2",
                "PLH", "L3", "LP2", "LH2", "L2P", "P3", "PH2", "L2H", "P2H", "H3")
#: localize stops when both image coordinates of the forward model are this close to the target
LOCALIZE_TOLERANCE_PX = 1e-9
#: ... or when the Newton step is below this (degrees, about 0.1 µm on the ground)
LOCALIZE_STEP_TOLERANCE_DEG = 1e-12
#: points still outside the tolerance after this many Newton steps get NaN
LOCALIZE_MAX_ITERATIONS = 30


def rpc00b_terms(L: ArrayLike, P: ArrayLike, H: ArrayLike, derivatives: bool = False):
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

    def normalised_ground(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(L, P, H): longitude, latitude and height normalised by the model's offsets and scales."""
        return ((np.asarray(lon_deg, float) - self.long_off) / self.long_scale,
                (np.asarray(lat_deg, float) - self.lat_off) / self.lat_scale,
                (np.asarray(h_m, float) - self.height_off) / self.height_scale)

    @overload
    def project(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike,
                jacobian: Literal[False] = False) -> tuple[np.ndarray, np.ndarray]: ...

    @overload
    def project(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike,
                jacobian: Literal[True]) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def project(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike, jacobian: bool = False
                ) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray]:
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

    def _image(self, r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        shift = self.pixel_shift
        return r * self.line_scale + self.line_off + shift, c * self.samp_scale + self.samp_off + shift

    def localize(self, row_px: ArrayLike, col_px: ArrayLike, h_m: ArrayLike,
                 tolerance_px: float = LOCALIZE_TOLERANCE_PX, max_iterations: int = LOCALIZE_MAX_ITERATIONS
                 ) -> tuple[np.ndarray, np.ndarray]:
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


# --- bias compensation (Grodecki & Dial 2003) ------------------------------------------------------

#: parameter names of each kind, in the order of the parameter vector and the covariance
BIAS_PARAMETERS = {"shift": ("a0", "b0"), "affine": ("a0", "a1", "a2", "b0", "b1", "b2")}


def _check_kind(kind: str) -> None:
    if kind not in BIAS_PARAMETERS:
        raise ValueError(f"kind must be one of {sorted(BIAS_PARAMETERS)}, not {kind!r}")


@dataclass(frozen=True)
class RpcBias:
    """Affine image-space correction of an RPC: row = row_rpc + a0 + a1 row_rpc + a2 col_rpc,
    col = col_rpc + b0 + b1 row_rpc + b2 col_rpc (a0, b0 in px; the others unitless). The shift-only
    kind has a1 = a2 = b1 = b2 = 0."""

    a: tuple[float, float, float] = (0.0, 0.0, 0.0)
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kind: str = "affine"

    def __post_init__(self):
        _check_kind(self.kind)
        object.__setattr__(self, "a", tuple(float(v) for v in self.a))
        object.__setattr__(self, "b", tuple(float(v) for v in self.b))
        if len(self.a) != 3 or len(self.b) != 3:
            raise ValueError("a and b are (offset, row term, col term)")
        if self.kind == "shift" and any(self.a[1:] + self.b[1:]):
            raise ValueError("a shift-only bias has a1 = a2 = b1 = b2 = 0")

    @classmethod
    def from_parameters(cls, kind: str, parameters: ArrayLike) -> "RpcBias":
        """The bias of a parameter vector in the order of ``BIAS_PARAMETERS[kind]``."""
        _check_kind(kind)
        x = np.asarray(parameters, float).ravel()
        if len(x) != len(BIAS_PARAMETERS[kind]):
            raise ValueError(f"{kind} bias has {len(BIAS_PARAMETERS[kind])} parameters, found {len(x)}")
        if kind == "shift":
            return cls((x[0], 0.0, 0.0), (x[1], 0.0, 0.0), "shift")
        return cls(tuple(x[:3]), tuple(x[3:]), "affine")

    @property
    def parameters(self) -> np.ndarray:
        """The parameter vector in the order of ``BIAS_PARAMETERS[kind]``."""
        if self.kind == "shift":
            return np.array([self.a[0], self.b[0]])
        return np.array(self.a + self.b)

    def correction(self, row_rpc_px: ArrayLike, col_rpc_px: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(d_row, d_col) in px added to the RPC's image coordinates."""
        row, col = np.asarray(row_rpc_px, float), np.asarray(col_rpc_px, float)
        return (self.a[0] + self.a[1] * row + self.a[2] * col,
                self.b[0] + self.b[1] * row + self.b[2] * col)

    def apply(self, row_rpc_px: ArrayLike, col_rpc_px: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Corrected (row, col) in px of the RPC's image coordinates."""
        d_row, d_col = self.correction(row_rpc_px, col_rpc_px)
        return np.asarray(row_rpc_px, float) + d_row, np.asarray(col_rpc_px, float) + d_col

    def project(self, model: RpcModel, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
                ) -> tuple[np.ndarray, np.ndarray]:
        """Bias-corrected image coordinates (row, col) in px of ground points."""
        return self.apply(*model.project(lon_deg, lat_deg, h_m))

    def remove(self, row_px: ArrayLike, col_px: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The RPC's (row_rpc, col_rpc) of corrected image coordinates: :meth:`apply` inverted."""
        A = np.array([[1.0 + self.a[1], self.a[2]], [self.b[1], 1.0 + self.b[2]]])
        row, col = np.broadcast_arrays(np.asarray(row_px, float) - self.a[0], np.asarray(col_px, float) - self.b[0])
        out = np.linalg.solve(A, np.stack([row.ravel(), col.ravel()]))
        return out[0].reshape(row.shape), out[1].reshape(row.shape)

    def localize(self, model: RpcModel, row_px: ArrayLike, col_px: ArrayLike, h_m: ArrayLike
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Ground (lon_deg, lat_deg) of bias-corrected image coordinates at heights h_m."""
        return model.localize(*self.remove(row_px, col_px), h_m)

    @property
    def is_shift(self) -> bool:
        """Whether the linear terms are all zero (a shift, whatever ``kind`` estimated it)."""
        return not any(self.a[1:] + self.b[1:])


def shifted_rpc(model: RpcModel, bias: RpcBias) -> RpcModel:
    """The RPC whose projection *is* ``bias.project(model, ...)`` for a shift bias, exactly: the image coordinate is
    ``line = r * line_scale + line_off`` (the offset added after the scale), so row = row_rpc + a0 is LINE_OFF + a0
    and col = col_rpc + b0 is SAMP_OFF + b0, in pixels, the coefficients untouched. An affine bias mixes the line's
    and the sample's rational functions (two denominators): it has no exact RPC (ValueError; fit one)."""
    if not bias.is_shift:
        raise ValueError("an affine bias with non-zero linear terms has no exact RPC; fit one (selfcal.sensors.rpc_fit)")
    return replace(model, line_off=model.line_off + bias.a[0], samp_off=model.samp_off + bias.b[0])


def rpc_extent_px(model: RpcModel) -> tuple[float, float]:
    """(rows, cols) of the image an RPC describes, from its image normalisation: its last line and sample,
    LINE_OFF + LINE_SCALE and SAMP_OFF + SAMP_SCALE, in selfcal's pixels (the image starts at 0)."""
    return (model.line_off + model.pixel_shift + abs(model.line_scale),
            model.samp_off + model.pixel_shift + abs(model.samp_scale))


def bias_design(kind: str, row_rpc_px: ArrayLike, col_rpc_px: ArrayLike) -> np.ndarray:
    """Design matrix (n, 2, u): the derivatives of (row, col) of each point with respect to the
    parameters of ``kind`` (order of ``BIAS_PARAMETERS[kind]``)."""
    _check_kind(kind)
    row, col = np.broadcast_arrays(np.atleast_1d(np.asarray(row_rpc_px, float)),
                                   np.atleast_1d(np.asarray(col_rpc_px, float)))
    one, zero = np.ones_like(row), np.zeros_like(row)
    if kind == "shift":
        return np.stack([np.stack([one, zero], -1), np.stack([zero, one], -1)], -2)
    return np.stack([np.stack([one, row, col, zero, zero, zero], -1),
                     np.stack([zero, zero, zero, one, row, col], -1)], -2)


# --- the sensor contract (selfcal.sensors.base) --------------------------------------------------

_BIAS_UNITS = {"a0": "px", "a1": "", "a2": "", "b0": "px", "b1": "", "b2": ""}


class RpcBound(BoundSensor):
    """RPC images of a problem: observations are the measured (col, row) in px."""

    def __init__(self, problem, block, o, pixel, sigma_px):
        from ..errors import BlockError
        self.problem = problem
        self.o = np.asarray(o)
        models = block.image_models or {}
        self.models = {}
        for i in np.unique(problem.obs_image[self.o]):
            image_id = block.images.image_id[i]
            if image_id not in models:
                raise BlockError("images.csv", f"image '{image_id}' of an rpc camera has no RPC (its sensor_file)",
                                 int(block.images.line[i]), "sensor_file")
            self.models[int(i)] = models[image_id]
        self.pixel = np.zeros((problem.n_image_observations, 2))
        self.pixel[self.o] = pixel
        self.sigma = np.repeat(np.asarray(sigma_px, float)[:, None], 2, axis=1)

    def observations(self):
        return self.pixel[self.o], self.sigma

    def context(self, state, jacobians: bool = True):
        return state.image

    def _rpc(self, img, points, jacobians):
        """(col, row) of the RPC (m, 2) and, with ``jacobians``, d(col, row)/d(X, Y, Z) (m, 2, 3)."""
        lat, lon, h = geodetic_from_ecef(points)
        out = np.zeros((len(img), 2))
        J = np.zeros((len(img), 2, 3)) if jacobians else None
        geodetic = geodetic_jacobian(points) if jacobians else None          # rows lat, lon (rad), h
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            model = self.models[int(i)]
            if J is not None and geodetic is not None:                       # jacobians
                row, col, J_llh = model.project(np.degrees(lon[sel]), np.degrees(lat[sel]), h[sel], jacobian=True)
                # (row, col) per (lon_deg, lat_deg, h) -> per (lat_rad, lon_rad, h) -> per ECEF
                J_rad = np.stack([J_llh[:, :, 1] * np.degrees(1.0), J_llh[:, :, 0] * np.degrees(1.0),
                                  J_llh[:, :, 2]], -1)
                J[sel] = (J_rad @ geodetic[sel])[:, ::-1]
            else:
                row, col = model.project(np.degrees(lon[sel]), np.degrees(lat[sel]), h[sel])
            out[sel] = np.column_stack([col, row])
        return out, J

    def predict(self, context, o, img, cam, points, jacobians):
        bias = context[img]                                   # a0, a1, a2, b0, b1, b2
        rpc, J = self._rpc(img, points, jacobians)
        col, row = rpc[:, 0], rpc[:, 1]
        f = np.column_stack([col + bias[:, 3] + bias[:, 4] * row + bias[:, 5] * col,
                             row + bias[:, 0] + bias[:, 1] * row + bias[:, 2] * col])
        if not jacobians:
            return f
        m = len(img)
        one, zero = np.ones(m), np.zeros(m)
        j_e = np.stack([np.stack([zero, zero, zero, one, row, col], -1),
                        np.stack([one, row, col, zero, zero, zero], -1)], 1)
        # d f / d(col_rpc, row_rpc): [[1 + b2, b1], [a2, 1 + a1]]
        D = np.stack([np.stack([1.0 + bias[:, 5], bias[:, 4]], -1), np.stack([bias[:, 2], 1.0 + bias[:, 1]], -1)], 1)
        return f, j_e, D @ J, np.zeros((m, 2, 0))

    def rays(self, context, img, pixel):
        """The line through the points of the image point at the top and the bottom of the model's height range."""
        origin, direction = np.zeros((len(img), 3)), np.zeros((len(img), 3))
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            model = self.models[int(i)]
            row, col = self._unbiased(context[int(i)], pixel[sel])
            ends = []
            for h in (model.height_off + model.height_scale, model.height_off - model.height_scale):
                lon, lat = model.localize(row, col, np.full(sel.size, h))
                ends.append(ecef_from_geodetic(np.radians(lat), np.radians(lon), np.full(sel.size, h)))
            d = ends[1] - ends[0]
            origin[sel], direction[sel] = ends[0], d / np.linalg.norm(d, axis=1, keepdims=True)
        return origin, direction

    @staticmethod
    def _unbiased(bias, pixel):
        """(row_rpc, col_rpc) of measured (col, row) under the bias: the affine map inverted."""
        A = np.array([[1.0 + bias[1], bias[2]], [bias[4], 1.0 + bias[5]]])
        rhs = np.column_stack([pixel[:, 1] - bias[0], pixel[:, 0] - bias[3]])
        rc = np.linalg.solve(A, rhs.T).T
        return rc[:, 0], rc[:, 1]

    def pixels(self, context, img, points):
        return self.predict(context, None, img, None, points, False)

    def height(self, points):
        """Ellipsoidal heights (WGS 84) of ECEF points."""
        return geodetic_from_ecef(points)[2]

    def ground_sample_distance(self, state):
        """Mean over images of the ground distance (m) of one pixel step along rows and columns at the centre of
        the image's observations, on the median height of their points."""
        img, pt = self.problem.obs_image[self.o], self.problem.obs_point[self.o]
        pixel = self.pixel[self.o]
        values = []
        for i in np.unique(img):
            sel = img == i
            height = float(np.nanmedian(self.height(state.points[pt[sel]])))
            centre = pixel[sel].mean(axis=0)
            ground = self.ground(state.image, np.full(3, i), centre + np.array([[0, 0], [1, 0], [0, 1]]), height)
            values.append(0.5 * (np.linalg.norm(ground[1] - ground[0]) + np.linalg.norm(ground[2] - ground[0])))
        return float(np.mean(values)) if values else None

    def ground(self, context, img, pixel, height):
        out = np.full((len(img), 3), np.nan)
        for i in np.unique(img):
            sel = np.flatnonzero(img == i)
            model = self.models[int(i)]
            row, col = self._unbiased(context[int(i)], pixel[sel])
            h = np.full(sel.size, float(model.height_off)) if callable(height) else \
                np.broadcast_to(np.asarray(height, float), img.shape)[sel].copy()
            for _ in range(8 if callable(height) else 1):
                lon, lat = model.localize(row, col, h)
                if callable(height):
                    h = np.asarray(height(lat, lon), float)
            out[sel] = ecef_from_geodetic(np.radians(lat), np.radians(lon), h)
        return out

    def pixel_residuals(self, o, v):
        return v


@dataclass(frozen=True)
class RpcCamera:
    """Images with vendor RPCs (``model = "rpc"``, DESIGN.md §3a): each image's RPC is its ``sensor_file``;
    the adjustment estimates an image-space ``bias`` per image, ``"shift"`` (a0, b0) or ``"affine"`` (six
    terms), or none (``"none"``: the tie points intersected through the RPCs as they are), weighted by
    ``sigma_bias_px`` when given (px; the linear terms by it over the larger image size: ``width_px``,
    ``height_px``, or where not given twice the larger scale of the image's RPC)."""

    camera_id: str
    bias: str = "affine"
    width_px: int | None = None
    height_px: int | None = None
    sigma_bias_px: float | None = None

    model = "rpc"
    pixel_size_mm = 1.0


class RpcSensor(Sensor):
    """A vendor RPC per image with an image-space bias (module docstring)."""

    name = "rpc"
    image_parameters = tuple(Parameter(n, _BIAS_UNITS[n], "EOP", screened=True) for n in BIAS_PARAMETERS["affine"])
    object_frame = "ECEF"
    min_points_per_image = 1
    camera_type = RpcCamera
    camera_keys = {
    "model": ("str", True),
    "bias": ("str", False),
    "width_px": ("int", False),
    "height_px": ("int", False),
    "sigma_bias_px": ("pos", False),
}

    def bind(self, problem, block, o, pixel, sigma_px, options):
        return RpcBound(problem, block, o, pixel, sigma_px)

    def check_camera(self, values):
        bias = values.get("bias", "affine")
        return [] if bias in BIAS_PARAMETERS or bias == "none" else \
            [("bias", f"bias must be \"shift\", \"affine\" or \"none\", found {bias!r}")]

    def image_setup(self, block, image_index, options):
        """The bias kind of the camera frees its terms; ``sigma_bias_px`` weights the shifts by it and the
        linear terms by it over the larger image size (the same displacement at the far edge)."""
        free, sigma = [], []
        for i in image_index:
            camera = block.cameras[block.images.camera_id[i]]
            free.append([name in BIAS_PARAMETERS.get(camera.bias, ()) for name in BIAS_PARAMETERS["affine"]])
            s = np.nan if camera.sigma_bias_px is None else float(camera.sigma_bias_px)
            size = float(max(camera.width_px or 0, camera.height_px or 0))
            model = (block.image_models or {}).get(block.images.image_id[i])
            if not size and model is not None:
                # an RPC's scales are half its image's extent (line = r * line_scale + line_off, |r| <= 1)
                size = 2.0 * max(abs(model.line_scale), abs(model.samp_scale))
            size = max(size, 1.0)
            sigma.append([s, s / size, s / size, s, s / size, s / size])
        return np.array(free, bool).reshape(-1, 6), np.array(sigma).reshape(-1, 6)

    def image_geometry(self, block, k, image_parameters, camera_parameters):
        """The image's RPC with its adjusted bias (a0, a1, a2, b0, b1, b2); ``rpc`` the exact corrected RPC
        when the linear terms are zero (:func:`shifted_rpc`). The image's size is its camera's ``height_px``,
        ``width_px`` where given, else the RPC's (:func:`rpc_extent_px`); its heights the RPC's HEIGHT_OFF -/+
        HEIGHT_SCALE."""
        image_id = str(block.images.image_id[k])
        model = (block.image_models or {})[image_id]
        camera = block.cameras[block.images.camera_id[k]]
        bias = RpcBias.from_parameters("affine", image_parameters)
        rows, cols = rpc_extent_px(model)
        rows, cols = float(camera.height_px or rows), float(camera.width_px or cols)
        heights = (model.height_off - abs(model.height_scale), model.height_off + abs(model.height_scale))
        return ImageGeometry(image_id, rows, cols,
                             lambda lon, lat, h: bias.project(model, lon, lat, h),
                             lambda row, col, h: bias.localize(model, row, col, h),
                             heights, shifted_rpc(model, bias) if bias.is_shift else None)


SENSOR = RpcSensor()
