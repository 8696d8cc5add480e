"""Initial values: forward intersection of object points and space resection of images.

Exterior orientation comes from images.csv. An image without it (or whose
given orientation projects its control points far from where they were
measured) is oriented by space resection from the points whose coordinates
are known: control and check points, and tie points intersected from the
other images. Object points are then intersected from all their rays.
"""
from __future__ import annotations

import numpy as np

from ..errors import AdjustmentError
from ..sensors import bal
from ..sensors.frame import project, project_with_jacobians, rays
from .problem import Problem, State

__all__ = ["intersect", "resect", "initial_state"]

#: an image whose given orientation reprojects its control points worse than
#: this share of the image diagonal is re-oriented by resection
POOR_ORIENTATION_SHARE = 0.05


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
    img = problem.obs_image[use]
    pt = problem.obs_point[use]
    eop = state.eop[img]
    iop = np.array([c[:3] for c in state.cameras])[problem.image_camera[img]]
    d = rays(problem.obs_xy_mm[use], eop, iop)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = np.zeros((problem.n_points, 3, 3))
    b = np.zeros((problem.n_points, 3))
    np.add.at(A, pt, proj)
    np.add.at(b, pt, np.einsum("nij,nj->ni", proj, eop[:, :3]))
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


def _control_rms(problem: Problem, state: State, image: int, known: np.ndarray) -> float:
    sel = (problem.obs_image == image) & known[problem.obs_point]
    if sel.sum() < 3:
        return 0.0
    iop = state.cameras[problem.image_camera[image]][:3]
    pred = project(state.points[problem.obs_point[sel]], np.broadcast_to(state.eop[image], (sel.sum(), 6)), iop)
    return float(np.sqrt(np.mean(np.sum((pred - problem.obs_xy_mm[sel]) ** 2, axis=1))))


def _from_previous(problem: Problem, block, state: State, start) -> tuple[np.ndarray, np.ndarray]:
    """Copy a previous adjustment's estimates where ids match; returns which images and points got one."""
    prev = start.block
    img_lookup = {i: k for k, i in enumerate(prev.images.image_id)}
    pt_lookup = {p: k for k, p in enumerate(prev.points.point_id)}
    img_src = np.array([img_lookup.get(i, -1) for i in block.images.image_id])
    pt_src = np.array([pt_lookup.get(p, -1) for p in block.points.point_id])
    has_img, has_pt = img_src >= 0, pt_src >= 0
    state.eop[has_img] = start.state.eop[img_src[has_img]]
    state.points[has_pt] = start.state.points[pt_src[has_pt]]
    prev_names = [n for t in start.problem.trajectory for n in t.names]
    names = [n for t in problem.trajectory for n in t.names]
    if prev_names == names:
        state.extra[:] = np.where(problem.extra_free, start.state.extra, state.extra)
    prev_cams = {c.camera_id: (c, v) for c, v in zip(start.problem.cameras, start.state.cameras)}
    for k, cam in enumerate(problem.cameras):
        if cam.camera_id in prev_cams:
            pc, values = prev_cams[cam.camera_id]
            state.cameras[k][:3] = values[:3]
            if pc.names == cam.names:
                state.cameras[k][3:] = np.where(cam.free[3:], values[3:], 0.0)
    return has_img, has_pt


def initial_state(problem: Problem, block, start=None) -> tuple[State, list[str]]:
    """Initial values of all unknowns, and notes on what was resected.

    With ``start`` (a previous :class:`~selfcal.adjust.AdjustmentResult`), its
    estimates are used wherever image and point ids match (warm start).

    Raises
    ------
    AdjustmentError
        When an image can be oriented neither from images.csv nor by resection.
    """
    images, points = block.images, block.points
    eop = np.column_stack([images.position_m, images.attitude_rad])
    is_bal = problem.image_sensor == "bal"
    if is_bal.any():
        if not np.isfinite(eop[is_bal]).all():
            raise AdjustmentError("BAL images need their orientation in images.csv (no resection for this model)")
        eop[is_bal] = bal.params_from_eop(eop[is_bal, :3], eop[is_bal, 3:])
    eop_given = eop.copy()
    cameras = [cam.prior_value.copy() for cam in problem.cameras]
    xyz = points.xyz_m.copy()
    state = State(eop=eop, cameras=cameras, points=xyz,
                  extra=np.concatenate([np.zeros(0)] + [t.initial() for t in problem.trajectory]))
    notes: list[str] = []
    if start is not None:
        has_img, has_pt = _from_previous(problem, block, state, start)
        if has_img.all() and has_pt.all():
            return state, notes
        state.eop[~has_img] = eop_given[~has_img]
    known = np.isfinite(xyz).all(axis=1) & (points.role != "tie")  # reference coordinates
    need = ~np.isfinite(eop).all(axis=1)
    # given orientations that miss their control points badly are treated as missing
    for i in np.flatnonzero(~need & ~is_bal):
        cam = block.cameras[images.camera_id[i]]
        diagonal = np.hypot(cam.width_mm, cam.height_mm)
        rms = _control_rms(problem, state, i, known)
        if rms > POOR_ORIENTATION_SHARE * diagonal:
            notes.append(f"image '{images.image_id[i]}': given orientation misses its control points by "
                         f"{rms / cam.pixel_size_mm:.0f} px rms; re-oriented by space resection")
            need[i] = True
    state.eop[need] = np.nan

    given = np.isfinite(points.xyz_m).all(axis=1) & (points.role == "tie")   # approximate tie coordinates
    unknown = (points.role == "chk") | ((points.role == "tie") & ~given)

    def intersect_ties():
        use = ~need[problem.obs_image] & ~is_bal[problem.obs_image]
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
            state.eop[i] = resect(problem.obs_xy_mm[sel], state.points[problem.obs_point[sel]], iop)
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
        raise AdjustmentError(f"{int(bad.sum())} point(s) cannot be intersected (rays do not meet at a useful "
                              f"angle), e.g. '{points.point_id[np.flatnonzero(bad)[0]]}'")
    # angles into (-pi, pi] (frame images; BAL images hold rotation vectors)
    frame = ~is_bal
    state.eop[frame, 3:] = (state.eop[frame, 3:] + np.pi) % (2 * np.pi) - np.pi
    return state, notes
