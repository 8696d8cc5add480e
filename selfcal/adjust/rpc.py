"""Bias compensation of a vendor RPC in image space (Grodecki & Dial 2003), estimated from GCPs.

The RPC of a satellite image carries the error of its telemetry, which over the short arc of one
scene is an offset and a small drift in image space. Grodecki & Dial (2003) correct it by an
affine function of the image coordinates,

    row = row_rpc + a0 + a1 row_rpc + a2 col_rpc,
    col = col_rpc + b0 + b1 row_rpc + b2 col_rpc,

(``kind="affine"``, 6 parameters) or by its shift terms only (``kind="shift"``: a0, b0). Here
(row_rpc, col_rpc) = :meth:`~selfcal.sensors.rpc.RpcModel.project` of the ground point (px,
selfcal's convention), so the corrected model stays a function of the ground point alone; a0, b0
are in px, a1, a2, b1, b2 unitless (px per px).

With the ground of the GCPs known and their image coordinates measured, the parameters enter
linearly: :func:`adjust_rpc_bias` solves one weighted least-squares problem (no iteration) and
reports the a-posteriori statistics.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import AdjustmentError
from ..sensors.rpc import RpcModel

__all__ = ["BIAS_PARAMETERS", "MIN_GCPS", "RpcBias", "RpcBiasResult", "bias_design", "adjust_rpc_bias"]

#: parameter names of each kind, in the order of the parameter vector and the covariance
BIAS_PARAMETERS = {"shift": ("a0", "b0"), "affine": ("a0", "a1", "a2", "b0", "b1", "b2")}
#: fewest GCPs that determine each kind (two image coordinates per GCP)
MIN_GCPS = {"shift": 1, "affine": 3}
#: the scaled normal matrix is taken as singular beyond this condition number
_SINGULAR_CONDITION = 1e12


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
    def from_parameters(cls, kind: str, parameters) -> "RpcBias":
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

    def correction(self, row_rpc_px, col_rpc_px):
        """(d_row, d_col) in px added to the RPC's image coordinates."""
        row, col = np.asarray(row_rpc_px, float), np.asarray(col_rpc_px, float)
        return (self.a[0] + self.a[1] * row + self.a[2] * col,
                self.b[0] + self.b[1] * row + self.b[2] * col)

    def apply(self, row_rpc_px, col_rpc_px):
        """Corrected (row, col) in px of the RPC's image coordinates."""
        d_row, d_col = self.correction(row_rpc_px, col_rpc_px)
        return np.asarray(row_rpc_px, float) + d_row, np.asarray(col_rpc_px, float) + d_col

    def project(self, model: RpcModel, lon_deg, lat_deg, h_m):
        """Bias-corrected image coordinates (row, col) in px of ground points."""
        return self.apply(*model.project(lon_deg, lat_deg, h_m))


def bias_design(kind: str, row_rpc_px, col_rpc_px) -> np.ndarray:
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


@dataclass(frozen=True, eq=False)
class RpcBiasResult:
    """Outcome of :func:`adjust_rpc_bias`.

    Attributes
    ----------
    bias : RpcBias
        The estimate.
    parameter_names : tuple of str
        Order of the rows and columns of ``covariance``.
    covariance : (u, u) array
        A-posteriori covariance sigma0² Q_xx of the parameters (px² for a0, b0); with no redundancy
        sigma0 is unknown and the a-priori Q_xx (sigma0 = 1) is given.
    sigma0 : float
        A-posteriori standard deviation of unit weight, unitless: sqrt(v^T P v / r) with P = 1/sigma_px².
        About 1 when ``sigma_px`` is right; NaN when the redundancy is 0.
    residuals_px : (n, 2) array
        Measured minus corrected (row, col) of each GCP, px.
    redundancy : int
        2 n - u.
    redundancy_numbers : (n, 2) array
        Diagonal of I - A Q_xx A^T P for each (row, col) observation; they sum to ``redundancy``.
    """

    bias: RpcBias
    parameter_names: tuple[str, ...]
    covariance: np.ndarray
    sigma0: float
    residuals_px: np.ndarray
    redundancy: int
    redundancy_numbers: np.ndarray

    @property
    def sigmas(self) -> np.ndarray:
        """A-posteriori standard deviations of the parameters (order of ``parameter_names``)."""
        return np.sqrt(np.diag(self.covariance))


