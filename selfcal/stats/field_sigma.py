"""The uncertainty of an AP model's correction over the image, and the test of two independent calibrations of
one camera against each other (issue 40 item 5).

**The σ of the correction.** An AP family is a linear basis (:mod:`selfcal.ap.base`): at photo coordinates (x, y)
the correction is ``Delta_x = Bx(x, y) a``, ``Delta_y = By(x, y) a`` (pixels along the photo axes, x right, y up),
``a`` the camera's estimated AP coefficients (px). Its covariance is

    Sigma_Delta(x, y) = [Bx; By] Sigma_aa [Bx; By]^T          (2 x 2 at each (x, y))

with ``Sigma_aa = sigma0^2 Q_aa`` the a-posteriori covariance of the coefficients: their block of the inverse of
the whole normal matrix, so the uncertainty of everything estimated with them (c, x0, y0, the orientations, the
points, trajectory terms) is in it by marginalisation. The field itself holds no c, x0, y0: they are not
coefficients of the basis (a wavelet basis is even orthogonalised against their fields, :mod:`selfcal.ap.wavelet`).
Coefficients that screening held are not estimated and have no variance. :func:`field_covariance` gives the 2 x 2
blocks; ``sigma_norm = sqrt(var_x + var_y)`` is the RMS length of the error vector (the root of the trace), and
``sigma_major`` the standard deviation in the worst direction (the largest eigenvalue's root).

**Two calibrations compared** (:func:`compare_calibrations`): coefficients ``a1``, ``a2`` of the same basis, estimated
from disjoint observations (two halves of a block), with covariances ``C1``, ``C2``. Under a right model both
estimate the same coefficients: ``d = a1 - a2 ~ N(0, C1 + C2)`` and ``T = d^T (C1 + C2)^-1 d ~ chi2(k)``. The test
is made on the coefficients (where the field's nodes are strongly correlated, the coefficient space is their
exact, finite parametrisation); directions that the two halves do not determine numerically are left out: the
eigenvalues of the correlation matrix of ``d`` below :data:`DEFECT_TOLERANCE` times the largest (the engine's
tolerance for a datum defect). ``k`` counts the directions kept. The field of the difference and its σ on the
grid (:func:`field_covariance` of ``C1 + C2``) say where the two differ most (``|delta| / sigma`` per axis, at
nodes where the observations lie).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from .distributions import chi2_isf, chi2_sf

if TYPE_CHECKING:
    from ..adjust import AdjustmentResult

__all__ = ["FieldCovariance", "field_covariance", "observed_nodes", "CalibrationDifference", "compare_calibrations",
           "CorrectionSigma", "correction_sigma", "ap_estimate", "grid_nodes", "observed_pixels", "observed_radius_px",
           "estimated_frame_cameras", "HALF_BLOCK_ALPHA", "DEFECT_TOLERANCE", "OBSERVED_RADIUS_SHARE", "GRID_NODES"]

#: significance of the comparison of two half-block calibrations (the diagnosis's tests use the same)
HALF_BLOCK_ALPHA = 0.001
#: eigenvalues of the difference's correlation matrix below this share of the largest are directions the halves do
#: not determine (the engine's datum-defect tolerance, :func:`selfcal.adjust.engine._free_network_cofactor`)
DEFECT_TOLERANCE = 1e-10
#: a grid node is *observed* when an image observation lies within this share of the frame's width of it
OBSERVED_RADIUS_SHARE = 0.05
#: nodes across the frame of distortion_sigma.csv (as distortion_grid.csv: 61 x 41 on a 3:2 frame)
GRID_NODES = 61


@dataclass(frozen=True)
class FieldCovariance:
    """Covariance of a correction field at n points, px^2, along the photo axes (x right, y up)."""

    var_x: np.ndarray
    var_y: np.ndarray
    cov_xy: np.ndarray

    @property
    def sigma_x(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.var_x, 0.0))

    @property
    def sigma_y(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.var_y, 0.0))

    @property
    def rho(self) -> np.ndarray:
        """Correlation of the x and y components (NaN where either has no variance)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where((self.var_x > 0) & (self.var_y > 0), self.cov_xy / (self.sigma_x * self.sigma_y), np.nan)

    @property
    def sigma_norm(self) -> np.ndarray:
        """sqrt(var_x + var_y): the RMS length of the field's error vector."""
        return np.sqrt(np.maximum(self.var_x + self.var_y, 0.0))

    @property
    def sigma_major(self) -> np.ndarray:
        """The standard deviation in the worst direction: the root of the 2 x 2 block's largest eigenvalue."""
        half = 0.5 * (self.var_x + self.var_y)
        return np.sqrt(np.maximum(half + np.sqrt(0.25 * (self.var_x - self.var_y) ** 2 + self.cov_xy ** 2), 0.0))


