"""The images' working columns: Jacobian rows of few non-zero entries, mapped to the image parameters per image.

A sensor whose image rows are dense in the image parameters but sparse in another basis (a line image's jitter:
:class:`selfcal.sensors.base.WorkingColumns`) gives its rows in that basis, as ``slots`` values per observation and
the working columns they belong to. The sums over observations (the image blocks of the normal equations, their
right-hand side, the points' Schur terms) are formed in the working columns, at the cost of the few slots; the
image parameters' blocks are T^T (sum) T per image, T the sensor's map with the columns of held parameters zeroed.
Quantities given in the image parameters (a correction, a cofactor block) go the other way: T d, T Q T^T.

:class:`ImageMaps` holds every image's T and applies it; without working columns the engine does not use it (its
rows are in the image parameters already).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["working_columns", "image_maps", "ImageMaps", "symmetrised"]


def working_columns(problem: Problem):
    """The :class:`~selfcal.sensors.base.WorkingColumns` the engine assembles in, or None: a problem of one sensor
    that gives them, with its cameras in the dense form (the compact camera rows of BAL-like blocks have their own
    wide blocks, :func:`selfcal.adjust.schur.reduce`)."""
    if len(problem.sensors) != 1 or problem.compact_cameras:
        return None
    return problem.sensors[0].bound.working_columns()


def image_maps(problem: Problem, working) -> "ImageMaps":
    """Each image's T (working width, image width), the columns of its held parameters zeroed."""
    T = working.to_parameters
    return ImageMaps((T if T.ndim == 3 else T[None, :, :]) * problem.image_free[:, None, :])


def symmetrised(blocks: np.ndarray) -> np.ndarray:
    """Per-image blocks (n, w, w) summed over slot pairs a <= b only (:func:`~.kernels.accumulate_observations`):
    the whole symmetric sums, S + S^T - diag(S) (two slots of one column are a value and a zero, whose product is 0,
    so the diagonal holds each slot's own products once)."""
    out = blocks + blocks.transpose(0, 2, 1)
    diagonal = np.einsum("nii->ni", out)
    diagonal *= 0.5
    return out


