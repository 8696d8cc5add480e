"""Normal equations with the object points eliminated (Schur complement).

With the unknowns split into theta (orientation, camera, extra) and the object
points p, the normal equations of the whitened problem are

    [ U    W ] [d_theta]   [g_theta]
    [ W^T  V ] [d_p    ] = [g_p    ]

where V is block diagonal with one 3x3 block per point. Eliminating the points
gives the reduced system

    (U - W V^-1 W^T) d_theta = g_theta - W V^-1 g_p,      d_p = V^-1 (g_p - W^T d_theta).

Everything is assembled chunk by chunk over the points (observations are sorted
by point), with NumPy and sparse products and no Python loop over
observations. The linearisation (Jacobians, U, V, W) is computed once per
iteration; the reduction is repeated only when the Levenberg-Marquardt damping
changes.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from ..ap.base import pattern_groups
from ..errors import AdjustmentError
from ..geometry.rotation import matrix_from_opk_with_derivatives, opk_from_matrix_with_derivatives
from .kernels import (accumulate_observations, camera_couplings, camera_couplings_compact, compact_rows,
                      point_blocks_times, schur_image_blocks, spd_inverse_3x3,
                      subtract_image_couplings)
from .parallel import over_chunks
from .problem import Problem, State, row_positions

__all__ = [
    "ChunkLinearisation",
    "Linearisation",
    "linearise",
    "reduce",
    "back_substitute",
    "evaluate_cost",
    "image_residuals",
    "contexts",
    "predict",
    "predict_observations",
    "observation_rows",
    "carry_ap_columns",
    "chunk_rows",
    "evaluate_ap_columns",
    "sparse_ap_rows",
    "parameter_observation_groups",
    "parameter_observations",
]


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


@dataclass
class ChunkLinearisation:
    p0: int              # positions [p0, p1) in Problem.point_order
    p1: int
    o0: int
    o1: int
    points: np.ndarray   # (n_pc,) the block's point at each position
    V: np.ndarray        # (n_pc, 3, 3) point normal blocks, control prior included
    g_p: np.ndarray      # (n_pc, 3)
    w_e: np.ndarray      # (m_c, width, 3) coupling of each observation's image with its point
    W_pd: np.ndarray | None      # (3 n_pc, n_d) coupling of the points with the camera parameters (dense form)
    w_d: np.ndarray | None = None  # (m_c, 3, width) its non-zero parts per observation (compact form)

    def couplings(self, transposed: bool = False) -> np.ndarray:
        """Each observation's coupling with its point over the columns it touches, (m_c, w, 3): its image's,
        then (compact cameras) its camera's (:func:`selfcal.adjust.covariance.observation_columns` names them).
        ``transposed``: (m_c, 3, w), C-contiguous."""
        if transposed:
            if self.w_d is None:
                return np.ascontiguousarray(self.w_e.transpose(0, 2, 1))
            return np.concatenate([self.w_e.transpose(0, 2, 1), self.w_d], axis=2)
        return self.w_e if self.w_d is None else np.concatenate([self.w_e, self.w_d.transpose(0, 2, 1)], axis=1)


@dataclass
class Linearisation:
    cost: float
    U_ee: np.ndarray     # (n_images, width, width)
    U_ed: np.ndarray     # (n_e, n_d)
    U_dd: np.ndarray     # (n_d, n_d)
    g_theta: np.ndarray  # (n_theta,) before elimination, parameter observations included
    J_x: sp.csr_matrix   # parameter observations (whitened), (k, n_theta)
    r_x: np.ndarray
    chunks: list[ChunkLinearisation]
    diag_theta: np.ndarray   # diagonal of U (parameter observations included)

    def of_points(self, name: str) -> np.ndarray:
        """A chunk quantity of every point (``"V"``, ``"g_p"``) in the block's point order."""
        parts = [getattr(ch, name) for ch in self.chunks]
        out = np.empty((sum(len(ch.points) for ch in self.chunks),) + parts[0].shape[1:])
        for ch, part in zip(self.chunks, parts):
            out[ch.points] = part
        return out


def _camera_jacobian(problem: Problem, k: int) -> np.ndarray:
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
    columns = problem._ap_columns.get(key)
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
            bound = _bound_of(problem, mine)

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
        problem._ap_columns[key] = columns
    return columns


def evaluate_ap_columns(problem: Problem) -> None:
    """Evaluate the kept AP columns of every camera now, before the threads of a pass over the chunks
    (:mod:`.parallel`) share them."""
    for k, cam in enumerate(problem.cameras):
        if cam.ap.n_params:
            _camera_jacobian(problem, k)


#: observations per block when a camera's AP columns are evaluated
AP_COLUMN_BLOCK = 8192


def _sparse_gram(sparse, o0: int, o1: int) -> np.ndarray:
    """The Gram matrix of the sparse rows of observations o0:o1 over the raw columns (n_raw, n_raw): one
    product per pattern and axis over its few columns."""
    n_raw = sparse.to_params.shape[0]
    out = np.zeros((n_raw, n_raw))
    pattern = sparse.pattern[o0:o1]
    for rows in pattern_groups(pattern):
        for k in range(2):
            cols = sparse.columns[pattern[rows[0]], k]
            X = sparse.values[o0 + rows, k]
            out[np.ix_(cols, cols)] += X.T @ X
    return out


