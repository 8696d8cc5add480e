"""Geometry that cannot be determined: found and named, so that it is a failure rather than a result.

* :func:`control_on_a_line` — the ground control that is to fix a block's datum lies on one line (or at
  one point): a rotation about that line is then fixed by nothing but noise. Found before the adjustment,
  from the coordinates alone.
* :func:`undetermined_points` — after the adjustment, object points whose a-posteriori sigma is orders of
  magnitude above the block's median (rays nearly parallel, a point far outside the block).
* :func:`behind_camera` and :func:`points_not_determined_by_rays` — before a free network's adjustment, at the
  start values: observations of a point behind its camera (a central projection still gives them a residual,
  through the mirrored point), and points whose rays alone do not fix them (their 3 x 3 block of the normal
  equations near-singular, or their sigma with the orientations held orders of magnitude above the median).
* :func:`similarity_directions` — a free network's datum directions (a shift, rotation and scale of the object
  frame) in the reduced unknowns, the first guess of its minimum-norm steps.

The weakly determined *parameters* are :func:`selfcal.adjust.engine.weakly_determined`'s, and exactly singular
directions :func:`selfcal.adjust.linalg.null_directions`'; these two add what the normal equations hide when
priors or noise keep them positive definite.
"""
from __future__ import annotations

import numpy as np

from .working import image_maps, working_columns

__all__ = ["control_on_a_line", "control_far_away", "undetermined_points", "behind_camera",
           "points_not_determined_by_rays", "conditional_point_sigma", "undetermined_by_sigma",
           "LINE_FRACTION", "POINT_SIGMA_RATIO", "FAR_FACTOR", "POINT_BLOCK_RCOND",
           "FREE_POINT_SIGMA_RATIO", "similarity_directions"]

#: control whose RMS distance from its best-fitting line is below this share of the block's extent is on a line
LINE_FRACTION = 0.01
#: a point whose sigma exceeds the median of the block's points by this factor is not determined
POINT_SIGMA_RATIO = 1000.0
#: a free network leaves out a point whose sigma with the orientations held exceeds this factor times the median:
#: without a datum nothing holds it, and a least-squares step sends a point with nearly parallel rays along them
#: (BAL problem-49: the points 35-1000x the median at the start drift beyond 1e10 m within 50 iterations, each
#: crossing 1000x one at a time, so the 1000x rule alone would restart the adjustment dozens of times)
FREE_POINT_SIGMA_RATIO = 100.0
#: a point whose 3 x 3 normal block has its smallest eigenvalue below this share of its largest is not determined
POINT_BLOCK_RCOND = 1e-12
#: control farther from the block's centre than this many times the block's median radius is a mistake
FAR_FACTOR = 100.0


def _centre_and_radius(block_xyz_m: np.ndarray) -> tuple[np.ndarray, float]:
    """Median centre and median distance from it of the finite rows (robust to a few wild coordinates)."""
    span = np.asarray(block_xyz_m, float)
    span = span[np.all(np.isfinite(span), axis=1)]
    if not len(span):
        return np.zeros(3), 0.0
    centre = np.median(span, axis=0)
    return centre, float(np.median(np.linalg.norm(span - centre, axis=1)))


def control_far_away(point_ids, control_xyz_m: np.ndarray, block_xyz_m: np.ndarray, lines=None,
                     factor: float = FAR_FACTOR) -> str | None:
    """A reason naming the control points farther than ``factor`` times the block's median radius from its
    median centre (a coordinate typed in other units, an exponent too many); else None."""
    centre, radius = _centre_and_radius(block_xyz_m)
    distance = np.linalg.norm(np.asarray(control_xyz_m, float) - centre, axis=1)
    bad = np.flatnonzero(distance > factor * max(radius, 1e-9))
    if not bad.size:
        return None
    k = bad[np.argmax(distance[bad])]
    where = f" (points.csv line {lines[k]})" if lines is not None else ""
    return (f"control point '{point_ids[k]}'{where} lies {distance[k]:.3g} m from the block's centre, "
            f"{distance[k] / max(radius, 1e-9):.3g} times the block's median radius ({radius:.4g} m)"
            + (f", and so do {bad.size - 1} more" if bad.size > 1 else "")
            + ": a coordinate in other units or mistyped?")


