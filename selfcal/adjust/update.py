"""The start of a re-adjustment: the previous normal equations with the left-out observations taken out.

Data snooping and screening re-adjust a block after leaving out a few observations and holding a few
parameters; the leave-one-out check of the control after turning a control point into a check point (its three
control rows leave, like left-out observations, only its own point block). At the previous estimate x the previous gradient vanishes, so the new problem's gradient is
only what the left-out observations R contributed, with the opposite sign (whitened: g = -J_R^T r_R), and its
normal matrix is the previous one minus J_R^T J_R. Holding parameters H at their new values moves them by a
known d_H, which enters the other equations through the normal matrix's columns H. One solve of this
downdated system (the points eliminated as in every iteration) is the Gauss-Newton step of the new problem
from x, taken with the previous linearisation instead of a new one: exact for a linear model, and for a
converged estimate within the change of the Jacobian over the last correction. The re-adjustment iterates
from there as from any start and stops by the same tests, so its result is that of a cold re-adjustment to
within the convergence tolerance; the step saves one full linearisation (on the 80,000-observation
seed-000 block with 254 WAPs, its camera couplings and AP displacements, about 0.25 s a round).

The previous linearisation is at the estimate before the last correction, which the solver applied below the
tolerances; the residuals and Jacobians of the left-out observations are taken at the estimate itself.

Two things keep the step sound where the model is far from linear. The points the left-out rows touch are
intersected again from the rays they keep (a few Gauss-Newton steps per point, the orientations held at the
step's): a blunder left out of a weakly intersected point moves it along its rays further than the previous
Jacobian reaches. A free network's step is the minimum-norm one along the previous adjustment's datum
directions: the downdate's rounding leaves S's datum eigenvalues near 1e-9 of the largest, above the defect
tolerance of an eigendecomposition. BAL problem-49 with snooping took the start in none of its rounds before
both (each one raised the cost), and in four of six after (40 -> 30 iterations).
"""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from .linalg import SingularSystem, factorise, pseudo_factorise
from .covariance import observation_columns
from .working import image_maps, working_columns
from .residuals.image import ap_displacement, observation_rows, point_rows
from .schur import SingularPoints, back_substitute, evaluate_cost
from .ordering import row_positions
from .problem import Problem, State

__all__ = ["downdated_start", "intersect_points"]


def _held_moves(previous, problem: Problem) -> tuple[np.ndarray, np.ndarray] | None:
    """The previous problem's theta indices that ``problem`` holds, and how far each moves to its held value
    (an AP coefficient to its reference, a trajectory term to its start); None unless ``problem`` frees
    nothing the previous one held and holds no image or core parameter the previous one freed."""
    old = previous.problem
    if not np.array_equal(old.image_free, problem.image_free):
        return None
    old_cams = {c.camera_id: (k, c) for k, c in enumerate(old.cameras)}
    index, move = [], []
    for cam in problem.cameras:
        if cam.camera_id not in old_cams:
            return None
        k, before = old_cams[cam.camera_id]
        if before.names != cam.names or np.any(cam.free & ~before.free) \
                or np.any(cam.free[:cam.n_core] != before.free[:before.n_core]):
            return None
        held = before.free & ~cam.free
        position = old.d_offset[k] + np.cumsum(before.free) - 1
        index.append(position[held])
        move.append(cam.reference[held] - previous.state.cameras[k][held])
    if [n for t in old.trajectory for n in t.names] != [n for t in problem.trajectory for n in t.names]:
        return None
    if old.n_extra or problem.n_extra:
        before, now = old.extra_free, problem.extra_free
        if np.any(now & ~before):
            return None
        held = before & ~now
        start = np.concatenate([np.zeros(0)] + [t.initial() for t in problem.trajectory])
        position = old.n_theta - old.n_extra + np.cumsum(before) - 1
        index.append(position[held])
        move.append(start[held] - previous.state.extra[held])
    return (np.concatenate([np.zeros(0, np.int64)] + index).astype(np.int64),
            np.concatenate([np.zeros(0)] + move))