def sparse_ap_rows(problem: Problem):
    """The whitened AP columns of a one-camera problem as sparse rows (:class:`selfcal.ap.base.SparseBasis`,
    in problem order, ``to_params`` mapping to the camera's free APs), or None: several cameras, a core
    parameter held, or rows that the AP model or the sensor gives dense only.

    Kept per problem like the dense columns (:func:`_camera_jacobian`), evaluated block by block on the
    threads of a pass, or taken over from the adjustment this one re-runs (:func:`carry_ap_columns`)."""
    if len(problem.cameras) != 1:
        return None
    cam = problem.cameras[0]
    if not cam.ap.n_params or not cam.free[:cam.n_core].all():
        return None
    key = ("sparse", 0)
    if key not in problem._ap_columns:
        o = np.arange(problem.n_image_observations)
        bound = _bound_of(problem, o) if o.size else None
        parts = {}

        def evaluate(start: int, _) -> None:
            part = o[start:start + AP_COLUMN_BLOCK]
            rows = bound.sparse_ap_columns(0, part, cam.ap)
            # whitened on the block's thread (a new array: the sensor's may be one it keeps)
            if rows is not None:
                rows = replace(rows, values=rows.values / problem.obs_sigma[part][:, :, None])
            parts[start] = rows
        if bound is not None:
            over_chunks(range(0, o.size, AP_COLUMN_BLOCK), evaluate, lambda: None)
        blocks = [parts[start] for start in sorted(parts)]
        sparse = None
        if blocks and all(b is not None for b in blocks):
            sparse = replace(blocks[0], pattern=np.concatenate([b.pattern for b in blocks]),
                             values=np.concatenate([b.values for b in blocks]))
        problem._ap_columns[key] = sparse
    sparse = problem._ap_columns[key]
    if sparse is None:
        return None
    return replace(sparse, to_params=sparse.to_params[:, cam.free[cam.n_core:]])


def _bound_of(problem: Problem, o: np.ndarray):
    """The bound sensor of observations ``o`` (of one camera, hence one sensor)."""
    return problem.sensors[int(problem.obs_sensor[o[0]])].bound


def _ap_columns(problem: Problem, k: int, o0: int, o1: int, mask) -> np.ndarray:
    """The AP columns of camera ``k`` at its observations among o0:o1 (``mask``): a view for a
    single camera, a gathered copy (kept) otherwise."""
    columns = _camera_jacobian(problem, k)[:, :, problem.cameras[k].n_core:]
    if isinstance(mask, slice):
        return columns[o0:o1]
    key = (k, o0, o1, problem.cameras[k].free[problem.cameras[k].n_core:].tobytes())
    part = problem._ap_columns.get(key)
    if part is None:
        position = np.cumsum(problem.image_camera[problem.obs_image] == k) - 1
        part = problem._ap_columns[key] = columns[position[o0:o1][mask]]
    return part


def _gather(columns: np.ndarray, rows: np.ndarray, keep: np.ndarray | None, block: int = 4096) -> np.ndarray:
    """columns[rows][:, :, keep] in one pass, block by block (no full-size temporary)."""
    out = np.empty((len(rows), columns.shape[1], columns.shape[2] if keep is None else len(keep)))
    for start in range(0, len(rows), block):
        part = columns[rows[start:start + block]]
        out[start:start + block] = part if keep is None else part[:, :, keep]
    return out


