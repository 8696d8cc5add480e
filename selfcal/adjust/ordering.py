"""The order of the points in a problem and their chunks, the unit of every pass over the points
(:mod:`selfcal.adjust.parallel`), and how a re-adjustment finds its predecessor's observations and keeps their order."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..block import Block
    from .problem import Problem

__all__ = ["CHUNK_OBSERVATIONS", "point_order", "point_chunks", "row_positions", "inherited_point_key"]

#: observations per chunk of the normal-equation assembly (bounds memory)
CHUNK_OBSERVATIONS = 16384


def point_order(image_index: np.ndarray, point_index: np.ndarray, n_points: int,
                key: np.ndarray | None = None, row_px: np.ndarray | None = None) -> np.ndarray:
    """The points by ``key`` if given, else by the first image that observes them, and in it by the row they are
    seen at where ``row_px`` (each observation's) is given, then as in the block; unobserved points last.

    The rows put points seen at nearby times together: a line image's jitter functions are local in time, so the
    assembly's sums (:mod:`selfcal.adjust.working`) then write to nearby entries (1.7x faster on a 50,000-point
    stereo pair than in the block's order)."""
    if key is None:
        first = image_index.astype(np.int64) if row_px is None else \
            np.empty(len(image_index), np.int64)
        if row_px is not None:
            first[np.lexsort((row_px, image_index))] = np.arange(len(image_index))   # rank by (image, row)
        key = np.full(n_points, np.iinfo(np.int64).max)
        np.minimum.at(key, point_index, first)
    return np.argsort(key, kind="stable")


def row_positions(old_rows: np.ndarray, new_rows: np.ndarray) -> np.ndarray | None:
    """The position in ``old_rows`` of each of ``new_rows`` (observations named by their block row, ``row``), or
    None when ``old_rows`` repeat a row or a new row is not among them (not a subset of the old observations).

    A row is a position in the block as read, so a table over the rows is no larger than that block: one scatter
    and one gather (a sort and a binary search of 80,000 rows took 6 ms, in every re-adjustment three times)."""
    if not len(old_rows):
        return None if len(new_rows) else np.zeros(0, np.int64)
    if old_rows.min() < 0 or (len(new_rows) and new_rows.min() < 0):
        return None
    size = int(max(old_rows.max(), new_rows.max() if len(new_rows) else 0)) + 1
    table = np.full(size, -1, np.int64)
    position = np.arange(len(old_rows))
    table[old_rows] = position
    if not np.array_equal(table[old_rows], position):               # a row repeated: the last one stayed
        return None
    where = table[new_rows]
    return None if len(where) and where.min() < 0 else where


def inherited_point_key(block: Block, previous_block: Block, previous: Problem) -> np.ndarray | None:
    """A key that puts the points of ``block`` (a subset of the observations of ``previous_block``, as after
    data snooping) in the order they had in ``previous``, or None if the observations are not such a subset.

    The first image of a point changes when that observation is rejected; a re-adjustment that kept its
    predecessor's order for the other points only would reorder it, and the arrays it carries over (the AP
    columns, hundreds of MB) could not be compacted in place."""
    where = row_positions(previous_block.observations.row, block.observations.row)
    if where is None:
        return None
    key = np.full(len(block.points), np.iinfo(np.int64).max)
    key[block.observations.point_index] = previous.point_positions()[previous_block.observations.point_index[where]]
    return key


def point_chunks(point_start: np.ndarray, target: int) -> list[tuple[int, int]]:
    """Split points into ranges holding about ``target`` observations each (at most), their number a
    multiple of the threads of a pass (:mod:`selfcal.adjust.parallel`), so that the threads' shares are even:
    five chunks of 16,000 observations on two threads wait for the third (six of 13,400 do not)."""
    from .parallel import MAX_WORKERS
    n_points = len(point_start) - 1
    n_chunks = -(-int(point_start[-1]) // max(int(target), 1))
    if n_chunks > 1:
        n_chunks = -(-n_chunks // MAX_WORKERS) * MAX_WORKERS
        target = -(-int(point_start[-1]) // n_chunks)
    bounds = [0]
    cuts = np.searchsorted(point_start, np.arange(target, point_start[-1], target))
    for cut in cuts:
        cut = int(min(max(cut, bounds[-1] + 1), n_points))
        if cut > bounds[-1] and cut < n_points:
            bounds.append(cut)
    bounds.append(n_points)
    return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