#: the downdated start is taken for reduced systems up to this many unknowns (the previous reduced matrix is kept
#: on the result: 32 MB at this size)
UPDATE_LIMIT = 2000


def downdated_start(previous, problem: Problem, block, free_network: bool = False):
    """The start of the re-adjustment of ``block`` (``problem``, built with its held parameters) from the
    adjustment ``previous`` of a superset of its observations: ``previous``'s estimate moved by the downdated
    Gauss-Newton step (module docstring), as a start for :func:`~selfcal.adjust.initial.initial_state`; None
    where it does not apply (no previous normal equations, an observation not in the previous block or with
    another weight, an image left out, a parameter freed, a point block that the leaving out makes singular).
    Call it before the previous problem's AP columns are carried over."""
    S = getattr(previous, "reduced_matrix", None)
    if S is None or not previous.converged:
        return None
    old, old_block = previous.problem, previous.block
    if not np.array_equal(np.asarray(block.images.image_id), np.asarray(old_block.images.image_id)):
        return None
    held = _held_moves(previous, problem)
    if held is None:
        return None
    # the new block's observations among the previous problem's (problem order), by block row
    old_rows = old_block.observations.row[old.obs_order]
    kept = row_positions(old_rows, block.observations.row)
    if kept is None:
        return None
    if np.any(old_block.observations.sigma_px[old.obs_order][kept] != block.observations.sigma_px):
        return None
    if np.any(old.obs_weight != 1.0) or np.any(old.control.weight != 1.0):
        return None                         # a robust adjustment's rows were re-weighted
    if not _same_terrain(old, old_block, problem, block):
        return None                         # terrain heights rejected, or their sigma changed: a cold start
    dropped = _dropped_control(old, old_block, problem, block)
    if dropped is None:
        return None                         # a check point became a control point, or a survey sigma changed
    left = np.ones(old.n_image_observations, bool)
    left[kept] = False
    removed = np.flatnonzero(left)
    if removed.size == 0 and held[0].size == 0 and dropped.size == 0:
        return None
    try:
        return _step(previous, S, removed, held, free_network, dropped)
    except (SingularPoints, SingularSystem, np.linalg.LinAlgError):
        return None


def _same_terrain(old: Problem, old_block, problem: Problem, block) -> bool:
    """Whether both problems observe the same points' terrain heights with the same sigmas (or neither has any):
    the downdate takes out image rows only."""
    before, now = old.terrain, problem.terrain
    if before is None or not len(before):
        return now is None or not len(now)
    if now is None:
        return False
    return bool(np.array_equal(np.asarray(old_block.points.point_id)[before.index],
                               np.asarray(block.points.point_id)[now.index])
                and np.array_equal(before.sigma_m, now.sigma_m) and np.all(before.weight == 1.0))


def _dropped_control(old: Problem, old_block, problem: Problem, block) -> np.ndarray | None:
    """The previous problem's control points (positions in its control block) that ``problem`` no longer holds
    as control (their role now ``chk``: the leave-one-out check of the control); None unless every control point
    of ``problem`` was one before, with the same survey weights."""
    old_ids = np.asarray(old_block.points.point_id)[old.control_index]
    new_ids = np.asarray(block.points.point_id)[problem.control_index]
    if np.array_equal(old_ids, new_ids):
        return np.zeros(0, np.int64)
    where = {name: k for k, name in enumerate(old_ids)}
    if any(name not in where for name in new_ids):
        return None
    positions = np.array([where[name] for name in new_ids], np.int64)
    if not np.allclose(old.control.W[positions], problem.control.W) or np.any(np.diff(positions) <= 0):
        return None
    return np.setdiff1d(np.arange(len(old_ids)), positions)


