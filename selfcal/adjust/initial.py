"""Initial values: forward intersection of object points and space resection of images.

Image parameters come from each image's sensor (a frame image's exterior orientation from
images.csv). A frame image without it (or whose given orientation projects its control
points far from where they were measured) is oriented by space resection from the points
whose coordinates are known: control and check points, and tie points intersected from the
other images. Object points are then intersected from all their rays (the sensors' rays).

Matcher output carries wrong observations, and start values must survive them: a given orientation is
judged by the median misfit at its control points, not their RMS; a resection whose least-squares
solution leaves points far off (or fails) is redone by RANSAC (OpenCV's ``solvePnPRansac``) and refined
on its inliers; and for a robust adjustment every point is intersected by iteratively reweighted least
squares (:func:`intersect` with ``robust``), so that a wrong ray among good ones does not pull it.
"""
from __future__ import annotations

import numpy as np

from ..errors import AdjustmentError
from ..geometry.rotation import opk_from_matrix
from ..sensors.frame import project, project_with_jacobians
from .kernels import best_ray_pairs
from .problem import Problem, State

__all__ = ["intersect", "resect", "resect_robust", "initial_state", "PointsNotIntersected"]


class PointsNotIntersected(AdjustmentError):
    """Points (``indices`` among the block's) whose rays do not meet at a useful angle at the start values."""

    def __init__(self, indices: np.ndarray, message: str):
        self.indices = np.asarray(indices)
        super().__init__(message)

#: an image whose given orientation reprojects its control points worse than
#: this share of the image diagonal is re-oriented by resection
POOR_ORIENTATION_SHARE = 0.05
#: a point off a resection by more than this share of the image diagonal is an outlier (RANSAC's threshold): the start
#: values of an uncalibrated camera miss by a few dozen pixels, a wrong match by hundreds
RESECTION_OUTLIER_SHARE = 0.005


def _sum_by_point(point: np.ndarray, values: np.ndarray, n_points: int) -> np.ndarray:
    """values (m, ...) summed per point (n_points, ...), in the observations' order: one bincount per component
    (np.add.at took 0.54 s for the rays of a 5000-image block)."""
    flat = values.reshape(len(point), -1)
    sums = [np.bincount(point, weights=flat[:, j], minlength=n_points) for j in range(flat.shape[1])]
    return np.stack(sums, axis=1).reshape((n_points,) + values.shape[1:])


