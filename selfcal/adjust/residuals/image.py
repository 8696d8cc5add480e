"""Image observations: each image point's prediction by its image's sensor, whitened, with its Jacobian rows.

The observations are the problem's arrays (``Problem.obs_*``, sorted by point: the structure the Schur
assembly is cut along). Their sensors (:mod:`selfcal.sensors`) predict them with analytic Jacobians; the
additional parameters add their displacement (:mod:`selfcal.adjust.ap_columns`). Every row is whitened by
``Problem.obs_sigma``: the a-priori standard deviation in the sensor's observation units divided by the square
root of the observation's weight factor (``Problem.obs_weight``: 1, or a robust weight below it), so that a
re-weighted observation is a rescaled one everywhere in the engine.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..ap_columns import bound_of, camera_jacobian, camera_terms, evaluate_ap_columns
from ..parallel import over_chunks
from ..problem import Problem, State

__all__ = ["contexts", "predict", "predict_observations", "observation_rows", "point_rows", "ap_displacement",
           "image_residuals", "chunk_rows", "whiten", "reweight_observations"]


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
    r, w = whiten(problem, o, img, f, delta, j_e, j_p)
    return r, j_e, j_p, j_d * w[:, :, None]


@dataclass
class PointRays:
    """The rays of a set of points (problem order, point after point) with their dense rows in θ:
    :func:`point_rays`."""
    o: np.ndarray            # (m,) observation indices in problem order
    counts: np.ndarray       # (points,) rays per point
    starts: np.ndarray       # (points,) each point's first ray in ``o``
    owner: np.ndarray        # (m,) each ray's point (0 .. points - 1)
    r: np.ndarray            # (m, 2) whitened residuals
    J: np.ndarray            # (m, 2, n_θ) whitened Jacobian in θ (image, then camera unknowns)
    j_p: np.ndarray          # (m, 2, 3) whitened point Jacobians
    V: np.ndarray            # (points, 3, 3) Σ J_pᵀ J_p over each point's rays
    W: np.ndarray            # (points, 3, n_θ) Σ J_pᵀ J over each point's rays


def point_rays(problem: Problem, state: State, positions: np.ndarray) -> PointRays:
    """Every ray of the points at ``positions`` (indices of the problem's points) with its residual and its dense
    row in θ, and per point the normal blocks V and W: what the projections off the points' own unknowns need
    (a few thousand rays at a time: J is dense in θ)."""
    counts = problem.point_start[positions + 1] - problem.point_start[positions]
    starts = np.cumsum(counts) - counts
    o = np.repeat(problem.point_start[positions], counts) + np.arange(counts.sum()) - np.repeat(starts, counts)
    owner = np.repeat(np.arange(len(positions)), counts)
    r, j_e, j_p, j_d = observation_rows(problem, state, o)
    m, n_e, width = len(o), problem.n_e, problem.image_width
    J = np.zeros((m, 2, problem.n_theta))
    columns = (width * problem.obs_image[o])[:, None] + np.arange(width)[None, :]
    J[np.arange(m)[:, None, None], np.arange(2)[None, :, None], columns[:, None, :]] = j_e
    J[:, :, n_e:n_e + problem.n_d] = j_d
    V = np.add.reduceat(np.einsum("oki,okj->oij", j_p, j_p), starts, axis=0)
    W = np.add.reduceat(np.einsum("oki,okt->oit", j_p, J), starts, axis=0)
    return PointRays(o, counts, starts, owner, r, J, j_p, V, W)


def point_rows(problem: Problem, state: State, o: np.ndarray, delta: np.ndarray):
    """Whitened residuals (n, 2) and point Jacobian rows (n, 2, 3) of the image observations ``o``, given their
    AP displacement ``delta`` (:func:`ap_displacement`): what re-intersecting points needs, the AP columns not
    evaluated again."""
    img = problem.obs_image[o]
    f, j_e, j_p, _ = predict_observations(problem, contexts(problem, state), o, state.points[problem.obs_point[o]],
                                          jacobians=True)
    r, _ = whiten(problem, o, img, f, delta, j_e, j_p)
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
        full = bound_of(problem, o[sel]).ap_columns(k, o[sel], cam.ap)
        delta[sel] = full @ state.cameras[k][cam.n_core:]
        if j_d is not None:
            start = problem.d_offset[k] - problem.n_e + int(cam.free[:cam.n_core].sum())
            ap_free = cam.free[cam.n_core:]
            j_d[sel, :, start:start + int(ap_free.sum())] = full[:, :, ap_free]
    return delta


def whiten(problem: Problem, o, img: np.ndarray, f: np.ndarray, delta: np.ndarray, j_e: np.ndarray,
            j_p: np.ndarray, hold: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals l - f - delta of observations ``o`` (a slice or indices) and their weights 1/sigma; the
    image and point rows are whitened in place (held image parameters zeroed, unless ``hold`` is False: rows in
    working columns, whose map to the image parameters holds them, :mod:`selfcal.adjust.working`)."""
    w = 1.0 / problem.obs_sigma[o]
    r = (problem.obs_value[o] - f - delta) * w
    j_e *= w[:, :, None]
    j_p *= w[:, :, None]
    if hold and not problem.all_images_free:
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
    delta, _ = camera_terms(problem, state, o0, o1, img)
    return problem.obs_value[o0:o1] - (f + delta)


def chunk_rows(problem: Problem, state: State, cs, context=None, compact: bool = False, working: bool = False):
    """Whitened residuals and Jacobian rows of the image observations of one chunk.

    Returns
    -------
    r : (m, 2) whitened residuals l - f
    j_e : (m, 2, width) derivatives with respect to the observation's image parameters (zero where held);
        with ``working`` (a problem with :func:`selfcal.adjust.working.working_columns`), (m, 2, slots): with respect
        to the working columns ``columns`` names, held parameters not zeroed
    j_p : (m, 2, 3) derivatives with respect to its point
    j_d : (m, 2, n_d) derivatives with respect to the free camera parameters (theta order); for a
        single camera a view of a kept array, valid until the next call: read it, do not keep or change it.
        With ``compact``, (m, 2, width): the derivatives with respect to the free parameters of the
        observation's own camera, in the order of :meth:`Problem.camera_columns`
    slot_columns : (m, slots) int64, j_e's working columns; None without ``working``
    """
    n_e, n_d = problem.n_e, problem.n_d
    context = contexts(problem, state) if context is None else context
    o0, o1, img = cs.o0, cs.o1, cs.img
    m = o1 - o0
    points = state.points[problem.obs_point[o0:o1]]
    slot_columns = None
    if working:
        cam = problem.image_camera[img]
        f, j_e, slot_columns, j_p, j_i = problem.sensors[0].bound.predict_working(context[0], np.arange(o0, o1), img,
                                                                              cam, points)
    else:
        f, j_e, j_p, j_i = predict(problem, context, o0, o1, points, jacobians=True)
    delta, cam_cols = camera_terms(problem, state, o0, o1, img)
    r, w = whiten(problem, slice(o0, o1), img, f, delta, j_e, j_p, hold=not working)
    if len(problem.cameras) == 1 and problem.cameras[0].free[:problem.cameras[0].n_core].all():
        # one camera with its core parameters free, the common case: the rows are a view of the
        # kept AP Jacobian with the core derivatives written into its slots (valid until the next call)
        nc = problem.cameras[0].n_core
        j_d = camera_jacobian(problem, 0)[o0:o1]
        np.multiply(j_i[:, :, :nc], w[:, :, None], out=j_d[:, :, :nc])
        return r, j_e, j_p, j_d, slot_columns
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
            return r, j_e, j_p, j_d, slot_columns
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
    return r, j_e, j_p, j_d, slot_columns



def reweight_observations(problem: Problem, weights: np.ndarray, tolerance: float = 0.0) -> int:
    """Give the image observations (problem order) the weight factors ``weights`` where they differ from their
    current ones by more than ``tolerance``; how many changed. A weight factor w makes an observation's sigma
    sigma_apriori / sqrt(w): its whitened rows, kept AP columns included, are rescaled in place, and the kept
    Gram matrix follows (:meth:`~selfcal.adjust.ap_columns.APColumnCache.rescale`)."""
    weights = np.asarray(weights, float)
    move = np.flatnonzero(np.abs(weights - problem.obs_weight) > tolerance)
    if not move.size:
        return 0
    ratio = np.sqrt(weights[move] / problem.obs_weight[move])          # new whitened row / old one
    problem.ap_cache.rescale(problem, move, ratio)
    problem.obs_weight[move] = weights[move]
    problem.obs_sigma[move] = problem.obs_sigma_apriori[move] / np.sqrt(weights[move])[:, None]
    return int(move.size)