def _point_columns(old: Problem, lin, obs: np.ndarray, block_of: np.ndarray, L: np.ndarray, W_d: np.ndarray | None,
                   n_blocks: int) -> np.ndarray:
    """X (n_theta, 3 n_blocks) with X[:, 3 j:3 j + 3] = W_j^T L_j: the couplings W_j (3 x theta) of points j made
    of the observations ``obs`` (``block_of`` their point's j), times the factor L_j of each one's V^-1, so that
    the points' part of the reduced matrix is X X^T. ``W_d`` (n_blocks, 3, n_d): the dense camera couplings
    (None: compact cameras, whose columns are part of each observation's block)."""
    n_e, n_d = old.n_e, old.n_d
    X = np.zeros((old.n_theta, 3 * n_blocks))
    coupling = _at(lin, [ch.couplings() for ch in lin.chunks], "o0", obs)       # (k, wide, 3)
    working = working_columns(old)
    if working is not None and lin.chunks and lin.chunks[0].columns is not None:
        # slots in working columns (:mod:`.working`): the couplings in the image parameters, T^T w
        slots = _at(lin, [ch.columns for ch in lin.chunks], "o0", obs).astype(np.int64)
        coupling = image_maps(old, working).dense_rows(old.obs_image[obs], coupling.transpose(0, 2, 1),
                                                       slots).transpose(0, 2, 1)
    rows = (old.image_theta() if coupling.shape[1] == old.image_width else observation_columns(old))[old.obs_image[obs]]
    part = coupling @ L[block_of]
    cols = np.broadcast_to((3 * block_of[:, None] + np.arange(3)[None, :])[:, None, :], part.shape)
    ok = rows >= 0
    np.add.at(X, (np.broadcast_to(rows[:, :, None], part.shape)[ok], cols[ok]), part[ok])
    if W_d is not None:
        X[n_e:n_e + n_d] = np.einsum("jkd,jkl->djl", W_d, L).reshape(n_d, 3 * n_blocks)
    return X


def _at(lin, arrays: list, start: str, index: np.ndarray, size: int = 1) -> np.ndarray:
    """Rows of per-chunk arrays (one per chunk of ``lin``, ``size`` rows per item) at ``index``: observations
    (``start`` = "o0") in problem order or points at their positions in ``Problem.point_order`` ("p0")."""
    starts = np.array([getattr(ch, start) for ch in lin.chunks])
    chunk = np.searchsorted(starts, index, side="right") - 1
    out = np.empty((len(index), size) + arrays[0].shape[1:])
    for c in np.unique(chunk):
        sel = np.flatnonzero(chunk == c)
        out[sel] = arrays[c].reshape((-1, size) + arrays[c].shape[1:])[index[sel] - starts[c]]
    return out[:, 0] if size == 1 else out


def intersect_points(problem: Problem, state: State, points: np.ndarray, obs: np.ndarray, iterations: int = 5) -> None:
    """Gauss-Newton on each of ``points`` alone from its observations ``obs`` (problem order, grouped by point),
    the other unknowns held; a point keeps each step that lowers its own cost and stops once its step is below
    1e-3 of its sigma (``state`` is changed in place)."""
    if not points.size:
        return
    owner = np.searchsorted(points, problem.obs_point[obs])
    delta = ap_displacement(problem, state, obs)           # the APs are held: their displacement is fixed
    r, j_p = point_rows(problem, state, obs, delta)
    cost = np.bincount(owner, np.sum(r * r, axis=1), minlength=points.size)
    active = np.ones(points.size, bool)
    for _ in range(iterations):
        V = np.zeros((points.size, 3, 3))
        g = np.zeros((points.size, 3))
        np.add.at(V, owner, np.einsum("oki,okj->oij", j_p, j_p))
        np.add.at(g, owner, np.einsum("oki,ok->oi", j_p, r))
        try:
            step = np.linalg.solve(V, g[:, :, None])[:, :, 0] * active[:, None]
        except np.linalg.LinAlgError:
            return
        before = state.points[points].copy()
        state.points[points] += step
        r, j_p = point_rows(problem, state, obs, delta)
        now = np.bincount(owner, np.sum(r * r, axis=1), minlength=points.size)
        worse = now > cost
        if worse.any():                          # that step raised the point's cost: back to where it was
            state.points[points[worse]] = before[worse]
            active &= ~worse
            r, j_p = point_rows(problem, state, obs, delta)
            now = np.bincount(owner, np.sum(r * r, axis=1), minlength=points.size)
        cost = now
        active &= np.einsum("pi,pij,pj->p", step, V, step) > 1e-6
        if not active.any():
            return


