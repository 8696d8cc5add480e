"""Do the images agree on a camera parameter? Each image's own value of it, and the spread between images beyond
their noise, added to the parameter's sigma.

A camera parameter enters every image's equations; where it enters through data of the image that carry errors of
their own, each image sees it scaled by its own error. A rolling shutter's readout tau is the case in point: the
centre of image i moves by v_i dt, and only v_i tau enters the collinearity, so a velocity 2 % off in image i is,
for image i's observations, a readout 2 % off. The adjustment holds the velocities as data and its sigma of tau
knows nothing of their errors: on the simulated serpentine blocks the readout's z-scores spread 1.23 (velocities
from GNSS-position differences) and 1.00 with the true velocities (benchmarks/study_rolling_shutter.py).

The images themselves tell how far apart they are. With c_i the parameter's column restricted to image i's
observations (whitened), the test of "image i has a value of its own, beta_i more" in the adjusted block is the
w-test of the alternative c_i (Baarda's, for a model error of a given direction):

    z_i = c_i' r,   M_ik = c_i' R c_k,   beta_i = z_i / M_ii,   sigma(beta_i) = sigma0 / sqrt(M_ii)

with r the whitened residuals l - f and R = I - A N^-1 A' the residuals' cofactor. The object points are eliminated
as in the adjustment (P_j = I - J_p V^-1 J_p' per point): c_i' R c_k = c_i' P c_k - g_i' Q g_k, g_i = J_theta' P c_i
its reduced right-hand side and Q the cofactor matrix of theta. If every image has its own deviation beta_i,
independent with variance s^2, z = M beta + e (e of cofactor M), and

    E[z' M^+ z] = sigma0^2 rank(M) + s^2 trace(M)

gives s^2 by the method of moments (z' M^+ z / sigma0^2 is chi^2 with rank(M) degrees of freedom when the images
agree: the test of their agreement). The common estimate moves by sum_i h_i beta_i, h_i = q' g_i (q: the
parameter's column of Q; the h_i sum to 1, less what a prior takes), so its variance gains s^2 sum_i h_i^2.

What this does not see: an image's error in another direction (a velocity across the flight line shears the image
across, which the readout's column does not take up), and errors shared by neighbouring images (velocities from the
same positions). It costs one evaluation of the image observations' Jacobians and Q times n_images columns; a
cofactor matrix kept as a :class:`~selfcal.adjust.selected.BandedCofactor` (beyond DENSE_LIMIT unknowns) is made
dense for it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..adjust.residuals.image import point_rays

__all__ = ["ImageSpread", "image_spread", "theta_index"]

#: observation rows per pass (each keeps a dense row of theta: 2 x n_theta numbers per observation)
_CHUNK_NUMBERS = 4_000_000


@dataclass(frozen=True)
class ImageSpread:
    """How the images of one camera agree on one of its parameters (module docstring), in the parameter's code
    unit: each image's own deviation from the common estimate with its sigma and its share of the estimate; the
    agreement's chi^2 and degrees of freedom; the spread between images beyond their noise; the sigma of the
    estimate from the adjustment alone and with the spread."""

    images: np.ndarray          # problem indices of the camera's images
    deviation: np.ndarray       # beta_i
    sigma: np.ndarray           # sigma(beta_i)
    share: np.ndarray           # h_i
    chi2: float
    dof: int
    spread: float               # s
    sigma_adjustment: float
    sigma_total: float

    @property
    def w(self) -> np.ndarray:
        return self.deviation / self.sigma


def theta_index(problem, camera: int, parameter: int) -> int | None:
    """The index in theta of core parameter ``parameter`` of camera ``camera`` (None: not estimated)."""
    cam = problem.cameras[camera]
    if not cam.free[parameter]:
        return None
    return int(problem.d_offset[camera] + cam.free[:parameter].sum())


def image_spread(result, camera: int, parameter: int) -> ImageSpread | None:
    """The images' agreement on core parameter ``parameter`` of camera ``camera`` of an adjustment (module
    docstring); None where the parameter is not estimated or fewer than two images see it."""
    problem, state = result.problem, result.state
    index = theta_index(problem, camera, parameter)
    if index is None:
        return None
    images = np.flatnonzero(problem.image_camera == camera)
    if len(images) < 2:
        return None
    local = np.full(problem.n_images, -1, np.int64)
    local[images] = np.arange(len(images))
    n, k = problem.n_theta, len(images)
    G = np.zeros((n, k))                    # g_i, the reduced right-hand side of each image's column
    M = np.zeros((k, k))                    # c_i' P c_k
    z = np.zeros(k)
    counts = np.diff(problem.point_start)
    positions = np.flatnonzero(counts >= 1)
    per_chunk = max(1, _CHUNK_NUMBERS // (2 * n))
    start = 0
    while start < len(positions):
        stop = start + 1
        rows = counts[positions[start]]
        while stop < len(positions) and rows + counts[positions[stop]] <= per_chunk:
            rows += counts[positions[stop]]
            stop += 1
        _accumulate(problem, state, positions[start:stop], index, local, G, M, z)
        start = stop
    Q = result.Q_theta
    QG = (Q if isinstance(Q, np.ndarray) else np.asarray(Q)) @ G     # (a BandedCofactor: its dense matrix)
    M -= G.T @ QG
    M = 0.5 * (M + M.T)
    share = QG[index]                       # h_i = q' g_i (Q symmetric)
    sigma0_sq = float(result.variance_factor)
    values, vectors = np.linalg.eigh(M)
    keep = values > values.max() * 1e-9
    dof = int(keep.sum())
    projected = vectors[:, keep].T @ z
    quadratic = float(np.sum(projected ** 2 / values[keep]))
    spread_sq = max(0.0, (quadratic - sigma0_sq * dof) / float(np.trace(M)))
    diagonal = np.maximum(np.diag(M), 1e-300)
    sigma_adjustment = float(np.sqrt(sigma0_sq * Q[index, index]))
    return ImageSpread(images, z / diagonal, np.sqrt(sigma0_sq / diagonal), share, quadratic / sigma0_sq, dof,
                       float(np.sqrt(spread_sq)), sigma_adjustment,
                       float(np.sqrt(sigma_adjustment ** 2 + spread_sq * float(share @ share))))


def _accumulate(problem, state, positions: np.ndarray, index: int, local: np.ndarray, G: np.ndarray, M: np.ndarray,
                z: np.ndarray) -> None:
    """Add the points at ``positions`` to G, M (c_i' P c_k) and z (module docstring)."""
    rays = point_rays(problem, state, positions)
    counts, starts, owner, r, J, j_p, V, W = (rays.counts, rays.starts, rays.owner, rays.r, rays.J, rays.j_p,
                                              rays.V, rays.W)
    img = problem.obs_image[rays.o]
    m = len(rays.o)
    c = J[:, :, index].copy()                                       # (m, 2): zero off the camera's images
    V_inv = np.linalg.inv(V)
    response = V_inv @ W                                            # (points, 3, n)
    u = np.einsum("oki,ok->oi", j_p, c)                             # J_p' c of each ray
    mine = local[img]
    seen = mine >= 0
    # g of a ray: J' c - W' V^-1 J_p' c
    g = np.einsum("okt,ok->ot", J, c) - np.einsum("oit,oi->ot", response[owner], u)
    np.add.at(G.T, mine[seen], g[seen])
    np.add.at(z, mine[seen], np.einsum("ok,ok->o", c, r)[seen])
    np.add.at(M, (mine[seen], mine[seen]), np.einsum("ok,ok->o", c, c)[seen])
    # - c_i' J_p V^-1 J_p' c_k over the pairs of a point's rays (its own pair included)
    pairs = counts[owner]
    a = np.repeat(np.arange(m), pairs)
    b = np.repeat(starts[owner], pairs) + np.arange(pairs.sum()) - np.repeat(np.cumsum(pairs) - pairs, pairs)
    both = seen[a] & seen[b]
    a, b = a[both], b[both]
    value = np.einsum("pi,pij,pj->p", u[a], V_inv[owner[a]], u[b])
    np.add.at(M, (mine[a], mine[b]), -value)
