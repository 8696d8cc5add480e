"""The images' working columns: Jacobian rows of few non-zero entries, mapped to the image parameters per image.

A sensor whose image rows are dense in the image parameters but sparse in another basis (a line image's jitter:
:class:`selfcal.sensors.base.WorkingColumns`) gives its rows in that basis, as ``slots`` values per observation and
the working columns they belong to. The sums over observations (the image blocks of the normal equations, their
right-hand side, the points' Schur terms) are formed in the working columns, at the cost of the few slots; the
image parameters' blocks are T^T (sum) T per image, T the sensor's map with the columns of held parameters zeroed.
Quantities given in the image parameters (a correction, a cofactor block) go the other way: T d, T Q T^T.

Every function takes the per-image maps of :func:`image_maps`; without working columns the engine does not call
them (its rows are in the image parameters already).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["working_columns", "image_maps", "symmetrised", "blocks_to_parameters", "pairs_to_parameters", "vectors_to_parameters",
           "rows_to_parameters", "vectors_to_working", "blocks_to_working", "pairs_to_working", "dense_rows"]


def working_columns(problem: Problem):
    """The :class:`~selfcal.sensors.base.WorkingColumns` the engine assembles in, or None: a problem of one sensor
    that gives them, with its cameras in the dense form (the compact camera rows of BAL-like blocks have their own
    wide blocks, :func:`selfcal.adjust.schur.reduce`)."""
    if len(problem.sensors) != 1 or problem.compact_cameras:
        return None
    return problem.sensors[0].bound.working_columns()


def image_maps(problem: Problem, working) -> np.ndarray:
    """(n_images, working width, image width): each image's T, the columns of its held parameters zeroed."""
    T = working.to_parameters
    return (T if T.ndim == 3 else T[None, :, :]) * problem.image_free[:, None, :]


def symmetrised(blocks: np.ndarray) -> np.ndarray:
    """Per-image blocks (n, w, w) summed over slot pairs a <= b only (:func:`~.kernels.accumulate_observations`):
    the whole symmetric sums, S + S^T - diag(S) (two slots of one column are a value and a zero, whose product is 0,
    so the diagonal holds each slot's own products once)."""
    out = blocks + blocks.transpose(0, 2, 1)
    diagonal = np.einsum("nii->ni", out)
    diagonal *= 0.5
    return out


def blocks_to_parameters(maps: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """T_i^T M_i T_i for per-image blocks M (n_images, working, working)."""
    return maps.transpose(0, 2, 1) @ blocks @ maps


def pairs_to_parameters(maps: np.ndarray, blocks: np.ndarray, image_a: np.ndarray, image_b: np.ndarray) -> np.ndarray:
    """T_a^T M_q T_b for the blocks M (n_pairs, working, working) of image pairs (a, b)."""
    return maps[image_a].transpose(0, 2, 1) @ blocks @ maps[image_b]


def vectors_to_parameters(maps: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """T_i^T v_i for per-image vectors v (n_images, working)."""
    return np.einsum("iwk,iw->ik", maps, vectors)


def rows_to_parameters(maps: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """T_i^T R_i for per-image row blocks R (n_images * working, n): the image x camera blocks, (n_images * width, n)."""
    n_img, working, width = maps.shape
    return (maps.transpose(0, 2, 1) @ rows.reshape(n_img, working, -1)).reshape(n_img * width, -1)


def vectors_to_working(maps: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """T_i d_i for per-image vectors d (n_images, width) in the image parameters: (n_images, working)."""
    return np.einsum("iwk,ik->iw", maps, vectors)


def blocks_to_working(maps: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """T_i Q_i T_i^T for per-image blocks Q (n_images, width, width) in the image parameters."""
    return maps @ blocks @ maps.transpose(0, 2, 1)


def pairs_to_working(maps: np.ndarray, blocks: np.ndarray, image_a: np.ndarray, image_b: np.ndarray) -> np.ndarray:
    """T_a Q_q T_b^T for the blocks Q (n_pairs, width, width) of image pairs (a, b)."""
    return maps[image_a] @ blocks @ maps[image_b].transpose(0, 2, 1)


def dense_rows(maps: np.ndarray, img: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Rows (m, k, slots) in working columns ``columns`` (m, slots) of images ``img``, in the image parameters:
    (m, k, width). For a few rows (those of a few observations)."""
    return np.einsum("mks,msw->mkw", rows, maps[img[:, None], columns])
