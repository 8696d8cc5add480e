"""Initial values: forward intersection of object points and space resection of images.

Image parameters come from each image's sensor (a frame image's exterior orientation from
images.csv). A frame image without it (or whose given orientation projects its control
points far from where they were measured) is oriented by space resection from the points
whose coordinates are known: control and check points, and tie points intersected from the
other images. Object points are then intersected from all their rays (the sensors' rays).
"""
from __future__ import annotations

import numpy as np

from ..errors import AdjustmentError
from ..sensors.frame import project, project_with_jacobians
from .problem import Problem, State

__all__ = ["intersect", "resect", "initial_state"]

#: an image whose given orientation reprojects its control points worse than
#: this share of the image diagonal is re-oriented by resection
POOR_ORIENTATION_SHARE = 0.05


def _sum_by_point(point: np.ndarray, values: np.ndarray, n_points: int) -> np.ndarray:
    """values (m, ...) summed per point (n_points, ...), in the observations' order: one bincount per component
    (np.add.at took 0.54 s for the rays of a 5000-image block)."""
    flat = values.reshape(len(point), -1)
    sums = [np.bincount(point, weights=flat[:, j], minlength=n_points) for j in range(flat.shape[1])]
    return np.stack(sums, axis=1).reshape((n_points,) + values.shape[1:])


def intersect(problem: Problem, state: State, use: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares intersection of the rays of every point.

    Minimises the sum of squared distances of the point to its rays,
    sum_i |(I - d_i d_i^T)(X - X0_i)|^2.

    Parameters
    ----------
    use : bool array over observations (sorted order), optional
        Rays to use (e.g. only those of oriented images).

    Returns
    -------
    xyz : (n_points, 3); NaN where fewer than two usable rays meet at a useful angle
    ok : (n_points,) bool
    """
    use = np.ones(problem.n_image_observations, bool) if use is None else use
    A = np.zeros((problem.n_points, 3, 3))
    b = np.zeros((problem.n_points, 3))
    pt = problem.obs_point[use]
    for slot in problem.sensors:
        o = slot.observations[use[slot.observations]]
        if not o.size:
            continue
        origin, d = slot.bound.rays(slot.bound.context(state, False), problem.obs_image[o], problem.obs_pixel[o])
        proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        A += _sum_by_point(problem.obs_point[o], proj, problem.n_points)
        b += _sum_by_point(problem.obs_point[o], np.einsum("nij,nj->ni", proj, origin), problem.n_points)
    n_rays = np.bincount(pt, minlength=problem.n_points)
    xyz = np.full((problem.n_points, 3), np.nan)
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


def _control_rms(problem: Problem, state: State, images: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Per image of the problem: the RMS misfit (photo mm) of its given orientation at the points with reference
    coordinates (``known``) it sees, for the frame images ``images``; 0 elsewhere and where fewer than three
    such observations. One pass over the observations (per image it was one pass each: 15.6 s at 5000 images)."""
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
    squares = np.bincount(image, weights=np.sum((pred - problem.obs_value[sel]) ** 2, axis=1),
                          minlength=problem.n_images)
    enough = count >= 3
    rms[enough] = np.sqrt(squares[enough] / count[enough])
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


def initial_state(problem: Problem, block, start=None) -> tuple[State, list[str]]:
    """Initial values of all unknowns, and notes on what was resected.

    With ``start`` (a previous :class:`~selfcal.adjust.AdjustmentResult`), its
    estimates are used wherever image and point ids match (warm start); held
    parameters keep their start values.

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
        pts, ok = intersect(problem, state, use)
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
            iop = state.cameras[problem.image_camera[i]][:3]
            state.image[i] = resect(problem.obs_value[sel], state.points[problem.obs_point[sel]], iop)
            need[i] = False
            progress = True
            notes.append(f"image '{images.image_id[i]}': oriented by space resection from {int(sel.sum())} points")
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
        raise AdjustmentError(f"{int(bad.sum())} point(s) cannot be intersected (rays do not meet at a useful "
                              f"angle), e.g. '{points.point_id[np.flatnonzero(bad)[0]]}'")
    # angles into (-pi, pi] (frame images)
    state.image[resectable, 3:] = (state.image[resectable, 3:] + np.pi) % (2 * np.pi) - np.pi
    return state, notes