def intersect(problem: Problem, state: State, use: np.ndarray | None = None,
              robust: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares intersection of the rays of every point.

    Minimises the sum of squared distances of the point to its rays,
    sum_i |(I - d_i d_i^T)(X - X0_i)|^2.

    Parameters
    ----------
    use : bool array over observations (sorted order), optional
        Rays to use (e.g. only those of oriented images).
    robust : bool
        Iteratively reweighted: each ray's angular distance from the point (its distance over the range)
        against three times the block's median gives it a Cauchy weight, five times (a wrong ray among good
        ones leaves the point where the good ones meet).

    Returns
    -------
    xyz : (n_points, 3); NaN where fewer than two usable rays meet at a useful angle
    ok : (n_points,) bool
    """
    use = np.ones(problem.n_image_observations, bool) if use is None else use
    rays, directions = [], []
    for slot in problem.sensors:
        o = slot.observations[use[slot.observations]]
        if o.size:
            origin, d = slot.bound.rays(slot.bound.context(state, False), problem.obs_image[o],
                                        problem.obs_pixel[o])
            rays.append((problem.obs_point[o], origin, np.eye(3)[None] - d[:, :, None] * d[:, None, :]))
            directions.append(d)
    n_rays = np.bincount(problem.obs_point[use], minlength=problem.n_points)
    xyz, ok = _intersect_rays(problem.n_points, rays, n_rays, None)
    if robust and rays:
        point = np.concatenate([r[0] for r in rays])
        origin = np.concatenate([r[1] for r in rays])
        angles = _angles(xyz[point], origin, np.concatenate([r[2] for r in rays]))
        typical = float(np.median(angles[ok[point]])) if ok[point].any() else 0.0
        if typical > 0:
            xyz = _best_pairs(point, origin, np.concatenate(directions), xyz, ok, 3.0 * typical)
        for _ in range(5):
            # each ray's angle from the point: its distance over the range
            ray_angles = []
            for point, origin, proj in rays:
                offset = np.nan_to_num(xyz[point]) - origin
                ray_angles.append(np.linalg.norm(np.einsum("nij,nj->ni", proj, offset), axis=1) /
                                  np.maximum(np.linalg.norm(offset, axis=1), 1e-300))
            every = np.concatenate(ray_angles)[np.concatenate([ok[point] for point, _, _ in rays])]
            typical = float(np.median(every)) if every.size else 0.0
            if not typical > 0:
                break
            weights = [1.0 / (1.0 + (a / (3.0 * typical)) ** 2) for a in ray_angles]
            xyz, ok = _intersect_rays(problem.n_points, rays, n_rays, weights)
    return xyz, ok


def _angles(xyz: np.ndarray, origin: np.ndarray, proj: np.ndarray) -> np.ndarray:
    """The angle (rad) between each ray (its origin and projector I - d d^T) and the direction to its point."""
    offset = np.nan_to_num(xyz) - origin
    return np.linalg.norm(np.einsum("nij,nj->ni", proj, offset), axis=1) / np.maximum(np.linalg.norm(offset, axis=1),
                                                                                  1e-300)


#: rays of a point whose pairs are tried as its start (the first ones: 28 pairs)
PAIR_RAYS = 8


def _best_pairs(point: np.ndarray, origin: np.ndarray, direction: np.ndarray, xyz: np.ndarray, ok: np.ndarray,
                threshold: float) -> np.ndarray:
    """For every point with three rays or more, the intersection of the pair of its rays that the most of its others
    agree with (a truncated quadratic of their angles, ``threshold`` rad), where it beats the least-squares point:
    one wrong ray among three or four pulls a least-squares point so far that every ray's angle is large, and a
    re-weighting from there cannot tell which is wrong (RANSAC over the pairs of its first :data:`PAIR_RAYS` rays,
    :func:`~selfcal.adjust.kernels.best_ray_pairs`)."""
    order = np.argsort(point, kind="stable")
    point, origin, direction = point[order], origin[order], direction[order]
    n_points = len(xyz)
    start = np.concatenate([[0], np.cumsum(np.bincount(point, minlength=n_points))]).astype(np.int64)
    candidate, score = best_ray_pairs(start, np.ascontiguousarray(origin, float),
                                      np.ascontiguousarray(direction, float), float(threshold), PAIR_RAYS)
    # the least-squares point's own score
    offset = np.nan_to_num(xyz[point]) - origin
    along = np.einsum("ni,ni->n", offset, direction)
    angle = np.where(along > 0, np.linalg.norm(offset - along[:, None] * direction, axis=1) /
                     np.maximum(np.abs(along), 1e-300), np.inf)
    own = np.bincount(point, np.minimum(angle / threshold, 1.0) ** 2, minlength=n_points)
    better = np.isfinite(score) & ((score < own) | ~ok)
    out = xyz.copy()
    out[better] = candidate[better]
    return out


def _intersect_rays(n_points: int, rays: list, n_rays: np.ndarray, weights: list | None):
    """The (weighted) least-squares intersection of ``rays`` ((point, origin, projector) of each ray, per sensor)
    of every point, NaN where fewer than two rays meet at a useful angle, and which points have one."""
    A = np.zeros((n_points, 3, 3))
    b = np.zeros((n_points, 3))
    for k, (point, origin, proj) in enumerate(rays):
        if weights is not None:
            proj = proj * weights[k][:, None, None]
        A += _sum_by_point(point, proj, n_points)
        b += _sum_by_point(point, np.einsum("nij,nj->ni", proj, origin), n_points)
    xyz = np.full((n_points, 3), np.nan)
    w = np.linalg.eigvalsh(A)
    ok = (n_rays >= 2) & (w[:, 0] > 1e-6 * np.maximum(w[:, 2], 1e-300))
    xyz[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    return xyz, ok


def resect(xy_mm: np.ndarray, xyz: np.ndarray, iop: np.ndarray, eop0: np.ndarray | None = None,
           iterations: int = 30) -> np.ndarray:
    """Space resection of one image from points with known coordinates.

    Without a start, assumes a near-vertical image: a plane similarity between
    photo and ground coordinates gives X0, Y0, kappa and the scale, hence Z0.
    Gauss-Newton then solves the six exterior orientation elements.

    Raises
    ------
    AdjustmentError
        With fewer than four points, or when the iteration does not converge.
    """
    n = len(xy_mm)
    if n < 4:
        raise AdjustmentError(f"space resection needs at least 4 points with coordinates, found {n}")
    c = iop[0]
    if eop0 is None:
        u = xy_mm - iop[1:3]
        A = np.zeros((2 * n, 4))
        A[0::2] = np.column_stack([u[:, 0], -u[:, 1], np.ones(n), np.zeros(n)])
        A[1::2] = np.column_stack([u[:, 1], u[:, 0], np.zeros(n), np.ones(n)])
        a, b, tx, ty = np.linalg.lstsq(A, xyz[:, :2].ravel(), rcond=None)[0]
        scale = np.hypot(a, b)  # metres per millimetre
        eop = np.array([tx, ty, np.mean(xyz[:, 2]) + scale * c, 0.0, 0.0, np.arctan2(b, a)])
    else:
        eop = np.asarray(eop0, float).copy()
    iop_rows = np.broadcast_to(iop, (n, 3))
    for _ in range(iterations):
        pred, j_e, _, _ = project_with_jacobians(xyz, np.broadcast_to(eop, (n, 6)), iop_rows)
        r = (xy_mm - pred).ravel()
        J = j_e.reshape(2 * n, 6)
        step = np.linalg.lstsq(J, r, rcond=None)[0]
        eop += step
        if np.all(np.abs(step[:3]) < 1e-6) and np.all(np.abs(step[3:]) < 1e-10):
            return eop
    rms = np.sqrt(np.mean((xy_mm - project(xyz, np.broadcast_to(eop, (n, 6)), iop_rows)) ** 2))
    if not np.isfinite(rms) or rms > 1.0:
        raise AdjustmentError(f"space resection did not converge (rms {rms:.3g} mm)")
    return eop


def resect_robust(xy_mm: np.ndarray, xyz: np.ndarray, iop: np.ndarray, threshold_mm: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Space resection that wrong points do not stop: the least-squares :func:`resect`, and where it fails or
    leaves points more than ``threshold_mm`` off, RANSAC over perspective-n-point solutions (OpenCV's
    ``solvePnPRansac``, the points in the camera's normalised coordinates) refined on its inliers. Returns the
    exterior orientation and which points it fits.

    Raises
    ------
    AdjustmentError
        When no orientation fits enough of the points.
    """
    n = len(xy_mm)
    iop_rows = np.broadcast_to(iop, (n, 3))
    try:
        eop = resect(xy_mm, xyz, iop)
        off = np.hypot(*(project(xyz, np.broadcast_to(eop, (n, 6)), iop_rows) - xy_mm).T)
        if np.all(off < threshold_mm):
            return eop, np.ones(n, bool)
    except AdjustmentError:
        pass
    if n < 6:
        raise AdjustmentError(f"space resection with wrong points among {n}: at least 6 are needed to find them")
    import cv2
    c, x0, y0 = iop
    # the camera frame of OpenCV: x right, y down, z along the view (selfcal's camera looks along -z, y up)
    normalised = np.column_stack([(xy_mm[:, 0] - x0) / c, -(xy_mm[:, 1] - y0) / c])
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        np.ascontiguousarray(xyz, np.float64), np.ascontiguousarray(normalised, np.float64), np.eye(3), None,
        reprojectionError=threshold_mm / c, iterationsCount=1000, confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not found or inliers is None or len(inliers) < 6:
        raise AdjustmentError(f"space resection did not find an orientation that fits 6 of {n} points "
                              f"within {threshold_mm:.3g} mm")
    R_cv = cv2.Rodrigues(rvec)[0]
    M = np.diag([1.0, -1.0, -1.0]) @ R_cv
    start = np.concatenate([-R_cv.T @ tvec.ravel(), opk_from_matrix(M[None])[0]])
    keep = np.zeros(n, bool)
    keep[inliers.ravel()] = True
    eop = resect(xy_mm[keep], xyz[keep], iop, start)
    off = np.hypot(*(project(xyz, np.broadcast_to(eop, (n, 6)), iop_rows) - xy_mm).T)
    return eop, off < threshold_mm