def _sigmas(sigma_px, n: int) -> np.ndarray:
    sigma = np.asarray(sigma_px, float)
    if sigma.ndim == 0 or sigma.shape == (n,):
        sigma = np.broadcast_to(sigma.reshape(-1, 1) if sigma.ndim else sigma, (n, 2))
    if sigma.shape != (n, 2):
        raise ValueError(f"sigma_px must be a scalar, (n,) or (n, 2) with n = {n}, found shape {sigma.shape}")
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ValueError("sigma_px must be positive and finite")
    return np.array(sigma)


def adjust_rpc_bias(model: RpcModel, lon_deg, lat_deg, h_m, row_obs_px, col_obs_px, sigma_px=1.0,
                    kind: str = "affine") -> RpcBiasResult:
    """Estimate the image-space bias of ``model`` from GCPs by weighted least squares.

    Parameters
    ----------
    model : RpcModel
    lon_deg, lat_deg, h_m : (n,) arrays
        Ground coordinates of the GCPs (taken as error-free).
    row_obs_px, col_obs_px : (n,) arrays
        Their measured image coordinates (selfcal's convention).
    sigma_px : float, (n,) or (n, 2)
        A-priori standard deviation of the image measurements (per point, or per row/col).
    kind : "affine" | "shift"
        The bias model (module docstring); affine needs at least 3 GCPs not on one line, shift 1.

    Raises
    ------
    AdjustmentError
        Too few GCPs, GCPs the RPC cannot project, or a singular system (GCPs on a line).
    """
    _check_kind(kind)
    lon, lat, h, row_obs, col_obs = (np.atleast_1d(np.asarray(v, float)).ravel()
                                     for v in (lon_deg, lat_deg, h_m, row_obs_px, col_obs_px))
    n = len(lon)
    if not all(len(v) == n for v in (lat, h, row_obs, col_obs)):
        raise ValueError("lon_deg, lat_deg, h_m, row_obs_px and col_obs_px must have the same length")
    if n < MIN_GCPS[kind]:
        raise AdjustmentError(f"the {kind} RPC bias needs at least {MIN_GCPS[kind]} GCPs, found {n}")
    sigma = _sigmas(sigma_px, n)
    row_rpc, col_rpc = model.project(lon, lat, h)
    observed = np.stack([row_obs, col_obs], -1)
    misclosure = observed - np.stack([row_rpc, col_rpc], -1)                 # l = measured - RPC, (n, 2)
    if not np.all(np.isfinite(misclosure)):
        bad = np.flatnonzero(~np.all(np.isfinite(misclosure), axis=1))
        raise AdjustmentError(f"GCPs {bad.tolist()} (0-based) have non-finite coordinates or projections")

    A = bias_design(kind, row_rpc, col_rpc)                                   # (n, 2, u)
    u = A.shape[-1]
    weights = 1.0 / sigma
    A_w = (A * weights[..., None]).reshape(2 * n, u)                          # whitened
    l_w = (misclosure * weights).ravel()
    column_scale = np.max(np.abs(A_w), axis=0)
    column_scale[column_scale == 0] = 1.0
    N = (A_w / column_scale).T @ (A_w / column_scale)
    if np.linalg.cond(N) > _SINGULAR_CONDITION:
        raise AdjustmentError(f"the {kind} RPC bias is not determined by these {n} GCPs "
                              f"(singular normal equations: GCPs on a line in the image?)")
    Q = np.linalg.inv(N) / np.outer(column_scale, column_scale)
    Q = 0.5 * (Q + Q.T)
    x = Q @ (A_w.T @ l_w)

    v_w = l_w - A_w @ x
    redundancy = 2 * n - u
    sigma0 = float(np.sqrt(v_w @ v_w / redundancy)) if redundancy > 0 else float("nan")
    covariance = (sigma0 ** 2 if redundancy > 0 else 1.0) * Q
    redundancy_numbers = 1.0 - np.einsum("ij,jk,ik->i", A_w, Q, A_w)
    return RpcBiasResult(RpcBias.from_parameters(kind, x), BIAS_PARAMETERS[kind], covariance, sigma0,
                         (v_w.reshape(n, 2) / weights), redundancy, redundancy_numbers.reshape(n, 2))
