"""The additional parameters' Jacobian columns: evaluated once per problem, kept, and carried over.

The whitened AP columns of a camera depend on the measured image coordinates only, so they are the same
in every iteration: a problem evaluates them once (in blocks, on the threads of a pass) and keeps them, with
their Gram matrix, and a re-adjustment (data snooping, screening, variance components, robust reweighting)
takes over the previous problem's arrays (:func:`carry_ap_columns`) instead of evaluating the basis again.
Where the AP model gives its basis as sparse rows times a fixed map (:class:`selfcal.ap.base.SparseBasis`:
the wavelets of compact support), those rows are kept too (:func:`sparse_ap_rows`).

All of this lives in one :class:`APColumnCache` per problem (``Problem.ap_cache``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ..ap.base import pattern_groups
from .kernels import compact_rows
from .parallel import over_chunks
from .ordering import row_positions
from .problem import Problem, State

if TYPE_CHECKING:
    from ..sensors.base import BoundSensor

__all__ = ["APColumnCache", "AP_COLUMN_BLOCK", "camera_jacobian", "evaluate_ap_columns", "sparse_ap_rows",
           "sparse_gram", "carry_ap_columns", "camera_terms", "bound_of", "rows_times"]


@dataclass
class APColumnCache:
    """What a problem keeps of its AP columns: the whitened dense columns of each camera (keyed by the camera and
    its free APs), gathered parts of several cameras' columns, the sparse rows of a one-camera problem, the Gram
    matrix of the constant columns, and the AP displacement of each assembly chunk at the AP values it was last
    computed for."""

    columns: dict = field(default_factory=dict)
    gram: np.ndarray | None = None
    delta: dict = field(default_factory=dict)        # (o0, o1) -> (AP values, their displacement)

    def forget(self) -> None:
        """Drop everything (the columns are evaluated afresh when next needed)."""
        self.columns.clear()
        self.delta.clear()
        self.gram = None

    def rescale(self, problem: Problem, rows: np.ndarray, ratio: np.ndarray) -> None:
        """The whitened rows of the observations ``rows`` (problem order) multiplied by ``ratio`` (a re-weighting):
        the kept dense columns and sparse rows in place, the Gram matrix of the constant columns updated by the
        changed rows' outer products (summed afresh at the next linearisation when more than a fifth of the rows
        changed), the gathered parts of several cameras' columns dropped."""
        factor = ratio[:, None, None]
        single = len(problem.cameras) == 1
        for key in list(self.columns):
            value = self.columns[key]
            if value is None:
                continue
            if key[0] == "sparse":                          # (one camera) owned by the cache: in place
                value.values[rows] *= factor
                continue
            if len(key) != 2:
                del self.columns[key]                       # a gathered part: gathered again when needed
                continue
            k = key[0]
            if single:
                position, scale = rows, factor
            else:
                mine = problem.image_camera[problem.obs_image[rows]] == k
                position = (np.cumsum(problem.image_camera[problem.obs_image] == k) - 1)[rows[mine]]
                scale = factor[mine]
            n_core = problem.cameras[k].n_core
            if single and self.gram is not None:
                if rows.size > 0.2 * problem.n_image_observations or self.gram.shape[0] != value.shape[2] - n_core:
                    self.gram = None
                else:                   # G + sum over the rows of (ratio^2 - 1) a a^T
                    change = ratio * ratio - 1.0
                    flat = (value[position, :, n_core:] * np.sqrt(np.abs(change))[:, None, None]).reshape(
                        2 * len(position), -1)
                    self.gram = self.gram + (flat * np.repeat(np.sign(change), 2)[:, None]).T @ flat
            value[position] *= scale


