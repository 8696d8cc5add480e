"""Three-dimensional similarity (Helmert) transformations and ray intersection."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Similarity", "fit_similarity", "intersect_rays"]


@dataclass(frozen=True)
class Similarity:
    """x_target = scale · R x_source + translation."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, x: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(x, float) @ self.rotation.T + self.translation


def fit_similarity(source: np.ndarray, target: np.ndarray) -> tuple[Similarity, np.ndarray]:
    """Least-squares similarity from at least three non-collinear point pairs (Umeyama 1991).

    Returns the transformation and the residuals target - transformed source, (n, 3).
    """
    source, target = np.asarray(source, float), np.asarray(target, float)
    if len(source) < 3:
        raise ValueError(f"a similarity needs at least 3 point pairs, found {len(source)}")
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    a, b = source - ms, target - mt
    cov = b.T @ a / len(source)
    U, S, Vt = np.linalg.svd(cov)
    if S[1] < 1e-12 * max(S[0], 1e-300):
        raise ValueError("the point pairs are collinear: the similarity is not determined")
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = np.mean(np.sum(a * a, axis=1))
    scale = float(np.trace(np.diag(S) @ D) / var_s)
    t = mt - scale * R @ ms
    sim = Similarity(scale, R, t)
    return sim, target - sim.apply(source)


def intersect_rays(origins: np.ndarray, directions: np.ndarray, groups: np.ndarray, n_groups: int):
    """Least-squares intersection of rays grouped by point.

    Minimises sum |(I - d d^T)(X - o)|^2 over the rays of each group.

    Returns
    -------
    xyz : (n_groups, 3), NaN where fewer than two rays or they are (nearly) parallel
    """
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = np.zeros((n_groups, 3, 3))
    b = np.zeros((n_groups, 3))
    np.add.at(A, groups, proj)
    np.add.at(b, groups, np.einsum("nij,nj->ni", proj, origins))
    count = np.bincount(groups, minlength=n_groups)
    xyz = np.full((n_groups, 3), np.nan)
    w = np.linalg.eigvalsh(A)
    ok = (count >= 2) & (w[:, 0] > 1e-8 * np.maximum(w[:, 2], 1e-300))
    xyz[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    return xyz