def control_on_a_line(point_ids, control_xyz_m: np.ndarray, control_sigma_m: np.ndarray,
                      block_xyz_m: np.ndarray) -> str | None:
    """A reason, naming the points, if the control points ``control_xyz_m`` (n, 3) cannot fix a datum: fewer than
    three, or all within max(3 sigma, LINE_FRACTION x the block's extent) of one line; else None.

    ``block_xyz_m`` are coordinates spanning the block (its points with coordinates, its image positions; NaN
    rows are ignored): its extent is twice their median distance from their median centre.
    """
    xyz = np.asarray(control_xyz_m, float)
    ids = [str(p) for p in point_ids]
    listed = ", ".join(ids[:8]) + (", ..." if len(ids) > 8 else "")
    if len(xyz) < 3:
        return None                      # too few control is the reader's error (min_gcp), not this one
    centred = xyz - xyz.mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    off_line = centred - np.outer(centred @ vt[0], vt[0])
    distance = float(np.sqrt(np.mean(np.sum(off_line**2, axis=1))))
    extent = 2.0 * _centre_and_radius(block_xyz_m)[1]
    sigma = float(np.median(np.asarray(control_sigma_m, float)))
    limit = max(3.0 * sigma, LINE_FRACTION * extent)
    if distance > limit:
        return None
    return (f"the {len(ids)} control points ({listed}) lie on one line: {distance:.3g} m RMS off it, where the block "
            f"spans {extent:.4g} m, so a rotation of the block about that line is not determined (it would be "
            f"fixed by noise alone). Add control off the line, or [gnss] / [imu], or set datum = \"free\"")


def undetermined_points(point_ids, sigma_m: np.ndarray, ratio: float = POINT_SIGMA_RATIO, top: int = 5
                        ) -> tuple[np.ndarray, str] | None:
    """(indices, reason) of the points whose sigma ``sigma_m`` (n,) (e.g. sqrt of the covariance trace) is more
    than ``ratio`` times the median; None if there are none."""
    sigma = np.asarray(sigma_m, float)
    finite = np.isfinite(sigma)
    if finite.sum() < 3:
        return None
    median = float(np.median(sigma[finite]))
    bad = np.flatnonzero(~finite | (sigma > ratio * median))
    if not bad.size:
        return None
    worst = bad[np.argsort(-np.nan_to_num(sigma[bad], nan=np.inf))][:top]
    listed = ", ".join(f"'{point_ids[k]}' ({sigma[k]:.3g} m)" for k in worst)
    return bad, (f"object points not determined: {bad.size} point(s) have a sigma above {ratio:g}x the block's median "
                 f"({median:.3g} m): {listed}{', ...' if bad.size > top else ''}. Their rays are nearly parallel or "
                 f"they lie far outside the block: check their observations or remove them")


def behind_camera(problem, state) -> np.ndarray:
    """Bool over the problem's (sorted) image observations: the point lies behind its camera at ``state``.

    Sensor-independent: the ray of the pixel the point projects to (:meth:`BoundSensor.rays`, pointing into
    the scene) has the point on its backward half. A central projection maps a point behind the camera to
    the pixel of its mirror image, so the point is then opposite the ray's direction; COLMAP's cost function
    gives such an observation a zero residual (benchmarks/bench_engine.py).
    """
    behind = np.zeros(problem.n_image_observations, bool)
    for slot in problem.sensors:
        o = np.asarray(slot.observations)
        if not o.size:
            continue
        img, points = problem.obs_image[o], state.points[problem.obs_point[o]]
        context = slot.bound.context(state, False)
        try:
            origin, direction = slot.bound.rays(context, img, slot.bound.pixels(context, img, points))
        except NotImplementedError:
            continue
        behind[o] = np.einsum("ni,ni->n", points - origin, direction) < 0
    return behind


def points_not_determined_by_rays(V: np.ndarray, ratio: float = POINT_SIGMA_RATIO,
                                  rcond: float = POINT_BLOCK_RCOND) -> tuple[np.ndarray, np.ndarray]:
    """(indices, sigma) of the points whose rays do not determine them, from their 3 x 3 blocks ``V`` (n, 3, 3)
    of the normal equations (unit weight): the smallest eigenvalue below ``rcond`` times the largest, or the
    conditional sigma sqrt(trace V^-1) (the point's sigma with the orientations held) above ``ratio`` times
    the median. ``sigma`` is that conditional sigma (inf where singular)."""
    sigma = conditional_point_sigma(V, rcond)
    return undetermined_by_sigma(sigma, ratio), sigma