def camera_jacobian(problem: Problem, k: int) -> np.ndarray:
    """Whitened camera-parameter Jacobian of camera ``k`` at all its observations (in problem
    order), (n_k, 2, n_core + n_free_ap): a slot for each of its sensor's core parameters (a frame
    camera's interior orientation), which the caller fills in every iteration, then the
    displacement per unit of each free AP.

    The AP columns depend on the measured coordinates only, so they are evaluated
    once per problem and kept (a WAP basis costs far more to evaluate than to
    store), or taken over from the adjustment this one re-runs
    (:func:`carry_ap_columns`). Keeping the core slots in the same array lets one
    camera's Jacobian rows be a view, not a fresh copy per iteration.
    """
    cam = problem.cameras[k]
    nc = cam.n_core
    free = cam.free[nc:]
    key = (k, free.tobytes())
    columns = problem.ap_cache.columns.get(key)
    if columns is None:
        mine = np.flatnonzero(problem.image_camera[problem.obs_image] == k)
        n_free = int(free.sum())
        # np.empty, then every entry written: calloc's lazily zeroed pages take no transparent huge
        # pages, and faulting in hundreds of MB of 4 KiB pages costs more than the writes
        columns = np.empty((mine.size, 2, nc + n_free))
        # where the model gives sparse rows, the columns are those rows times their map (a product per pattern of a
        # few dozen raw columns), not a second evaluation of the basis
        sparse = sparse_ap_rows(problem) if n_free and mine.size else None
        if sparse is not None:
            def evaluate(start: int, _) -> None:
                stop = min(start + AP_COLUMN_BLOCK, mine.size)
                columns[start:stop, :, :nc] = 0.0
                sparse.times_map(start, stop, out=columns[start:stop, :, nc:])
            over_chunks(range(0, mine.size, AP_COLUMN_BLOCK), evaluate, lambda: None)
        elif n_free and mine.size:
            bound = bound_of(problem, mine)

            # block by block into the kept array (a basis evaluation makes several temporaries of the array's
            # size), the blocks on the threads of a pass (the wavelets' table look-ups release the interpreter lock)
            def evaluate(start: int, _) -> None:
                o = mine[start:start + AP_COLUMN_BLOCK]
                # the core slots too: each block's pages are first touched on its own thread, not all on one
                columns[start:start + o.size, :, :nc] = 0.0
                part = columns[start:start + o.size, :, nc:]
                if free.all():
                    bound.ap_columns(k, o, cam.ap, out=part)           # written in place, then whitened
                    part /= problem.obs_sigma[o][:, :, None]
                else:
                    np.divide(bound.ap_columns(k, o, cam.ap)[:, :, free], problem.obs_sigma[o][:, :, None], out=part)
            over_chunks(range(0, mine.size, AP_COLUMN_BLOCK), evaluate, lambda: None)
        else:
            columns[:, :, :nc] = 0.0
        problem.ap_cache.columns[key] = columns
    return columns


def evaluate_ap_columns(problem: Problem) -> None:
    """Evaluate the kept AP columns of every camera now, before the threads of a pass over the chunks
    (:mod:`.parallel`) share them."""
    for k, cam in enumerate(problem.cameras):
        if cam.ap.n_params:
            camera_jacobian(problem, k)


#: observations per block when a camera's AP columns are evaluated
AP_COLUMN_BLOCK = 8192


def sparse_gram(sparse, o0: int, o1: int, rows: np.ndarray | None = None) -> np.ndarray:
    """The Gram matrix of the sparse rows of observations o0:o1 (or of the observations ``rows``) over the raw
    columns (n_raw, n_raw): one product per pattern and axis over its few columns."""
    n_raw = sparse.to_params.shape[0]
    out = np.zeros((n_raw, n_raw))
    index = np.arange(o0, o1) if rows is None else np.asarray(rows)
    pattern = sparse.pattern[index]
    for group in pattern_groups(pattern):
        for k in range(2):
            cols = sparse.columns[pattern[group[0]], k]
            X = sparse.values[index[group], k]
            out[np.ix_(cols, cols)] += X.T @ X
    return out


