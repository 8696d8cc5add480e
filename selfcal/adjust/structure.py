"""Sparsity structure of the normal equations, computed once per problem.

Which observation belongs to which image and point never changes during an
adjustment, so the index arrays and sparse patterns used to assemble the
normal equations are built once here and only refilled with values in each
iteration (no sorting or COO conversion in the iterations).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["SparsePattern", "ChunkStructure", "BlockStructure", "build_structure", "observation_pairs"]


class SparsePattern:
    """A CSR matrix structure whose values are given in a fixed (COO) order.

    ``pattern.matrix(values)`` returns the CSR matrix with ``values[i]`` at
    ``(rows[i], cols[i])``; the (rows, cols) pairs must be distinct.
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]):
        rows = np.asarray(rows).ravel()
        cols = np.asarray(cols).ravel()
        order = np.argsort(rows.astype(np.int64) * shape[1] + cols, kind="stable")
        self.shape = shape
        self.perm = order
        self.indices: np.ndarray = cols[order].astype(np.int32 if max(shape) < 2**31 else np.int64)
        counts = np.bincount(rows, minlength=shape[0])
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(self.indices.dtype)

    def matrix(self, values: np.ndarray) -> sp.csr_matrix:
        values = np.asarray(values).ravel()[self.perm]
        return sp.csr_matrix((values, self.indices, self.indptr), shape=self.shape)


def _summing(groups: np.ndarray, n_groups: int) -> sp.csr_matrix:
    """(n_groups, len(groups)) 0/1 matrix that sums rows by group."""
    m = len(groups)
    return SparsePattern(groups, np.arange(m), (n_groups, m)).matrix(np.ones(m))


def observation_pairs(point_local: np.ndarray, n_points: int, upper: bool = False):
    """Pairs (a, b) of observations of the same point (observations grouped by point).

    All ordered pairs by default; with ``upper`` only a < b.
    """
    m = len(point_local)
    counts = np.bincount(point_local, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    k = counts[point_local]
    a = np.repeat(np.arange(m), k)
    offset = np.arange(a.size) - np.repeat(np.cumsum(k) - k, k)
    b = np.repeat(starts[point_local], k) + offset
    if upper:
        keep = a < b
        a, b = a[keep], b[keep]
    return a, b


@dataclass
class ChunkStructure:
    """Index arrays and summing matrices of one chunk of points and their observations (the
    camera-parameter couplings are accumulated by the kernels in selfcal.adjust.kernels)."""

    p0: int                         # the chunk's positions [p0, p1) in Problem.point_order
    p1: int
    o0: int
    o1: int
    points: np.ndarray              # the block's point at each of its positions
    img: np.ndarray                 # image of each observation
    ptl: np.ndarray                 # point of each observation, relative to p0 (an index into ``points``)
    sum_by_image: sp.csr_matrix     # (n_images, m)
    sum_by_point: sp.csr_matrix     # (n_pc, m)
    pair_a: np.ndarray              # upper pairs a < b of observations of the same point
    pair_b: np.ndarray
    pair_key: np.ndarray            # index into BlockStructure.pair_keys of each pair


@dataclass
class BlockStructure:
    chunks: list[ChunkStructure]
    pair_keys: np.ndarray           # image pairs (ia < ib) that share points: ia * n_images + ib
    image_pair_a: np.ndarray
    image_pair_b: np.ndarray


def build_structure(problem) -> BlockStructure:
    """The structure of a problem's normal equations (see module docstring)."""
    n_img = problem.n_images
    per_chunk = []
    all_keys = []
    position = problem.point_positions()
    for p0, p1 in problem.chunks:
        o0, o1 = int(problem.point_start[p0]), int(problem.point_start[p1])
        m, n_pc = o1 - o0, p1 - p0
        img = problem.obs_image[o0:o1]
        ptl = position[problem.obs_point[o0:o1]] - p0
        a, b = observation_pairs(ptl, n_pc, upper=True)
        keys = img[a] * n_img + img[b]
        all_keys.append(np.unique(keys))
        per_chunk.append((p0, p1, o0, o1, m, n_pc, img, ptl, a, b, keys))
    pair_keys = np.unique(np.concatenate(all_keys)) if all_keys else np.zeros(0, np.int64)

    chunks = []
    for p0, p1, o0, o1, m, n_pc, img, ptl, a, b, keys in per_chunk:
        key_index = np.searchsorted(pair_keys, keys)
        chunks.append(ChunkStructure(
            p0=p0, p1=p1, o0=o0, o1=o1, points=problem.point_order[p0:p1], img=img, ptl=ptl,
            sum_by_image=_summing(img, n_img),
            sum_by_point=_summing(ptl, n_pc),
            pair_a=a, pair_b=b, pair_key=key_index,
        ))
    return BlockStructure(chunks, pair_keys, pair_keys // n_img if n_img else pair_keys,
                          pair_keys % n_img if n_img else pair_keys)