class ImageMaps:
    """The images' maps T (n_images, working, width) from working columns to image parameters, and their products.

    A square T is its diagonal D plus a few rows E (a line image's: the identity, and the polynomial's rows that
    carry the powers taken off the jitter's functions), so every product is taken as D X D + the few rows' terms:
    O(width^2) per image instead of a dense product's O(width^3)."""

    def __init__(self, T: np.ndarray):
        self.T = T
        self.square = T.shape[1] == T.shape[2]
        if self.square:
            self.D = np.ascontiguousarray(np.einsum("nii->ni", T))
            rest = T.copy()
            np.einsum("nii->ni", rest)[:] = 0.0
            self.rows = np.flatnonzero(np.any(rest != 0.0, axis=(0, 2)))
            self.E = np.ascontiguousarray(rest[:, self.rows, :])                # (n, k, width)

    def blocks_to_parameters(self, blocks: np.ndarray) -> np.ndarray:
        """T_i^T M_i T_i for per-image blocks M (n_images, working, working)."""
        return self._between(blocks, np.arange(len(blocks)), np.arange(len(blocks)))

    def pairs_to_parameters(self, blocks: np.ndarray, image_a: np.ndarray, image_b: np.ndarray) -> np.ndarray:
        """T_a^T M_q T_b for the blocks M (n_pairs, working, working) of image pairs (a, b)."""
        return self._between(blocks, image_a, image_b)

    def _between(self, M: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if not len(M):
            return np.zeros((0, self.T.shape[2], self.T.shape[2]))
        if not self.square:
            return self.T[a].transpose(0, 2, 1) @ M @ self.T[b]
        r = self.rows
        Da, Db, Ea, Eb = self.D[a], self.D[b], self.E[a], self.E[b]
        out = Da[:, :, None] * M * Db[:, None, :]                              # D_a M D_b
        out += Da[:, :, None] * (M[:, :, r] @ Eb)                               # D_a M E_b
        out += Ea.transpose(0, 2, 1) @ (M[:, r, :] * Db[:, None, :])            # E_a^T M D_b
        out += Ea.transpose(0, 2, 1) @ (M[:, r][:, :, r] @ Eb)                  # E_a^T M E_b
        return out

    def vectors_to_parameters(self, vectors: np.ndarray) -> np.ndarray:
        """T_i^T v_i for per-image vectors v (n_images, working)."""
        if not self.square:
            return np.einsum("iwk,iw->ik", self.T, vectors)
        return self.D * vectors + np.einsum("irk,ir->ik", self.E, vectors[:, self.rows])

    def rows_to_parameters(self, rows: np.ndarray) -> np.ndarray:
        """T_i^T R_i for per-image row blocks R (n_images * working, n): the image x camera blocks,
        (n_images * width, n)."""
        n_img, working, width = self.T.shape
        R = rows.reshape(n_img, working, -1)
        if not self.square:
            return (self.T.transpose(0, 2, 1) @ R).reshape(n_img * width, -1)
        out = self.D[:, :, None] * R + self.E.transpose(0, 2, 1) @ R[:, self.rows, :]
        return out.reshape(n_img * width, -1)

    def vectors_to_working(self, vectors: np.ndarray) -> np.ndarray:
        """T_i d_i for per-image vectors d (n_images, width) in the image parameters: (n_images, working)."""
        if not self.square:
            return np.einsum("iwk,ik->iw", self.T, vectors)
        out = self.D * vectors
        out[:, self.rows] += np.einsum("irk,ik->ir", self.E, vectors)
        return out

    def rows_to_working(self, rows: np.ndarray) -> np.ndarray:
        """T_i R_i for per-image row blocks R (n_images, width, n) in the image parameters: (n_images, working, n)."""
        if not self.square:
            return self.T @ rows
        out = self.D[:, :, None] * rows
        out[:, self.rows, :] += self.E @ rows
        return out

    def blocks_to_working(self, blocks: np.ndarray) -> np.ndarray:
        """T_i Q_i T_i^T for per-image blocks Q (n_images, width, width) in the image parameters."""
        n = np.arange(len(blocks))
        return self._around(blocks, n, n)

    def pairs_to_working(self, blocks: np.ndarray, image_a: np.ndarray, image_b: np.ndarray) -> np.ndarray:
        """T_a Q_q T_b^T for the blocks Q (n_pairs, width, width) of image pairs (a, b)."""
        return self._around(blocks, image_a, image_b)

    def _around(self, Q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if not len(Q):
            return np.zeros((0, self.T.shape[1], self.T.shape[1]))
        if not self.square:
            return self.T[a] @ Q @ self.T[b].transpose(0, 2, 1)
        r = self.rows
        Da, Db, Ea, Eb = self.D[a], self.D[b], self.E[a], self.E[b]
        out = Da[:, :, None] * Q * Db[:, None, :]                              # D_a Q D_b
        QEb = Q @ Eb.transpose(0, 2, 1)                                         # (n, width, k)
        out[:, :, r] += Da[:, :, None] * QEb                                    # D_a Q E_b^T
        EaQ = Ea @ Q                                                            # (n, k, width)
        out[:, r, :] += EaQ * Db[:, None, :]                                    # E_a Q D_b
        out[:, r[:, None], r[None, :]] += EaQ @ Eb.transpose(0, 2, 1)           # E_a Q E_b^T
        return out

    def dense_rows(self, img: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """Rows (m, k, slots) in working columns ``columns`` (m, slots) of images ``img``, in the image parameters:
        (m, k, width). For a few rows (those of a few observations)."""
        return np.einsum("mks,msw->mkw", rows, self.T[img[:, None], columns])