def sparse_ap_rows(problem: Problem):
    """The whitened AP columns of a one-camera problem as sparse rows (:class:`selfcal.ap.base.SparseBasis`,
    in problem order, ``to_params`` mapping to the camera's free APs), or None: several cameras, a core
    parameter held, or rows that the AP model or the sensor gives dense only.

    Kept per problem like the dense columns (:func:`camera_jacobian`), evaluated block by block on the
    threads of a pass, or taken over from the adjustment this one re-runs (:func:`carry_ap_columns`)."""
    if len(problem.cameras) != 1:
        return None
    cam = problem.cameras[0]
    if not cam.ap.n_params or not cam.free[:cam.n_core].all():
        return None
    key = ("sparse", 0)
    if key not in problem.ap_cache.columns:
        o = np.arange(problem.n_image_observations)
        bound = bound_of(problem, o) if o.size else None
        parts = {}

        def evaluate(start: int, _) -> None:
            assert bound is not None                    # (evaluated only where there is one)
            part = o[start:start + AP_COLUMN_BLOCK]
            rows = bound.sparse_ap_columns(0, part, cam.ap)
            # whitened on the block's thread (a new array: the sensor's may be one it keeps)
            if rows is not None:
                rows = replace(rows, values=rows.values / problem.obs_sigma[part][:, :, None])
            parts[start] = rows
        if bound is not None:
            over_chunks(range(0, o.size, AP_COLUMN_BLOCK), evaluate, lambda: None)
        blocks = [parts[start] for start in sorted(parts)]
        given = [b for b in blocks if b is not None]
        sparse = None
        if blocks and len(given) == len(blocks):
            sparse = replace(given[0], pattern=np.concatenate([b.pattern for b in given]),
                             values=np.concatenate([b.values for b in given]))
        problem.ap_cache.columns[key] = sparse
    sparse = problem.ap_cache.columns[key]
    if sparse is None:
        return None
    return replace(sparse, to_params=sparse.to_params[:, cam.free[cam.n_core:]])


def bound_of(problem: Problem, o: np.ndarray) -> BoundSensor:
    """The bound sensor of observations ``o`` (of one camera, hence one sensor)."""
    return problem.sensors[int(problem.obs_sensor[o[0]])].bound


def _gathered_columns(problem: Problem, k: int, o0: int, o1: int, mask) -> np.ndarray:
    """The AP columns of camera ``k`` at its observations among o0:o1 (``mask``): a view for a
    single camera, a gathered copy (kept) otherwise."""
    columns = camera_jacobian(problem, k)[:, :, problem.cameras[k].n_core:]
    if isinstance(mask, slice):
        return columns[o0:o1]
    key = (k, o0, o1, problem.cameras[k].free[problem.cameras[k].n_core:].tobytes())
    part = problem.ap_cache.columns.get(key)
    if part is None:
        position = np.cumsum(problem.image_camera[problem.obs_image] == k) - 1
        part = problem.ap_cache.columns[key] = columns[position[o0:o1][mask]]
    return part


def _gather(columns: np.ndarray, rows: np.ndarray, keep: np.ndarray | None, block: int = 4096) -> np.ndarray:
    """columns[rows][:, :, keep] in one pass, block by block (no full-size temporary)."""
    out = np.empty((len(rows), columns.shape[1], columns.shape[2] if keep is None else len(keep)))
    for start in range(0, len(rows), block):
        part = columns[rows[start:start + block]]
        out[start:start + block] = part if keep is None else part[:, :, keep]
    return out


def _same_positions(previous: np.ndarray | None, current: np.ndarray | None, source: np.ndarray) -> bool:
    """Whether the AP basis of each observation is evaluated where it was in the previous problem (both at the
    measured coordinates, or at the same adjusted ones)."""
    if previous is None or current is None:
        return previous is None and current is None
    return bool(np.array_equal(previous[source], current))