def field_covariance(bx: np.ndarray, by: np.ndarray, covariance: np.ndarray) -> FieldCovariance:
    """The 2 x 2 covariance of ``Delta = (bx a, by a)`` at each of n points, given the basis rows ``bx``, ``by``
    (n, k) there and the covariance (k, k) of the coefficients ``a``."""
    bx, by = np.atleast_2d(bx), np.atleast_2d(by)
    C = np.asarray(covariance, float)
    if bx.shape[1] == 0:
        zero = np.zeros(bx.shape[0])
        return FieldCovariance(zero, zero, zero)
    gx, gy = bx @ C, by @ C
    return FieldCovariance(np.einsum("ij,ij->i", gx, bx), np.einsum("ij,ij->i", gy, by),
                           np.einsum("ij,ij->i", gx, by))


def observed_nodes(node_col: np.ndarray, node_row: np.ndarray, observed_px: np.ndarray, radius_px: float) -> np.ndarray:
    """Which nodes (bool, n) have an observation (``observed_px``: (m, 2) col, row) within ``radius_px``: the observed
    area of an image."""
    from scipy.spatial import cKDTree
    nodes = np.column_stack([node_col, node_row])
    if len(observed_px) == 0:
        return np.zeros(len(nodes), bool)
    tree = cKDTree(np.asarray(observed_px, float))
    distance, _ = tree.query(nodes, k=1, distance_upper_bound=radius_px)
    return np.isfinite(distance)


@dataclass(frozen=True)
class CalibrationDifference:
    """Two calibrations of one camera's AP coefficients compared (:func:`compare_calibrations`)."""

    statistic: float                 # T = d^T (C1 + C2)^-1 d over the determined directions
    dof: int                         # the directions kept
    n_coefficients: int
    p_value: float
    critical: float                  # chi2(dof) at 1 - alpha
    alpha: float
    difference: np.ndarray           # (n, 2) the field of a1 - a2 at the nodes, px, photo axes
    covariance: FieldCovariance      # its covariance there
    observed: np.ndarray             # (n,) bool: the nodes searched for the largest ratio
    largest_ratio: float             # the largest |difference| / sigma of one axis at an observed node
    largest_node: int                # its node (-1: none)
    largest_axis: int                # 0: x, 1: y

    @property
    def flag(self) -> bool:
        return bool(self.dof > 0 and self.p_value < self.alpha)

    @property
    def rms_difference_px(self) -> float:
        """RMS length of the difference field over the observed nodes."""
        d = self.difference[self.observed]
        return float(np.sqrt(np.mean(np.sum(d * d, axis=1)))) if len(d) else float("nan")


def compare_calibrations(a1: np.ndarray, covariance1: np.ndarray, a2: np.ndarray, covariance2: np.ndarray,
                         bx: np.ndarray, by: np.ndarray, observed: np.ndarray,
                         alpha: float = HALF_BLOCK_ALPHA) -> CalibrationDifference:
    """The test of two independent estimates of the same AP coefficients (module docstring), with the field of
    their difference at the nodes where the basis rows ``bx``, ``by`` (n, k) are given; ``observed`` (n,) marks
    the nodes searched for the largest ratio."""
    d = np.asarray(a1, float) - np.asarray(a2, float)
    C = np.asarray(covariance1, float) + np.asarray(covariance2, float)
    k = len(d)
    statistic, dof = 0.0, 0
    if k:
        scale = np.sqrt(np.clip(np.diag(C), 1e-300, None))
        w, V = np.linalg.eigh(C / scale[:, None] / scale[None, :])
        keep = w > DEFECT_TOLERANCE * w.max()
        z = V[:, keep].T @ (d / scale)
        statistic, dof = float(np.sum(z * z / w[keep])), int(keep.sum())
    p = float(chi2_sf(statistic, dof)) if dof else 1.0
    critical = float(chi2_isf(alpha, dof)) if dof else float("nan")
    field = np.column_stack([np.atleast_2d(bx) @ d, np.atleast_2d(by) @ d]) if k else np.zeros((len(bx), 2))
    cov = field_covariance(bx, by, C)
    sigma = np.column_stack([cov.sigma_x, cov.sigma_y])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(sigma > 0, np.abs(field) / sigma, np.nan)
    ratio[~np.asarray(observed, bool)] = np.nan
    if np.isfinite(ratio).any():
        flat = int(np.nanargmax(ratio))
        node, axis, largest = flat // 2, flat % 2, float(ratio.ravel()[flat])
    else:
        node, axis, largest = -1, 0, float("nan")
    return CalibrationDifference(statistic, dof, k, p, critical, alpha, field, cov, np.asarray(observed, bool),
                                 largest, node, axis)