def _control_rms(problem: Problem, state: State, images: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Per image of the problem: the misfit (photo mm) of its given orientation at the points with reference
    coordinates (``known``) it sees, for the frame images ``images``, as the root of the median squared misfit (a
    wrong control observation among them leaves it as it is); 0 elsewhere and where fewer than three such
    observations."""
    rms = np.zeros(problem.n_images)
    wanted = np.zeros(problem.n_images, bool)
    wanted[images] = True
    sel = np.flatnonzero(wanted[problem.obs_image] & known[problem.obs_point])
    if not sel.size:
        return rms
    image = problem.obs_image[sel]
    camera = problem.image_camera[image]
    iop = np.empty((sel.size, 3))
    for k in np.unique(camera):
        iop[camera == k] = state.cameras[k][:3]
    pred = project(state.points[problem.obs_point[sel]], state.image[image, :6], iop)
    count = np.bincount(image, minlength=problem.n_images)
    squares = np.sum((pred - problem.obs_value[sel]) ** 2, axis=1)
    order = np.lexsort((squares, image))
    start = np.concatenate([[0], np.cumsum(count)])
    for i in np.flatnonzero(count >= 3):
        rms[i] = np.sqrt(np.median(squares[order[start[i]:start[i + 1]]]))
    return rms


def _from_previous(problem: Problem, block, state: State, start) -> tuple[np.ndarray, np.ndarray]:
    """Copy a previous adjustment's estimates where ids match; returns which images and points got one."""
    prev = start.block
    img_lookup = {i: k for k, i in enumerate(prev.images.image_id)}
    pt_lookup = {p: k for k, p in enumerate(prev.points.point_id)}
    img_src = np.array([img_lookup.get(i, -1) for i in block.images.image_id])
    pt_src = np.array([pt_lookup.get(p, -1) for p in block.points.point_id])
    has_img, has_pt = img_src >= 0, pt_src >= 0
    state.image[has_img] = start.state.image[img_src[has_img]]
    state.points[has_pt] = start.state.points[pt_src[has_pt]]
    prev_names = [n for t in start.problem.trajectory for n in t.names]
    names = [n for t in problem.trajectory for n in t.names]
    if prev_names == names:
        state.extra[:] = np.where(problem.extra_free, start.state.extra, state.extra)
    prev_cams = {c.camera_id: (c, v) for c, v in zip(start.problem.cameras, start.state.cameras)}
    for k, cam in enumerate(problem.cameras):
        if cam.camera_id in prev_cams:
            pc, values = prev_cams[cam.camera_id]
            nc = cam.n_core
            state.cameras[k][:nc] = values[:nc]
            if pc.names == cam.names:
                state.cameras[k][nc:] = np.where(cam.free[nc:], values[nc:], cam.reference[nc:])
    return has_img, has_pt


def _hold(problem: Problem, state: State) -> None:
    """Parameters held by the problem keep their start value: an image parameter its sensor's, a core
    parameter the camera's (block.toml), an AP coefficient zero (or its value held by block.toml)."""
    held = ~problem.image_free & np.isfinite(problem.image_prior_value)
    state.image[held] = problem.image_prior_value[held]
    for cam, values in zip(problem.cameras, state.cameras):
        values[:] = np.where(cam.free, values, cam.reference)


def _ground_the_rest(problem: Problem, state: State, points: np.ndarray, notes: list[str]) -> None:
    """Points whose rays do not meet at a useful angle (a stereo pair from one orbit, side-by-side cameras) start
    where the ray of their first observation meets the median height of the points that have coordinates,
    where their sensor can say (:meth:`~selfcal.sensors.base.BoundSensor.ground`)."""
    known = np.isfinite(state.points).all(axis=1)
    first = problem.point_start[problem.point_positions()[points]]      # each one's first observation
    placed = 0
    for slot in problem.sensors:
        o = first[np.isin(first, slot.observations)]
        mine = np.isin(problem.obs_point[slot.observations], np.flatnonzero(known))
        if not o.size or not mine.any():
            continue
        try:
            height = float(np.median(slot.bound.height(state.points[problem.obs_point[slot.observations[mine]]])))
            context = slot.bound.context(state, False)
            ground = slot.bound.ground(context, problem.obs_image[o], problem.obs_pixel[o], height)
        except NotImplementedError:
            continue
        state.points[problem.obs_point[o]] = ground
        placed += int(np.isfinite(ground).all(axis=1).sum())
    if placed:
        notes.append(f"{placed} point(s) whose rays meet at too small an angle start on the median height of the "
                     f"points with coordinates")


def initial_state(problem: Problem, block, start=None, robust: bool = False) -> tuple[State, list[str]]:
    """Initial values of all unknowns, and notes on what was resected.

    With ``start`` (a previous :class:`~selfcal.adjust.AdjustmentResult`), its
    estimates are used wherever image and point ids match (warm start); held
    parameters keep their start values. ``robust``: the points intersected by
    :func:`intersect`'s reweighting (for a robust adjustment of matcher output).

    Raises
    ------
    AdjustmentError
        When an image can be oriented neither from its sensor nor by resection.
    """
    images, points = block.images, block.points
    given_image = problem.image_prior_value.copy()
    cameras = [cam.prior_value.copy() for cam in problem.cameras]
    xyz = points.xyz_m.copy()
    state = State(image=given_image.copy(), cameras=cameras, points=xyz,
                  extra=np.concatenate([np.zeros(0)] + [t.initial() for t in problem.trajectory]))
    notes: list[str] = []
    if start is not None:
        has_img, has_pt = _from_previous(problem, block, state, start)
        _hold(problem, state)
        if has_img.all() and has_pt.all():
            return state, notes
        state.image[~has_img] = given_image[~has_img]
    resectable = np.zeros(problem.n_images, bool)
    for slot in problem.sensors:
        resectable[slot.images] = getattr(slot.sensor, "supports_resection", False)
    known = np.isfinite(xyz).all(axis=1) & (points.role != "tie")  # reference coordinates
    need = ~np.isfinite(state.image).all(axis=1)
    if (need & ~resectable).any():
        bad = images.image_id[np.flatnonzero(need & ~resectable)[0]]
        raise AdjustmentError(f"image '{bad}' has no initial values from its sensor (and its sensor has no "
                              f"space resection)")
    # given orientations that miss their control points badly are treated as missing
    given_frames = np.flatnonzero(~need & resectable)
    control_rms = _control_rms(problem, state, given_frames, known)
    for i in given_frames:
        cam = block.cameras[images.camera_id[i]]
        diagonal = np.hypot(cam.width_mm, cam.height_mm)
        rms = control_rms[i]
        if rms > POOR_ORIENTATION_SHARE * diagonal:
            notes.append(f"image '{images.image_id[i]}': given orientation misses its control points by "
                         f"{rms / cam.pixel_size_mm:.0f} px rms; re-oriented by space resection")
            need[i] = True
    state.image[need] = np.nan

    given = np.isfinite(points.xyz_m).all(axis=1) & (points.role == "tie")   # approximate tie coordinates
    unknown = (points.role == "chk") | ((points.role == "tie") & ~given)
    # images with an orientation of their own intersect; images without give no rays until resected
    intersecting = resectable.copy()
    for slot in problem.sensors:
        intersecting[slot.images] |= not getattr(slot.sensor, "given_points_only", False)

    def intersect_ties():
        use = ~need[problem.obs_image] & intersecting[problem.obs_image]
        pts, ok = intersect(problem, state, use, robust)
        state.points[unknown & ok] = pts[unknown & ok]
        return ok | (points.role == "gcp") | given

    have = intersect_ties() if (~need).any() else known.copy()
    for _ in range(len(need)):
        if not need.any():
            break
        progress = False
        for i in np.flatnonzero(need):
            sel = (problem.obs_image == i) & have[problem.obs_point] & np.isfinite(state.points[problem.obs_point]).all(axis=1)
            if sel.sum() < 4:
                continue
            k = problem.image_camera[i]
            iop = state.cameras[k][:3]
            cam = block.cameras[problem.camera_ids[k]]
            threshold = RESECTION_OUTLIER_SHARE * np.hypot(cam.width_mm, cam.height_mm)
            state.image[i], fits = resect_robust(problem.obs_value[sel], state.points[problem.obs_point[sel]], iop,
                                                 threshold)
            need[i] = False
            progress = True
            outliers = f", {int((~fits).sum())} of them off by more than {threshold:.2g} mm" if not fits.all() else ""
            notes.append(f"image '{images.image_id[i]}': oriented by space resection from {int(sel.sum())} "
                         f"points{outliers}")
        if not progress:
            break
        have = intersect_ties()
    if need.any():
        names = ", ".join(f"'{images.image_id[i]}'" for i in np.flatnonzero(need)[:5])
        raise AdjustmentError(f"cannot orient image(s) {names}: no exterior orientation in images.csv and "
                              f"fewer than 4 points with coordinates for a space resection")
    ok = intersect_ties() if unknown.any() else np.ones(len(points), bool)
    bad = ~ok & ~np.isfinite(state.points).all(axis=1)
    if bad.any():
        _ground_the_rest(problem, state, np.flatnonzero(bad), notes)
        bad = ~np.isfinite(state.points).all(axis=1)
    if bad.any():
        raise PointsNotIntersected(np.flatnonzero(bad), f"{int(bad.sum())} point(s) cannot be intersected (rays do "
                                   f"not meet at a useful angle), e.g. '{points.point_id[np.flatnonzero(bad)[0]]}'")
    # angles into (-pi, pi] (frame images)
    state.image[resectable, 3:] = (state.image[resectable, 3:] + np.pi) % (2 * np.pi) - np.pi
    return state, notes