def carry_ap_columns(problem: Problem, rows: np.ndarray, previous: Problem, previous_rows: np.ndarray,
                     consume: bool = False) -> None:
    """Give ``problem`` the AP columns of ``previous`` where both use the same AP model object.

    A re-adjustment after data snooping or AP screening keeps a subset of the
    observations and of the free APs; its columns are rows and columns of the
    previous ones (rescaled where an observation's sigma changed, as in a
    variance-component iteration). ``rows`` and ``previous_rows`` are the block
    row numbers of each problem's observations in problem order. With ``consume`` the previous
    problem's arrays are taken over and compacted in place, or dropped where they cannot be carried
    (it is not used again, or evaluates its columns afresh if it is).
    """
    source = row_positions(previous_rows, rows)                 # previous observation of each observation
    if source is None or not _same_positions(previous.obs_ap_at, problem.obs_ap_at, source):
        # not a subset of the previous observations (observations taken back), or the AP basis evaluated elsewhere
        # now: nothing to carry; consumed, the previous arrays are dropped rather than held beside the new ones
        if consume:
            previous.ap_cache.forget()
        return
    for k, cam in enumerate(problem.cameras):
        old_k = next((j for j, c in enumerate(previous.cameras) if c.camera_id == cam.camera_id), None)
        if old_k is None or previous.cameras[old_k].ap is not cam.ap or not cam.ap.n_params:
            continue
        nc = cam.n_core
        old_free, free = previous.cameras[old_k].free[nc:], cam.free[nc:]
        old_columns = previous.ap_cache.columns.get((old_k, old_free.tobytes()))
        if old_columns is None or np.any(free & ~old_free):
            continue
        old_position = np.cumsum(previous.image_camera[previous.obs_image] == old_k) - 1
        mine = problem.image_camera[problem.obs_image] == k
        take = old_position[source[mine]]
        keep = np.concatenate([np.ones(nc, bool), free[old_free]])   # the slots and the still free APs
        ratio = previous.obs_sigma[source[mine]] / problem.obs_sigma[mine]
        if len(problem.cameras) == 1 and len(previous.cameras) == 1 and np.all(ratio == 1.0):
            problem.ap_cache.gram = _carried_gram(previous, old_columns, source, free[old_free])
        # every previous observation, in its order (a control point left out, a parameter held): the array as it is
        whole = take.size == old_columns.shape[0] and bool(np.all(take == np.arange(take.size)))
        if consume and whole and keep.all():
            del previous.ap_cache.columns[(old_k, old_free.tobytes())]
            columns = old_columns
        elif consume and old_columns.flags.c_contiguous and np.all(np.diff(take) > 0):
            # the previous problem's array, compacted where it lies (no second copy of hundreds of MB);
            # the previous problem forgets it and would evaluate its columns afresh if used again
            del previous.ap_cache.columns[(old_k, old_free.tobytes())]
            flat = old_columns.reshape(-1)
            width = 2 * old_columns.shape[2]
            both = np.flatnonzero(np.concatenate([keep, keep]))          # x then y row of each observation
            compact_rows(flat, width, take.astype(np.int64), both)
            columns = flat[:take.size * both.size].reshape(take.size, 2, both.size // 2)
        else:
            columns = _gather(old_columns, take, None if keep.all() else np.flatnonzero(keep))
        if np.any(ratio != 1.0):
            columns *= ratio[:, :, None]
        problem.ap_cache.columns[(k, free.tobytes())] = columns
        sparse = (previous.ap_cache.columns.pop if consume else previous.ap_cache.columns.get)(("sparse", old_k), None)
        if sparse is not None and len(problem.cameras) == 1 and consume and whole and np.all(ratio == 1.0):
            problem.ap_cache.columns[("sparse", 0)] = sparse
        elif sparse is not None and len(problem.cameras) == 1:
            values = sparse.values[take]
            if np.any(ratio != 1.0):
                values *= ratio[:, :, None]
            problem.ap_cache.columns[("sparse", 0)] = replace(sparse, pattern=sparse.pattern[take], values=values)


def _carried_gram(previous: Problem, old_columns: np.ndarray, source: np.ndarray, keep: np.ndarray):
    """The Gram matrix of the constant AP columns of a one-camera problem that keeps the
    observations ``source`` of ``previous`` and its APs ``keep`` (bool over the previous free
    APs): the previous Gram minus the rows of the observations that were left out, or None
    (computed afresh) when there is none to carry or most rows went."""
    gram = previous.ap_cache.gram
    n_core = previous.cameras[0].n_core
    if gram is None or gram.shape[0] != old_columns.shape[2] - n_core:
        return None
    left = np.ones(previous.n_image_observations, bool)
    left[source] = False
    removed = np.flatnonzero(left)                 # (a mask: setdiff1d sorts 80,000 rows by hashing, 50 ms)
    if removed.size > 0.2 * previous.n_image_observations:
        return None                          # the difference would lose digits: sum afresh
    if removed.size:
        rows = old_columns[removed, :, n_core:].reshape(2 * removed.size, gram.shape[0])
        gram = gram - rows.T @ rows
    return gram[np.ix_(keep, keep)]


def rows_times(rows: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """(n, 2, k) @ (k,) as one BLAS matrix-vector product (a batched 3-D matmul is ~5x slower)."""
    n, two, k = rows.shape
    if rows.flags.c_contiguous:
        return (rows.reshape(n * two, k) @ vector).reshape(n, two)
    return rows @ vector


def camera_terms(problem: Problem, state: State, o0: int, o1: int, img: np.ndarray):
    """Additional-parameter displacement (observation units) of observations o0:o1, and per camera
    the observations it takes (mask) with the (whitened) Jacobian columns of its free APs (None when
    no camera has additional parameters)."""
    m = o1 - o0
    if not any(cam.ap.n_params for cam in problem.cameras):
        return np.zeros((m, 2)), None          # no additional parameters (BAL's 49 cameras: no mask per camera)
    # the displacement depends on the AP values alone: a cost evaluation at a state and the linearisation at the
    # same state that follows it (an accepted step) compute it once (one pass over the kept AP columns)
    values = b"".join(v[c.n_core:].tobytes() for c, v in zip(problem.cameras, state.cameras))
    cached = problem.ap_cache.delta.get((o0, o1))
    known = cached is not None and cached[0] == values
    delta = cached[1] if known and cached is not None else np.zeros((m, 2))
    cam_of_obs = problem.image_camera[img]
    cam_cols = []  # (camera index, mask, whitened columns (n, 2, n_free_ap))
    single = len(problem.cameras) == 1
    sigma = problem.obs_sigma[o0:o1]
    for k, cam in enumerate(problem.cameras):
        mask = slice(None) if single else cam_of_obs == k
        if not isinstance(mask, slice) and not mask.any():
            continue
        nc = cam.n_core
        if cam.ap.n_params:
            a = state.cameras[k][nc:]
            free = cam.free[nc:]
            if single:
                # the kept Jacobian rows are contiguous with the core slots first:
                # one matrix-vector product over them, the slots weighted by zero
                rows = camera_jacobian(problem, k)[o0:o1]
                columns = rows[:, :, nc:]
                if not known:
                    delta[:] = rows_times(rows, np.concatenate([np.zeros(nc), a[free]])) * sigma
            else:
                columns = _gathered_columns(problem, k, o0, o1, mask)
                if not known:
                    delta[mask] = rows_times(columns, a[free]) * sigma[mask]
            if not known and np.any(a[~free] != 0):          # APs held at a non-zero value
                o = o0 + (np.arange(m) if isinstance(mask, slice) else np.flatnonzero(mask))
                held = np.where(free, 0.0, a)
                delta[mask] += bound_of(problem, o).ap_columns(k, o, cam.ap) @ held
        else:
            columns = np.zeros((m if isinstance(mask, slice) else int(mask.sum()), 2, 0))
        cam_cols.append((k, mask, columns))
    problem.ap_cache.delta[(o0, o1)] = (values, delta)
    return delta, cam_cols