# --- the correction's σ of an adjustment's cameras ------------------------------------------------------------------

def estimated_frame_cameras(result: AdjustmentResult) -> list[int]:
    """The cameras (indices in the problem) with a frame AP model and at least one estimated coefficient."""
    return [k for k, cam in enumerate(result.problem.cameras)
            if getattr(cam.ap, "frame", None) is not None and cam.free[cam.n_core:].any()]


def ap_estimate(result: AdjustmentResult, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera ``k``'s AP coefficients as estimated: (which are estimated (bool over its coefficients), their
    values (px), their a-posteriori covariance σ̂0² Q (px²): the block of the whole inverse)."""
    cam = result.problem.cameras[k]
    position = result.problem.d_offset[k] + np.cumsum(cam.free) - 1
    estimated = np.asarray(cam.free[cam.n_core:], bool)
    index = position[cam.n_core:][estimated]
    values = np.asarray(result.state.cameras[k][cam.n_core:], float)[estimated]
    Q = np.asarray(result.Q_theta[index[:, None], index[None, :]], float).reshape(len(index), len(index))
    return estimated, values, result.variance_factor * Q


def grid_nodes(result: AdjustmentResult, k: int, nodes_x: int = GRID_NODES
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Camera ``k``'s grid over its frame (that of distortion_grid.csv): photo coordinates x, y (mm) and pixels
    col, row of its nodes."""
    from ..ap import frame_nodes_mm
    from ..sensors.frame import pixel_from_photo
    cam = result.problem.cameras[k]
    cfg = result.block.cameras[cam.camera_id]
    x, y = frame_nodes_mm(cam.ap.frame, nodes_x)
    col, row = pixel_from_photo(np.column_stack([x, y]), cfg.width_px, cfg.height_px, cfg.pixel_size_mm).T
    return x, y, col, row


def observed_pixels(result: AdjustmentResult, camera_id: str) -> np.ndarray:
    """The measured pixels (m, 2) of the adjustment's image observations in the images of ``camera_id``."""
    block = result.block
    ob = block.observations
    at = np.asarray(block.images.camera_id)[ob.image_index] == camera_id
    return ob.pixel[at]


def observed_radius_px(result: AdjustmentResult, camera_id: str) -> float:
    """The radius of the observed area around an observation: :data:`OBSERVED_RADIUS_SHARE` of the frame's width."""
    return OBSERVED_RADIUS_SHARE * float(result.block.cameras[camera_id].width_px)


@dataclass(frozen=True)
class CorrectionSigma:
    """The σ of one camera's correction on the grid over its frame."""

    camera_id: str
    col_px: np.ndarray
    row_px: np.ndarray
    covariance: FieldCovariance          # along the photo axes (x right, y up)
    observed: np.ndarray                 # (n,) bool: an observation within the observed radius
    n_estimated: int


def correction_sigma(result: AdjustmentResult, k: int, nodes_x: int = GRID_NODES) -> CorrectionSigma:
    """The σ of camera ``k``'s AP correction on its grid (module docstring), with its observed area."""
    cam = result.problem.cameras[k]
    estimated, _, cov = ap_estimate(result, k)
    x, y, col, row = grid_nodes(result, k, nodes_x)
    bx, by = cam.ap.basis(x, y)
    seen = observed_nodes(col, row, observed_pixels(result, cam.camera_id), observed_radius_px(result, cam.camera_id))
    return CorrectionSigma(cam.camera_id, col, row, field_covariance(bx[:, estimated], by[:, estimated], cov), seen,
                           int(estimated.sum()))