def carry_ap_columns(problem: Problem, rows: np.ndarray, previous: Problem, previous_rows: np.ndarray,
                     consume: bool = False) -> None:
    """Give ``problem`` the AP columns of ``previous`` where both use the same AP model object.

    A re-adjustment after data snooping or AP screening keeps a subset of the
    observations and of the free APs; its columns are rows and columns of the
    previous ones (rescaled where an observation's sigma changed, as in a
    variance-component iteration). ``rows`` and ``previous_rows`` are the block
    row numbers of each problem's observations in problem order. With ``consume`` the previous
    problem's arrays are taken over and compacted in place (it is not used again, or evaluates its
    columns afresh if it is).
    """
    source = row_positions(previous_rows, rows)                 # previous observation of each observation
    if source is None:
        return                                                  # not a subset of the previous observations
    for k, cam in enumerate(problem.cameras):
        old_k = next((j for j, c in enumerate(previous.cameras) if c.camera_id == cam.camera_id), None)
        if old_k is None or previous.cameras[old_k].ap is not cam.ap or not cam.ap.n_params:
            continue
        nc = cam.n_core
        old_free, free = previous.cameras[old_k].free[nc:], cam.free[nc:]
        old_columns = previous._ap_columns.get((old_k, old_free.tobytes()))
        if old_columns is None or np.any(free & ~old_free):
            continue
        old_position = np.cumsum(previous.image_camera[previous.obs_image] == old_k) - 1
        mine = problem.image_camera[problem.obs_image] == k
        take = old_position[source[mine]]
        keep = np.concatenate([np.ones(nc, bool), free[old_free]])   # the slots and the still free APs
        ratio = previous.obs_sigma[source[mine]] / problem.obs_sigma[mine]
        if len(problem.cameras) == 1 and len(previous.cameras) == 1 and np.all(ratio == 1.0):
            problem._ap_gram = _carried_gram(previous, old_columns, source, free[old_free])
        if consume and old_columns.flags.c_contiguous and np.all(np.diff(take) > 0):
            # the previous problem's array, compacted where it lies (no second copy of hundreds of MB);
            # the previous problem forgets it and would evaluate its columns afresh if used again
            del previous._ap_columns[(old_k, old_free.tobytes())]
            flat = old_columns.reshape(-1)
            width = 2 * old_columns.shape[2]
            both = np.flatnonzero(np.concatenate([keep, keep]))          # x then y row of each observation
            compact_rows(flat, width, take.astype(np.int64), both)
            columns = flat[:take.size * both.size].reshape(take.size, 2, both.size // 2)
        else:
            columns = _gather(old_columns, take, None if keep.all() else np.flatnonzero(keep))
        if np.any(ratio != 1.0):
            columns *= ratio[:, :, None]
        problem._ap_columns[(k, free.tobytes())] = columns
        sparse = (previous._ap_columns.pop if consume else previous._ap_columns.get)(("sparse", old_k), None)
        if sparse is not None and len(problem.cameras) == 1:
            values = sparse.values[take]
            if np.any(ratio != 1.0):
                values *= ratio[:, :, None]
            problem._ap_columns[("sparse", 0)] = replace(sparse, pattern=sparse.pattern[take], values=values)


def _carried_gram(previous: Problem, old_columns: np.ndarray, source: np.ndarray, keep: np.ndarray):
    """The Gram matrix of the constant AP columns of a one-camera problem that keeps the
    observations ``source`` of ``previous`` and its APs ``keep`` (bool over the previous free
    APs): the previous Gram minus the rows of the observations that were left out, or None
    (computed afresh) when there is none to carry or most rows went."""
    gram = previous._ap_gram
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


def _rows_times(rows: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """(n, 2, k) @ (k,) as one BLAS matrix-vector product (a batched 3-D matmul is ~5x slower)."""
    n, two, k = rows.shape
    if rows.flags.c_contiguous:
        return (rows.reshape(n * two, k) @ vector).reshape(n, two)
    return rows @ vector


def _camera_terms(problem: Problem, state: State, o0: int, o1: int, img: np.ndarray):
    """Additional-parameter displacement (observation units) of observations o0:o1, and per camera
    the observations it takes (mask) with the (whitened) Jacobian columns of its free APs (None when
    no camera has additional parameters)."""
    m = o1 - o0
    if not any(cam.ap.n_params for cam in problem.cameras):
        return np.zeros((m, 2)), None          # no additional parameters (BAL's 49 cameras: no mask per camera)
    # the displacement depends on the AP values alone: a cost evaluation at a state and the linearisation at the
    # same state that follows it (an accepted step) compute it once (one pass over the kept AP columns)
    values = b"".join(v[c.n_core:].tobytes() for c, v in zip(problem.cameras, state.cameras))
    cached = problem._ap_delta.get((o0, o1))
    known = cached is not None and cached[0] == values
    delta = cached[1] if known else np.zeros((m, 2))
    cam_of_obs = problem.image_camera[img]
    cam_cols = []  # (camera index, mask, whitened columns (n, 2, n_free_ap))
    single = len(problem.cameras) == 1
    sigma = problem.obs_sigma[o0:o1]
    for k, cam in enumerate(problem.cameras):
        mask = slice(None) if single else cam_of_obs == k
        if not single and not mask.any():
            continue
        nc = cam.n_core
        if cam.ap.n_params:
            a = state.cameras[k][nc:]
            free = cam.free[nc:]
            if single:
                # the kept Jacobian rows are contiguous with the core slots first:
                # one matrix-vector product over them, the slots weighted by zero
                rows = _camera_jacobian(problem, k)[o0:o1]
                columns = rows[:, :, nc:]
                if not known:
                    delta[:] = _rows_times(rows, np.concatenate([np.zeros(nc), a[free]])) * sigma
            else:
                columns = _ap_columns(problem, k, o0, o1, mask)
                if not known:
                    delta[mask] = _rows_times(columns, a[free]) * sigma[mask]
            if not known and np.any(a[~free] != 0):          # APs held at a non-zero value
                o = o0 + (np.arange(m) if single else np.flatnonzero(mask))
                held = np.where(free, 0.0, a)
                delta[mask] += _bound_of(problem, o).ap_columns(k, o, cam.ap) @ held
        else:
            columns = np.zeros((m if single else int(mask.sum()), 2, 0))
        cam_cols.append((k, mask, columns))
    problem._ap_delta[(o0, o1)] = (values, delta)
    return delta, cam_cols


def contexts(problem: Problem, state: State, jacobians: bool = True) -> list:
    """What each sensor needs of ``state`` for its predictions (rotations, ...), computed once."""
    return [slot.bound.context(state, jacobians) for slot in problem.sensors]


def predict(problem: Problem, context: list, o0: int, o1: int, points: np.ndarray, jacobians: bool):
    """Predictions f (m, 2) of observations o0:o1 by their images' sensors; with ``jacobians`` also
    (f, j_image (m, 2, width), j_point (m, 2, 3), j_core (m, 2, widest core)). Additional parameters
    excluded."""
    return predict_observations(problem, context, np.arange(o0, o1), points, jacobians)


def predict_observations(problem: Problem, context: list, o: np.ndarray, points: np.ndarray, jacobians: bool):
    """:func:`predict` of the observations ``o`` (indices in problem order)."""
    img = problem.obs_image[o]
    cam = problem.image_camera[img]
    if len(problem.sensors) == 1:
        return problem.sensors[0].bound.predict(context[0], o, img, cam, points, jacobians)
    m = len(o)
    kinds = problem.obs_sensor[o]
    n_core = max(c.n_core for c in problem.cameras)
    f = np.zeros((m, 2))
    j_e = np.zeros((m, 2, problem.image_width))
    j_p = np.zeros((m, 2, 3))
    j_c = np.zeros((m, 2, n_core))
    for s, slot in enumerate(problem.sensors):
        sel = np.flatnonzero(kinds == s)
        if not sel.size:
            continue
        out = slot.bound.predict(context[s], o[sel], img[sel], cam[sel], points[sel], jacobians)
        if not jacobians:
            f[sel] = out
            continue
        f[sel], j_e[sel], j_p[sel] = out[0], out[1], out[2]
        j_c[sel, :, :out[3].shape[2]] = out[3]
    return (f, j_e, j_p, j_c) if jacobians else f


def observation_rows(problem: Problem, state: State, o: np.ndarray):
    """Whitened residuals l - f (n, 2) and Jacobian rows of the image observations ``o`` (indices in problem
    order, any few): j_e (n, 2, width) (zero where held), j_p (n, 2, 3) and j_d (n, 2, n_d) in theta order.
    The AP columns are evaluated afresh (a problem's kept ones may have been carried away)."""
    img = problem.obs_image[o]
    f, j_e, j_p, j_i = predict_observations(problem, contexts(problem, state), o, state.points[problem.obs_point[o]],
                                            jacobians=True)
    j_d = np.zeros((len(o), 2, problem.n_d))
    delta = _ap_terms(problem, state, o, j_d)
    cam_of = problem.image_camera[img]
    for k, cam in enumerate(problem.cameras):
        sel = np.flatnonzero(cam_of == k)
        start = problem.d_offset[k] - problem.n_e
        core_free = cam.free[:cam.n_core]
        if sel.size:
            j_d[sel, :, start:start + int(core_free.sum())] = j_i[sel][:, :, :cam.n_core][:, :, core_free]
    r, w = _whiten(problem, o, img, f, delta, j_e, j_p)
    return r, j_e, j_p, j_d * w[:, :, None]


def point_rows(problem: Problem, state: State, o: np.ndarray, delta: np.ndarray):
    """Whitened residuals (n, 2) and point Jacobian rows (n, 2, 3) of the image observations ``o``, given their
    AP displacement ``delta`` (:func:`ap_displacement`): what re-intersecting points needs, the AP columns not
    evaluated again."""
    img = problem.obs_image[o]
    f, j_e, j_p, _ = predict_observations(problem, contexts(problem, state), o, state.points[problem.obs_point[o]],
                                          jacobians=True)
    r, _ = _whiten(problem, o, img, f, delta, j_e, j_p)
    return r, j_p


def ap_displacement(problem: Problem, state: State, o: np.ndarray) -> np.ndarray:
    """The AP displacement (n, 2) of the image observations ``o`` (problem order, any few), the AP columns
    evaluated afresh."""
    return _ap_terms(problem, state, o, None)


def _ap_terms(problem: Problem, state: State, o: np.ndarray, j_d: np.ndarray | None) -> np.ndarray:
    """AP displacement of observations ``o``; with ``j_d`` (n, 2, n_d) the free AP columns are written into it."""
    delta = np.zeros((len(o), 2))
    cam_of = problem.image_camera[problem.obs_image[o]]
    for k, cam in enumerate(problem.cameras):
        sel = np.flatnonzero(cam_of == k)
        if not sel.size or not cam.ap.n_params:
            continue
        full = _bound_of(problem, o[sel]).ap_columns(k, o[sel], cam.ap)
        delta[sel] = full @ state.cameras[k][cam.n_core:]
        if j_d is not None:
            start = problem.d_offset[k] - problem.n_e + int(cam.free[:cam.n_core].sum())
            ap_free = cam.free[cam.n_core:]
            j_d[sel, :, start:start + int(ap_free.sum())] = full[:, :, ap_free]
    return delta


def _whiten(problem: Problem, o, img: np.ndarray, f: np.ndarray, delta: np.ndarray, j_e: np.ndarray,
            j_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals l - f - delta of observations ``o`` (a slice or indices) and their weights 1/sigma; the
    image and point rows are whitened in place (held image parameters zeroed)."""
    w = 1.0 / problem.obs_sigma[o]
    r = (problem.obs_value[o] - f - delta) * w
    j_e *= w[:, :, None]
    j_p *= w[:, :, None]
    if not problem.all_images_free:
        j_e *= problem.image_free[img][:, None, :]
    return r, w


def image_residuals(problem: Problem, state: State, o0: int = 0, o1: int | None = None, context=None) -> np.ndarray:
    """Residuals l - f (observation units) of image observations o0:o1 (sorted order), shape (m, 2)."""
    context = contexts(problem, state, jacobians=False) if context is None else context
    if o0 == 0 and o1 is None and len(problem.chunks) > 1:
        # chunk by chunk (the AP columns are kept per assembly chunk), on the threads of a pass
        out = np.empty((problem.n_image_observations, 2))
        evaluate_ap_columns(problem)

        def work(cs, _) -> None:
            out[cs.o0:cs.o1] = image_residuals(problem, state, cs.o0, cs.o1, context)
        over_chunks(problem.structure().chunks, work, lambda: None)
        return out
    o1 = problem.n_image_observations if o1 is None else o1
    img = problem.obs_image[o0:o1]
    f = predict(problem, context, o0, o1, state.points[problem.obs_point[o0:o1]], jacobians=False)
    delta, _ = _camera_terms(problem, state, o0, o1, img)
    return problem.obs_value[o0:o1] - (f + delta)


def parameter_observation_groups(problem: Problem) -> np.ndarray:
    """The group of each row of :func:`parameter_observations`: "camera" for a-priori camera parameters,
    "image" for a-priori image parameters, else the trajectory sensor ("GNSS", "IMU")."""
    labels = []
    for cam in problem.cameras:
        labels += ["camera"] * int(np.sum(cam.free & np.isfinite(cam.prior_sigma)))
    labels += ["image"] * int(np.sum(problem.image_free & np.isfinite(problem.image_prior_sigma)))
    for t in problem.trajectory:
        labels += [t.sensor] * (3 * len(t.index))
    return np.array(labels, dtype=object)


def _mounted_sensor(t, eop: np.ndarray, mounting: np.ndarray):
    """What a trajectory sensor observes of each image before shift/drift, with derivatives.

    GNSS: X0 + M^T a (lever arm a in the camera frame). IMU: the angles of
    B(b)^T M (boresight angles b). Returns the model (n, 3), its derivatives with
    respect to the image's six orientation unknowns (n, 3, 6) and with respect to
    the mounting (n, 3, 3).
    """
    n = len(eop)
    d_eop = np.zeros((n, 3, 6))
    if not t.mounted:
        d_eop[:, np.arange(3), t.offset + np.arange(3)] = 1.0
        return eop[:, t.offset:t.offset + 3].copy(), d_eop, np.zeros((n, 3, 3))
    M, dM = matrix_from_opk_with_derivatives(eop[:, 3:])
    if t.offset == 0:
        d_eop[:, np.arange(3), np.arange(3)] = 1.0
        d_eop[:, :, 3:] = np.einsum("nkji,j->nik", dM, mounting)       # d(M^T a)/d angle k
        return eop[:, :3] + np.einsum("nji,j->ni", M, mounting), d_eop, np.swapaxes(M, 1, 2)
    B, dB = matrix_from_opk_with_derivatives(mounting)
    N = np.einsum("ji,njk->nik", B, M)                                  # B^T M
    angles, d_angles = opk_from_matrix_with_derivatives(N)
    d_eop[:, :, 3:] = np.einsum("naij,nkij->nak", d_angles, np.einsum("ji,nkjl->nkil", B, dM))
    d_mount = np.einsum("naij,nkij->nak", d_angles, np.einsum("kji,njl->nkil", dB, M))  # dB_k^T M
    return angles, d_eop, d_mount


def parameter_observations(problem: Problem, state: State) -> tuple[sp.csr_matrix, np.ndarray]:
    """Whitened Jacobian (k, n_theta) and residuals l - f of the parameter observations."""
    rows, cols, vals, res = [], [], [], []
    k = 0
    for cam, values, start in zip(problem.cameras, state.cameras, problem.d_offset):
        free_pos = np.cumsum(cam.free) - 1
        for i in np.flatnonzero(cam.free & np.isfinite(cam.prior_sigma)):
            sigma = cam.prior_sigma[i]
            rows.append(k)
            cols.append(start + free_pos[i])
            vals.append(1.0 / sigma)
            res.append((cam.prior_value[i] - values[i]) / sigma)
            k += 1
    weighted = np.flatnonzero((problem.image_free & np.isfinite(problem.image_prior_sigma)).ravel())
    if weighted.size:
        sigma = problem.image_prior_sigma.ravel()[weighted]
        rows += list(k + np.arange(weighted.size))
        cols += list(weighted)
        vals += list(1.0 / sigma)
        res += list((problem.image_prior_value.ravel()[weighted] - state.image.ravel()[weighted]) / sigma)
        k += weighted.size
    width = problem.image_width
    x_col = problem.n_e + problem.n_d
    x_full = 0
    for t in problem.trajectory:
        n = len(t.index)
        if n == 0:
            x_col += int(t.free.sum())
            x_full += t.n_params
            continue
        powers = t.design()                                            # (n, order + 1)
        values = state.extra[x_full:x_full + t.n_params]
        model, d_eop, d_mount = _mounted_sensor(t, state.image[t.index], t.mounting_of(values))
        if t.order >= 0:
            coeff = values[:t.n_strip_params].reshape(len(t.strips), t.order + 1, 3)
            model += np.einsum("nk,nka->na", powers, coeff[t.strip_of])
        diff = t.observed - model
        if t.wrap:
            diff = _wrap(diff)
        rows_here = k + np.arange(3 * n).reshape(n, 3)
        # d(model)/d(the image's six orientation unknowns), whitened: (n, 3 rows, 6 columns)
        nz = d_eop != 0
        rows.append(np.broadcast_to(rows_here[:, :, None], (n, 3, 6))[nz])
        cols.append(np.broadcast_to(width * t.index[:, None, None] + np.arange(6)[None, None, :], (n, 3, 6))[nz])
        vals.append((d_eop / t.sigma[:, :, None])[nz])
        if t.estimate_mounting:
            free_pos = np.cumsum(t.free) - 1
            ok = t.free[t.n_strip_params:t.n_strip_params + 3]
            mount_cols = x_col + free_pos[t.n_strip_params + np.arange(3)]
            rows.append(np.broadcast_to(rows_here[:, :, None], (n, 3, 3))[:, :, ok].ravel())
            cols.append(np.broadcast_to(mount_cols[None, None, :], (n, 3, 3))[:, :, ok].ravel())
            vals.append((d_mount / t.sigma[:, :, None])[:, :, ok].ravel())
        if t.order >= 0:
            # column of (strip s, power j, axis a) among this sensor's free parameters
            full_index = (t.strip_of[:, None, None] * (t.order + 1) + np.arange(t.order + 1)[None, :, None]) * 3 \
                + np.arange(3)[None, None, :]                           # (n, order + 1, 3)
            free_pos = np.cumsum(t.free) - 1
            ok = t.free[full_index]
            r_idx = np.broadcast_to(rows_here[:, None, :], full_index.shape)
            rows.append(r_idx[ok])
            cols.append(x_col + free_pos[full_index[ok]])
            vals.append((np.broadcast_to(powers[:, :, None], full_index.shape) / t.sigma[:, None, :])[ok])
        res.append((diff / t.sigma).ravel())
        k += 3 * n
        x_col += int(t.free.sum())
        x_full += t.n_params
    if k == 0:
        return sp.csr_matrix((0, problem.n_theta)), np.zeros(0)
    rows = np.concatenate([np.atleast_1d(r) for r in rows])
    cols = np.concatenate([np.atleast_1d(c) for c in cols])
    vals = np.concatenate([np.atleast_1d(v) for v in vals])
    res = np.concatenate([np.atleast_1d(r) for r in res])
    return sp.csr_matrix((vals, (rows, cols)), shape=(k, problem.n_theta)), res


def chunk_rows(problem: Problem, state: State, cs, context=None, compact: bool = False):
    """Whitened residuals and Jacobian rows of the image observations of one chunk.

    Returns
    -------
    r : (m, 2) whitened residuals l - f
    j_e : (m, 2, width) derivatives with respect to the observation's image parameters (zero where held)
    j_p : (m, 2, 3) derivatives with respect to its point
    j_d : (m, 2, n_d) derivatives with respect to the free camera parameters (theta order); for a
        single camera a view of a kept array, valid until the next call: read it, do not keep or change it.
        With ``compact``, (m, 2, width): the derivatives with respect to the free parameters of the
        observation's own camera, in the order of :meth:`Problem.camera_columns`
    """
    n_e, n_d = problem.n_e, problem.n_d
    context = contexts(problem, state) if context is None else context
    o0, o1, img = cs.o0, cs.o1, cs.img
    m = o1 - o0
    f, j_e, j_p, j_i = predict(problem, context, o0, o1, state.points[problem.obs_point[o0:o1]], jacobians=True)
    delta, cam_cols = _camera_terms(problem, state, o0, o1, img)
    r, w = _whiten(problem, slice(o0, o1), img, f, delta, j_e, j_p)
    if len(problem.cameras) == 1 and problem.cameras[0].free[:problem.cameras[0].n_core].all():
        # one camera with its core parameters free, the common case: the rows are a view of the
        # kept AP Jacobian with the core derivatives written into its slots (valid until the next call)
        nc = problem.cameras[0].n_core
        j_d = _camera_jacobian(problem, 0)[o0:o1]
        np.multiply(j_i[:, :, :nc], w[:, :, None], out=j_d[:, :, :nc])
        return r, j_e, j_p, j_d
    j_d = np.zeros((m, 2, problem.camera_columns().shape[1] if compact else n_d))
    # compact rows of cameras alike (BAL: 49 cameras with f, k1, k2 free): the core slots in one product, not one
    # masked copy per camera (8.7 of a chunk's 10 ms on BAL problem-49)
    n_core_all = {c.n_core for c in problem.cameras}
    alike = compact and len(n_core_all) == 1 and all(c.free[:c.n_core].all() for c in problem.cameras)
    if alike:
        nc = n_core_all.pop()
        np.multiply(j_i[:, :, :nc], w[:, :, None], out=j_d[:, :, :nc])
    if cam_cols is None:                        # no camera has additional parameters
        if alike:
            return r, j_e, j_p, j_d
        cam_of_obs = problem.image_camera[img]
        cam_cols = [(k, cam_of_obs == k, np.zeros((0, 2, 0))) for k in range(len(problem.cameras))]
    for k, mask, columns in cam_cols:
        cam = problem.cameras[k]
        start = 0 if compact else problem.d_offset[k] - n_e
        core_free = cam.free[:cam.n_core]
        n_core = int(core_free.sum())
        if n_core and not alike:
            j_d[mask, :, start:start + n_core] = j_i[mask][:, :, :cam.n_core][:, :, core_free] * w[mask][:, :, None]
        if columns.shape[2]:
            j_d[mask, :, start + n_core:start + n_core + columns.shape[2]] = columns
    return r, j_e, j_p, j_d


def _gram(rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """rows[:, columns]^T rows[:, columns]: the product of all columns, then the block of ``columns``. A
    strided view or a gathered copy of the columns is several times slower than the few extra ones."""
    return _self_product(rows)[np.ix_(columns, columns)]


def _self_product(Z: np.ndarray) -> np.ndarray:
    """Z^T Z. NumPy sees the transpose of the same array and takes BLAS's symmetric rank-k update (half the
    flops of a general product), and releases the interpreter lock in it, so the threads of a pass
    (:mod:`.parallel`) run theirs side by side; SciPy's BLAS wrappers (dsyrk) hold the lock."""
    Z = np.ascontiguousarray(Z)
    return Z.T @ Z


def linearise(problem: Problem, state: State) -> Linearisation:
    """Jacobians and normal-equation blocks at ``state``."""
    n_img, n_e, n_d, width = problem.n_images, problem.n_e, problem.n_d, problem.image_width
    structure = problem.structure()
    context = contexts(problem, state)
    control_of_point = np.full(problem.n_points, -1)
    control_of_point[problem.control_index] = np.arange(len(problem.control_index))
    varying = problem.d_varying()
    constant = np.setdiff1d(np.arange(n_d), varying)
    if not constant.size:
        varying = np.arange(n_d)
    compact = problem.compact_cameras
    if compact:
        cols = problem.camera_columns()
        constant = constant[:0]                 # the camera blocks are summed in every iteration
        varying = np.arange(n_d)
    gram = problem._ap_gram
    build_gram = gram is None and constant.size > 0
    # one camera: the AP columns are its sparse rows times a map, where the model gives them so; their Gram
    # matrix is summed over each row's few raw columns, then mapped (T^T R T)
    sparse = sparse_ap_rows(problem) if build_gram else None
    if sparse is not None and not np.array_equal(constant, np.arange(problem.cameras[0].n_core, n_d)):
        sparse = None
    gram_size = sparse.to_params.shape[0] if sparse is not None else constant.size
    evaluate_ap_columns(problem)

    def new_sums() -> dict:
        return {"U_ee": np.zeros((n_img, width, width)), "U_ed": np.zeros((n_e, n_d)), "U_dd": np.zeros((n_d, n_d)),
                "g_e": np.zeros((n_img, width)), "g_d": np.zeros(n_d), "cost": np.zeros(1),
                "gram": np.zeros((gram_size, gram_size)) if build_gram else None}

    def work(cs, sums: dict) -> ChunkLinearisation:
        p0, p1, o0, o1 = cs.p0, cs.p1, cs.o0, cs.o1
        m, n_pc = o1 - o0, p1 - p0
        r, j_e, j_p, j_d = chunk_rows(problem, state, cs, context, compact)
        sums["cost"] += 0.5 * float(np.sum(r * r))

        # image and point blocks, and the coupling of each observation's image and point
        V, g_p, w_e = accumulate_observations(j_e, j_p, r, cs.img, cs.ptl, sums["U_ee"], sums["g_e"], n_pc)
        W_pd, w_d = None, None
        if n_d and compact:
            w_d = camera_couplings_compact(j_d, j_e, j_p, r, cs.img, problem.image_camera[cs.img], cols,
                                           sums["U_ed"], sums["U_dd"], sums["g_d"])
        elif n_d:
            W_pd = np.zeros((3 * n_pc, n_d))
            U_vd = np.zeros((varying.size, n_d))
            camera_couplings(j_d, j_e, j_p, r, cs.img, cs.ptl, varying, sums["U_ed"], W_pd, sums["g_d"], U_vd)
            U_dd = sums["U_dd"]
            if constant.size:
                # the AP columns are constant: their Gram block is summed once per problem
                U_dd[varying, :] += U_vd
                U_dd[np.ix_(constant, varying)] += U_vd[:, constant].T
                if build_gram:
                    sums["gram"] += (_gram(j_d.reshape(2 * m, n_d), constant) if sparse is None else
                                     _sparse_gram(sparse, o0, o1))
            else:
                U_dd += U_vd

        ctl = control_of_point[cs.points]
        has = np.flatnonzero(ctl >= 0)
        if has.size:
            W = problem.control_weight[ctl[has]]
            rc = np.einsum("nij,nj->ni", W, problem.control_xyz[ctl[has]] - state.points[cs.points[has]])
            sums["cost"] += 0.5 * float(np.sum(rc * rc))
            V[has] += np.einsum("nki,nkj->nij", W, W)
            g_p[has] += np.einsum("nki,nk->ni", W, rc)
        return ChunkLinearisation(p0, p1, o0, o1, cs.points, V, g_p, w_e, W_pd, w_d)

    chunks, parts = over_chunks(structure.chunks, work, new_sums)
    U_ee, U_ed, U_dd, g_e, g_d, cost = (sum(part[name] for part in parts)
                                        for name in ("U_ee", "U_ed", "U_dd", "g_e", "g_d", "cost"))
    cost = float(cost[0])
    if build_gram:
        gram = sum(part["gram"] for part in parts)
        if sparse is not None:
            gram = sparse.to_params.T @ gram @ sparse.to_params

    if constant.size:
        if build_gram:
            problem._ap_gram = gram
        U_dd[np.ix_(constant, constant)] += gram
    if not problem.all_images_free:
        # held image parameters: a unit diagonal and no coupling, so that their correction is zero
        held_image, held_entry = np.nonzero(~problem.image_free)
        U_ee[held_image, held_entry, held_entry] = 1.0
    J_x, r_x = parameter_observations(problem, state)
    cost += 0.5 * float(np.sum(r_x * r_x))
    g_theta = np.concatenate([g_e.ravel(), g_d, np.zeros(problem.n_extra)])
    if J_x.shape[0]:
        g_theta += J_x.T @ r_x
    diag_theta = np.concatenate([np.einsum("nii->ni", U_ee).ravel(), np.diag(U_dd).copy(),
                                 np.zeros(problem.n_extra)])
    if J_x.shape[0]:
        diag_theta += np.asarray(J_x.multiply(J_x).sum(axis=0)).ravel()
    return Linearisation(cost, U_ee, U_ed, U_dd, g_theta, J_x, r_x, chunks, diag_theta)


class SingularPoints(AdjustmentError):
    """Point blocks of the normal equations that cannot be inverted (``indices`` into the points)."""

    def __init__(self, indices: np.ndarray):
        self.indices = np.asarray(indices)
        super().__init__(f"{len(self.indices)} object point(s) are not determined by their rays (parallel rays, "
                         f"or a point gone to infinity or behind its cameras)")


def _damped_inverse(V: np.ndarray, lam: float, points: np.ndarray | None = None) -> np.ndarray:
    """The inverse damped point blocks; a block that is singular raises SingularPoints naming its point
    (``points``: the block's point of each block, by default its index)."""
    if lam:
        V = V + lam * np.einsum("nii,ij->nij", V, np.eye(3))
    out = np.empty_like(V)
    if spd_inverse_3x3(V, out) < 0:
        return out
    try:                                    # a block not positive definite: LU, which names singular ones
        return np.linalg.inv(V)
    except np.linalg.LinAlgError:
        w = np.linalg.eigvalsh(V)
        bad = np.flatnonzero(w[:, 0] <= 1e-14 * np.abs(w[:, 2]))
        raise SingularPoints(bad if points is None else points[bad]) from None


def _point_schur(Vi: np.ndarray, W_pd: np.ndarray) -> np.ndarray:
    """W_pd^T blockdiag(Vi) W_pd, (n_d, n_d): with Vi = L L^T per point, Z = blockdiag(L^T) W_pd
    and the product is Z^T Z, a symmetric rank-k update (half the flops of a general product)."""
    try:
        L = np.linalg.cholesky(Vi)
    except np.linalg.LinAlgError:                       # a point block not positive definite: the plain product
        return W_pd.T @ point_blocks_times(Vi, W_pd, False)
    return _self_product(point_blocks_times(L, W_pd, True))


def reduce(problem: Problem, lin: Linearisation, lam: float = 0.0, dense: bool = True):
    """Reduced normal matrix S and right-hand side g of theta, with damping ``lam``.

    The damping adds ``lam * diag(N)`` to the full normal matrix N
    (Levenberg-Marquardt with Marquardt's scaling).

    The image-image part of W V^-1 W^T is summed over the pairs of
    observations of each point (one 6x6 block per pair of images that share
    the point); the camera-parameter parts are dense products.

    Returns
    -------
    S : ndarray or scipy.sparse.csc_matrix, (n_theta, n_theta)
    g : ndarray (n_theta,)
    v_inv : list of (n_pc, 3, 3) damped inverse point blocks per chunk
    """
    n_img, n_e, n_d, n_t = problem.n_images, problem.n_e, problem.n_d, problem.n_theta
    w = problem.image_width
    structure = problem.structure()
    S_ed = lin.U_ed.copy()
    S_dd = lin.U_dd.copy()
    g = lin.g_theta.copy()
    diag_blocks = lin.U_ee.copy()
    off_blocks = np.zeros((len(structure.pair_keys), w, w))
    # compact cameras: an observation's block is its image's columns and its camera's (one camera per
    # image in BAL); the Schur terms of both are summed over the pairs of each point's observations at once
    # and spread over S_ee, S_ed and S_dd afterwards
    compact = bool(n_d) and bool(lin.chunks) and lin.chunks[0].w_d is not None
    if compact:
        own = problem.camera_columns()[problem.image_camera]               # (n_images, camera width), -1 pads
        wide = w + own.shape[1]
        wide_diag = np.zeros((n_img, wide, wide))
        wide_off = np.zeros((len(structure.pair_keys), wide, wide))
    n_pairs = len(structure.pair_keys)

    def new_sums() -> dict:
        wider = wide if compact else w
        return {"diag": np.zeros((n_img, wider, wider)), "off": np.zeros((n_pairs, wider, wider)),
                "g": np.zeros(n_t), "S_ed": np.zeros((n_e, n_d)), "S_dd": np.zeros((n_d, n_d))}

    def work(pair, sums: dict) -> np.ndarray:
        ch, cs = pair
        Vi = _damped_inverse(ch.V, lam, ch.points)
        g = sums["g"]
        Y_t = schur_image_blocks(Vi, cs.ptl, ch.couplings(transposed=True), cs.img, cs.pair_a, cs.pair_b,
                                 cs.pair_key, sums["diag"], sums["off"])          # (m, 3, w or wide) = V^-1 W^T
        if compact:
            yg = np.einsum("oki,ok->oi", Y_t, ch.g_p[cs.ptl])
            g[:n_e] -= (cs.sum_by_image @ yg[:, :w]).ravel()
            cols = own[cs.img]
            np.subtract.at(g, n_e + cols[cols >= 0], yg[:, w:][cols >= 0])
            return Vi
        g[:n_e] -= (cs.sum_by_image @ np.einsum("oki,ok->oi", Y_t, ch.g_p[cs.ptl])).ravel()
        if n_d:
            subtract_image_couplings(Y_t, ch.W_pd, cs.img, cs.ptl, sums["S_ed"])
            sums["S_dd"] -= _point_schur(Vi, ch.W_pd)
            g[n_e:n_e + n_d] -= ch.W_pd.T @ np.einsum("pij,pj->pi", Vi, ch.g_p).ravel()
        return Vi

    v_inv, parts = over_chunks(list(zip(lin.chunks, structure.chunks)), work, new_sums)
    for part in parts:
        g += part["g"]
        S_ed += part["S_ed"]
        S_dd += part["S_dd"]
        if compact:
            wide_diag += part["diag"]
            wide_off += part["off"]
        else:
            diag_blocks += part["diag"]
            off_blocks += part["off"]
    ia, ib = structure.image_pair_a, structure.image_pair_b
    if compact:
        diag_blocks += wide_diag[:, :w, :w]
        off_blocks += wide_off[:, :w, :w]
        _spread_camera_blocks(wide_diag, wide_off, own, ia, ib, w, S_ed, S_dd)

    damp = lam * lin.diag_theta
    if dense:
        S = np.zeros((n_t, n_t))
        S_ee = np.zeros((n_img, n_img, w, w))
        S_ee[np.arange(n_img), np.arange(n_img)] = diag_blocks
        S_ee[ia, ib] = off_blocks
        S_ee[ib, ia] = off_blocks.transpose(0, 2, 1)
        S[:n_e, :n_e] = S_ee.transpose(0, 2, 1, 3).reshape(n_e, n_e)
        S[:n_e, n_e:n_e + n_d] = S_ed
        S[n_e:n_e + n_d, :n_e] = S_ed.T
        S[n_e:n_e + n_d, n_e:n_e + n_d] = S_dd
        if lin.J_x.shape[0]:
            S += (lin.J_x.T @ lin.J_x).toarray()
        S[np.diag_indices(n_t)] += damp
        S = 0.5 * (S + S.T)
    else:
        bi = np.concatenate([np.arange(n_img), ia, ib])
        bj = np.concatenate([np.arange(n_img), ib, ia])
        blocks = np.concatenate([diag_blocks, off_blocks, off_blocks.transpose(0, 2, 1)])
        rows = np.broadcast_to(w * bi[:, None, None] + np.arange(w)[None, :, None], blocks.shape)
        cols = np.broadcast_to(w * bj[:, None, None] + np.arange(w)[None, None, :], blocks.shape)
        S_ee = sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(n_e, n_e))
        top = sp.hstack([S_ee, sp.csr_matrix(S_ed), sp.csr_matrix((n_e, problem.n_extra))])
        mid = sp.hstack([sp.csr_matrix(S_ed.T), sp.csr_matrix(S_dd), sp.csr_matrix((n_d, problem.n_extra))])
        bot = sp.csr_matrix((problem.n_extra, n_t))
        S = sp.vstack([top, mid, bot]).tocsc()
        if lin.J_x.shape[0]:
            S = S + (lin.J_x.T @ lin.J_x).tocsc()
        S = S + sp.diags(damp)
        S = (0.5 * (S + S.T)).tocsc()
    return S, g, v_inv


def _spread_camera_blocks(wide_diag, wide_off, own, ia, ib, w, S_ed, S_dd) -> None:
    """Add the camera rows and columns of the per-image blocks (image then camera columns, ``own``: each
    image's camera columns, -1 pads) to S_ed and S_dd: each image's own block, and each pair of images
    (ia, ib) sharing a point with its transpose. Several images may share a camera: np.add.at sums them."""
    rows = w * np.arange(len(own))[:, None] + np.arange(w)[None, :]            # (n_images, w) image rows

    def add(image_rows, cams_a, cams_b, e_part, d_part):
        keep = cams_b >= 0
        r = np.broadcast_to(image_rows[:, :, None], e_part.shape)
        c = np.broadcast_to(cams_b[:, None, :], e_part.shape)
        mask = np.broadcast_to(keep[:, None, :], e_part.shape)
        np.add.at(S_ed, (r[mask], c[mask]), e_part[mask])
        both = (cams_a >= 0)[:, :, None] & keep[:, None, :]
        ra = np.broadcast_to(cams_a[:, :, None], d_part.shape)
        cb = np.broadcast_to(cams_b[:, None, :], d_part.shape)
        np.add.at(S_dd, (ra[both], cb[both]), d_part[both])
    add(rows, own, own, wide_diag[:, :w, w:], wide_diag[:, w:, w:])
    if len(ia):
        add(rows[ia], own[ia], own[ib], wide_off[:, :w, w:], wide_off[:, w:, w:])
        add(rows[ib], own[ib], own[ia], wide_off[:, w:, :w].transpose(0, 2, 1), wide_off[:, w:, w:].transpose(0, 2, 1))


def back_substitute(problem: Problem, lin: Linearisation, v_inv: list, d_theta: np.ndarray) -> np.ndarray:
    """Point corrections d_p = V^-1 (g_p - W^T d_theta), shape (n_points, 3)."""
    n_e, n_d = problem.n_e, problem.n_d
    d_e = d_theta[:n_e].reshape(-1, problem.image_width)
    d_d = d_theta[n_e:n_e + n_d]
    d_p = np.zeros((problem.n_points, 3))
    columns = problem.camera_columns() if n_d else None

    def work(chunk, _) -> None:                 # each chunk writes its own points
        ch, Vi = chunk
        img = problem.obs_image[ch.o0:ch.o1]
        starts = problem.point_start[ch.p0:ch.p1] - ch.o0
        wt = np.add.reduceat(np.einsum("oik,oi->ok", ch.w_e, d_e[img]), starts, axis=0)
        if n_d and ch.w_d is not None:
            d_own = np.append(d_d, 0.0)[columns[problem.image_camera[img]]]   # -1 pads: 0
            wt += np.add.reduceat(np.einsum("okc,oc->ok", ch.w_d, d_own), starts, axis=0)
        elif n_d:
            wt += (ch.W_pd @ d_d).reshape(-1, 3)
        d_p[ch.points] = np.einsum("pij,pj->pi", Vi, ch.g_p - wt)
    over_chunks(list(zip(lin.chunks, v_inv)), work, lambda: None)
    return d_p


def evaluate_cost(problem: Problem, state: State) -> float:
    """0.5 v^T P v of all observation groups at ``state``."""
    v = image_residuals(problem, state) / problem.obs_sigma
    cost = 0.5 * float(np.sum(v * v))
    if len(problem.control_index):
        rc = np.einsum("nij,nj->ni", problem.control_weight, problem.control_xyz - state.points[problem.control_index])
        cost += 0.5 * float(np.sum(rc * rc))
    _, r_x = parameter_observations(problem, state)
    return cost + 0.5 * float(np.sum(r_x * r_x))