def _left_out_rows(problem: Problem, state, removed: np.ndarray):
    """:func:`observation_rows` of the left-out image observations; none (a control point turned check point
    alone) gives empty rows without asking the sensors to predict nothing."""
    if removed.size:
        return observation_rows(problem, state, removed)
    return (np.zeros((0, 2)), np.zeros((0, 2, problem.image_width)), np.zeros((0, 2, 3)),
            np.zeros((0, 2, problem.n_d)))


def _step(previous, S_old: np.ndarray, removed: np.ndarray, held, free_network: bool,
          dropped: np.ndarray = np.zeros(0, np.int64)):
    old, state = previous.problem, previous.state
    lin, v_inv = previous.point_linearisation()
    n_e, n_d, width = old.n_e, old.n_d, old.image_width
    # points that keep fewer than two rays leave the problem: all their observations go
    rays = np.bincount(old.obs_point, minlength=old.n_points) - np.bincount(old.obs_point[removed],
                                                                            minlength=old.n_points)
    gone = rays < 2
    if np.any(gone[old.control_index]):
        return None                         # (a control point left out of the control keeps two rays too)
    # the control coordinates left out: their rows (point blocks only), at the estimate
    dropped_points = old.control_index[dropped]
    r_c, J_c = old.control.rows(state.points[dropped_points], dropped)
    removed = np.union1d(removed, np.flatnonzero(gone[old.obs_point]))
    r, j_e, j_p, j_d = _left_out_rows(old, state, removed)
    point = old.obs_point[removed]
    # the left-out rows (theta part, dense) and their gradient, negated
    J = np.zeros((len(removed), 2, old.n_theta))
    J[np.arange(len(removed))[:, None, None], np.arange(2)[None, :, None],
      (width * old.obs_image[removed])[:, None, None] + np.arange(width)[None, None, :]] = j_e
    J[:, :, n_e:n_e + n_d] = j_d
    J = J.reshape(2 * len(removed), old.n_theta)
    g = -(J.T @ r.ravel())
    S = S_old - J.T @ J
    # the points the left-out rows touch: their part of the reduced matrix before and after
    touched = np.unique(np.concatenate([point, dropped_points]))
    n_t = len(touched)
    at = old.point_positions()[touched]                                # their positions in the problem's order
    counts = old.point_start[at + 1] - old.point_start[at]
    obs = np.repeat(old.point_start[at], counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts,
                                                                                      counts)
    block_of = np.repeat(np.arange(n_t), counts)
    V_old = _at(lin, [ch.V for ch in lin.chunks], "p0", at)
    Vi_old = _at(lin, v_inv, "p0", at)                        # undamped: the last reduction's
    position = np.searchsorted(touched, point)
    V_new = V_old.copy()
    np.subtract.at(V_new, position, np.einsum("oki,okj->oij", j_p, j_p))
    g_p = np.zeros((n_t, 3))
    np.subtract.at(g_p, position, np.einsum("oki,ok->oi", j_p, r))
    at_control = np.searchsorted(touched, dropped_points)
    np.subtract.at(V_new, at_control, np.einsum("nki,nkj->nij", J_c, J_c))
    np.subtract.at(g_p, at_control, np.einsum("nki,nk->ni", J_c, r_c))
    stays = ~gone[touched]
    V_new[~stays] = np.eye(3)                 # a point that leaves: no rays, no correction
    L_old = np.linalg.cholesky(Vi_old)
    L_new = np.linalg.cholesky(np.linalg.inv(V_new)) * stays[:, None, None]
    W_old = W_new = None
    if lin.chunks[0].W_pd is not None and n_d:
        W_old = _at(lin, [ch.W_pd for ch in lin.chunks], "p0", at, 3)        # (n_t, 3, n_d)
        W_new = W_old.copy()
        np.subtract.at(W_new, position, np.einsum("oki,okd->oid", j_p, j_d))
    X_old = _point_columns(old, lin, obs, block_of, L_old, W_old, n_t)
    still = ~np.isin(obs, removed)
    X_new = _point_columns(old, lin, obs[still], block_of[still], L_new, W_new, n_t)
    S += X_old @ X_old.T - X_new @ X_new.T
    S = 0.5 * (S + S.T)
    Lg = np.einsum("jki,jk->ji", L_new, g_p)                          # L^T g_p per point
    g -= X_new @ Lg.ravel()
    index, move = held
    if index.size:                              # held parameters move to their held values; the rest follow
        g -= S[:, index] @ move
        S[index, :] = 0.0
        S[:, index] = 0.0
        S[index, index] = 1.0
        g[index] = move
    # a free network: the downdate's rounding lifts S's datum eigenvalues to ~1e-9 of the largest (BAL problem-49),
    # above the eigendecomposition's defect tolerance; the previous datum directions still fit them
    factor = pseudo_factorise(S, getattr(previous, "datum_null", None)) if free_network else factorise(S)
    d_theta = factor.solve(g)
    if index.size:
        d_theta[index] = move
    # every point follows the orientations; the touched ones by their new blocks and gradients
    quiet = replace(lin, chunks=[replace(ch, g_p=np.zeros_like(ch.g_p)) for ch in lin.chunks])
    d_p = back_substitute(old, quiet, v_inv, d_theta)
    d_p[touched] = np.einsum("jik,jk->ji", L_new, Lg - (X_new.T @ d_theta).reshape(n_t, 3))
    predicted = old.apply(state, d_theta, d_p)
    # the touched points are intersected again from the rays they keep, the orientations held at the step's: a
    # blunder left out of a weakly intersected point moves it far along its rays, where the previous Jacobian no
    # longer holds (BAL problem-49: one such point raised the cost by 44-297 in three of five rounds)
    # (control points keep the linear step: their surveyed coordinates are observations too)
    rays_only = stays & ~np.isin(touched, old.control_index)
    intersect_points(old, predicted, touched[rays_only], obs[still & rays_only[block_of]])
    # the linear model must hold: the step lowers the new problem's cost below that of the previous estimate
    # (the previous problem's cost less the left-out rows'); where it does not (BAL's free network, strongly
    # non-linear, in some rounds), the re-adjustment starts from the previous estimate as before
    if index.size:
        d_held = np.zeros(old.n_theta)
        d_held[index] = move
        state = old.apply(state, d_held, np.zeros_like(state.points))
        plain = (evaluate_cost(old, state) - 0.5 * float(np.sum(_left_out_rows(old, state, removed)[0] ** 2))
                 - 0.5 * float(np.sum(old.control.rows(state.points[dropped_points], dropped)[0] ** 2)))
    else:
        plain = previous.cost - 0.5 * float(np.sum(r * r)) - 0.5 * float(np.sum(r_c * r_c))
    new = (evaluate_cost(old, predicted) - 0.5 * float(np.sum(_left_out_rows(old, predicted, removed)[0] ** 2))
           - 0.5 * float(np.sum(old.control.rows(predicted.points[dropped_points], dropped)[0] ** 2)))
    if not new < plain:
        return None
    return SimpleNamespace(block=previous.block, problem=old, state=predicted)