def conditional_point_sigma(V: np.ndarray, rcond: float = POINT_BLOCK_RCOND) -> np.ndarray:
    """sqrt(trace V^-1) of each point's 3 x 3 block ``V`` (n, 3, 3) of the normal equations: its sigma with the
    orientations held (unit weight); inf where the smallest eigenvalue is below ``rcond`` times the largest."""
    V = np.asarray(V, float)
    # closed forms for the symmetric 3 x 3 blocks: the principal 2 x 2 minors and the determinant. The
    # eigenvalues are needed only where 4 det / trace^2, a lower bound of the smallest eigenvalue (the other
    # two multiply to at most trace^2 / 4), does not clear rcond times trace with room for det's rounding
    a, b, c = V[:, 0, 0], V[:, 1, 1], V[:, 2, 2]
    d, e, f = V[:, 0, 1], V[:, 0, 2], V[:, 1, 2]
    minors = (b * c - f * f) + (a * c - e * e) + (a * b - d * d)
    det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
    trace = a + b + c
    singular = ~(4.0 * det > 2.0 * rcond * trace ** 3)
    unclear = np.flatnonzero(singular)
    if unclear.size:
        w = np.linalg.eigvalsh(V[unclear])
        singular[unclear] = ~(w[:, 0] > rcond * np.abs(w[:, 2]))
    sigma = np.full(len(V), np.inf)
    ok = ~singular
    if ok.any():
        sigma[ok] = np.sqrt(minors[ok] / det[ok])                  # trace(V^-1) = sum of the minors / det
    return sigma


def undetermined_by_sigma(sigma: np.ndarray, ratio: float = POINT_SIGMA_RATIO) -> np.ndarray:
    """The points whose conditional sigma (:func:`conditional_point_sigma`, of every point of the block) is infinite
    (a singular block) or above ``ratio`` times the median of the finite ones."""
    finite = np.isfinite(sigma)
    median = float(np.median(sigma[finite])) if finite.any() else np.inf
    return np.flatnonzero(~finite | (sigma > ratio * median))


def similarity_directions(problem, state, lin, rhs: np.ndarray | None = None) -> np.ndarray | None:
    """(n_theta, 7): the directions of theta along which a free network's reduced normal equations are singular,
    as a shift, a rotation and a change of scale of the object frame move them; None where an image's block is
    singular.

    The points move by t + w x (X - c) + s (X - c) (c their centroid). Each image's parameters move by what keeps
    its observations where they are: the least-squares fit of its rows of the Jacobian to the points' move,
    U_ee^-1 sum_o w_e[o] dX (exact wherever the sensor's image parameters absorb a similarity, as a frame
    camera's position and attitude do). The camera parameters do not move. A guess for
    :func:`selfcal.adjust.linalg.pseudo_factorise`, which checks it and finds the directions by an
    eigendecomposition where the guess is not a null space (another sensor, another defect).

    ``rhs``: the sum over the points (:func:`similarity_sums` of every point, or of shares of them added), computed
    here from ``lin``'s chunks when not given."""
    if rhs is None:
        rhs = similarity_sums(problem, lin, state.points, points_centroid(state.points))
    working = working_columns(problem)
    if working is not None:
        rhs = image_maps(problem, working).rows_to_parameters(rhs.reshape(-1, 7)).reshape(problem.n_images, -1, 7)
    try:
        fitted = np.linalg.solve(lin.U_ee, rhs)
    except np.linalg.LinAlgError:                         # an image that its observations do not determine
        return None
    out = np.zeros((problem.n_theta, 7))
    out[problem.image_theta().ravel()] = fitted.reshape(-1, 7)
    return out


def points_centroid(points: np.ndarray) -> np.ndarray:
    """The centroid of the points with finite coordinates (the rotation's and scale's centre)."""
    return points[np.isfinite(points).all(axis=1)].mean(axis=0)


def similarity_sums(problem, lin, points: np.ndarray, centroid: np.ndarray) -> np.ndarray:
    """- sum_o w_e[o] dX of :func:`similarity_directions` over the chunks of ``lin`` (the points ``points``, the
    problem's numbering), per image in its rows' columns (working columns where the sensor has them): a sum over the
    points, so over shares of them."""
    d = points - centroid
    moves = np.zeros((len(d), 3, 7))                      # per point: dX of each direction
    moves[:, [0, 1, 2], [0, 1, 2]] = 1.0
    for j in range(3):
        axis = np.zeros(3)
        axis[j] = 1.0
        moves[:, :, 3 + j] = np.cross(axis, d)
    moves[:, :, 6] = d
    moves[~np.isfinite(moves)] = 0.0
    working = working_columns(problem)
    rows_width = problem.image_width if working is None else working.width
    rhs = np.zeros((problem.n_images, rows_width, 7))
    for ch, cs in zip(lin.chunks, problem.structure().chunks):
        shifted = ch.w_e @ moves[ch.points[cs.ptl]]                             # (m, width or slots, 7)
        if ch.columns is None:
            rhs -= (cs.sum_by_image @ shifted.reshape(len(shifted), -1)).reshape(rhs.shape)
        else:                                                                   # slots in working columns
            np.subtract.at(rhs, (cs.img[:, None], ch.columns), shifted)
    return rhs
