"""A COLMAP sparse model (read by :mod:`selfcal.io.colmap`) as a selfcal block.

World-to-camera poses with the camera looking along +z (y down) become perspective centres and
M = R3(kappa) R2(phi) R1(omega) of a camera looking along -z (y up); camera models become principal distance and
principal point; their distortion becomes the initial values of the ``brown`` additional parameters (a
least-squares fit, as selfcal's Delta is a function of the measured, COLMAP's of the ideal position). With ground
control, the arbitrary frame of the reconstruction is moved into the control's CRS by a 3-D similarity estimated
from the control points intersected in that frame.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..ap import ImageFrame, create_ap, fit_displacement, frame_nodes_mm
from ..block import Block, FrameCamera, Images, InitialAP, Observations, Points
from ..errors import BlockError
from ..geometry.rotation import matrix_from_quaternion, opk_from_matrix
from ..geometry.similarity import fit_similarity, intersect_rays
from .labels import match_labels
from ..sensors.frame import pixel_from_photo


#: camera-axis flip between COLMAP (y down, looking along +z) and photogrammetry (y up, looking along -z)
FLIP = np.diag([1.0, -1.0, -1.0])


def _intrinsics(cam) -> tuple[float, float, float, float, dict]:
    p = cam.params
    if "f" in p:
        fx = fy = p["f"]
    else:
        fx, fy = p["fx"], p["fy"]
    dist = {k: v for k, v in p.items() if k not in ("f", "fx", "fy", "cx", "cy")}
    return fx, fy, p["cx"], p["cy"], dist


def colmap_undistort(cam, pixel: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Normalised ideal image coordinates (x/z, y/z in COLMAP's camera frame) of measured pixels.

    Inverts COLMAP's perspective distortion models (SIMPLE_RADIAL, RADIAL, OPENCV,
    FULL_OPENCV; pinhole models have none) by fixed-point iteration.
    """
    fx, fy, cx, cy, d = _intrinsics(cam)
    xd = (pixel[:, 0] - cx) / fx
    yd = (pixel[:, 1] - cy) / fy
    k1 = d.get("k1", d.get("k", 0.0))
    k2, k3, k4, k5, k6 = (d.get(k, 0.0) for k in ("k2", "k3", "k4", "k5", "k6"))
    p1, p2 = d.get("p1", 0.0), d.get("p2", 0.0)
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    return np.column_stack([x, y])


def colmap_distortion_as_brown(cam, camera: FrameCamera, nodes_x: int = 61) -> tuple[InitialAP | None, float]:
    """COLMAP's distortion of ``cam`` as initial values of selfcal's ``brown`` APs on ``camera``.

    On a grid over the image, Delta = measured - ideal (photo coordinates, mm) with the ideal
    position from COLMAP's inverse model, c = ``camera.focal_mm`` and the principal point of
    ``camera`` (a difference of fx and fy becomes the affinity b1). Returns None for models
    without distortion, and the largest misfit of the fit in pixels.
    """
    if not set(cam.params) - {"f", "fx", "fy", "cx", "cy"}:
        return None, 0.0
    p = camera.pixel_size_mm
    frame = ImageFrame(camera.width_mm, camera.height_mm, p)
    x, y = frame_nodes_mm(frame, nodes_x)
    ideal = colmap_undistort(cam, pixel_from_photo(np.column_stack([x, y]), cam.width, cam.height, p))
    dx = x - (camera.x0_mm + camera.focal_mm * ideal[:, 0])
    dy = y - (camera.y0_mm - camera.focal_mm * ideal[:, 1])
    brown = create_ap("brown", frame)
    values, misfit = fit_displacement(brown, x, y, dx / p, dy / p)
    return (InitialAP("brown", tuple(brown.parameter_names), tuple(float(v) for v in values)),
            float(np.max(np.hypot(misfit[:, 0], misfit[:, 1]))))


#: a control measurement is dropped when its ray misses the surveyed point by more than this many
#: standard deviations (the control point's larger sigma seen from the camera, with the image sigma)
MEASUREMENT_MISS_SIGMAS = 3.0

#: rays of one control point that miss their intersection by more than this hold a blunder
MAX_RAY_MISS_DEG = 1.0


def _robust_similarity(local, target, ok, names, notes, factor: float = 3.0, path: str = "gcp_list.txt"):
    """Similarity from the usable control points, dropping the worst while it stands out.

    A point is dropped when its residual exceeds ``factor`` times the median
    residual of the others (and at least 3 points remain).
    """
    ok = ok.copy()
    if ok.sum() < 3:
        raise BlockError(path, f"only {int(ok.sum())} ground control points are seen consistently in two "
                                         f"or more images of the model; 3 are needed to georeference it")
    while True:
        sim, residual = fit_similarity(local[ok], target[ok])
        size = np.linalg.norm(residual, axis=1)
        worst = int(np.argmax(size))
        others = np.delete(size, worst)
        if ok.sum() <= 3 or size[worst] <= factor * max(np.median(others), 1e-9):
            break
        k = np.flatnonzero(ok)[worst]
        ok[k] = False
        notes.append(f"gcp '{names[k]}' disagrees with the others by {size[worst]:.2f} m after the similarity; "
                     f"not used for the georeference")
    rms = np.sqrt(np.mean(size**2))
    notes.append(f"georeferenced by a 3-D similarity from {int(ok.sum())} control points: scale {sim.scale:.6g}, "
                 f"residual rms {rms:.3f} m")
    return sim, ok


#: a-priori sigma of the height of a control point known in plan only (gcp_list.txt geo_z NaN): held at a height
#: that only starts it, so loosely that the height is free (the engine weights a control point per axis)
PLAN_ONLY_SIGMA_Z_M = 1.0e6


#: the pixel size assumed when none is given (COLMAP and OpenSfM work in pixels only): it sets the camera's focal
#: length, principal point and APs in mm, and its use is a warning among the notes of the import
DEFAULT_PIXEL_SIZE_MM = 0.005

#: a-priori sigma (plan, height) of the control of an OpenDroneMap gcp_list.txt when none is given: the file has no
#: accuracy column, so this is every point's; metre level as a hand-held GPS (the COPR block's targets), not the
#: 0.01/0.02 m of the surveyed default of the importers whose files carry accuracies. Its use is a warning
DEFAULT_GCP_LIST_SIGMA_M = (3.0, 5.0)


def pixel_size_or_default(pixel_size_mm: float | None, tool: str, notes: list[str]) -> float:
    """``pixel_size_mm``, else :data:`DEFAULT_PIXEL_SIZE_MM` with a warning in ``notes`` naming the value, why and
    the option that sets it."""
    if pixel_size_mm is not None:
        return float(pixel_size_mm)
    notes.append(f"warning: no pixel size given: {DEFAULT_PIXEL_SIZE_MM} mm assumed ({tool} works in pixels only); "
                 f"it sets the focal length, principal point and APs in mm; give the camera's with --pixel-size-mm")
    return DEFAULT_PIXEL_SIZE_MM


def block_from_colmap(model, control=None, pixel_size_mm: float | None = None, image_sigma_px: float = 1.0,
                      control_sigma_m: tuple[float, float] | None = None, check_points=(),
                      name: str = "colmap") -> tuple[Block, list[str]]:
    """A block from a COLMAP model, georeferenced by ground control when given.

    Parameters
    ----------
    model : selfcal.io.colmap.ColmapModel
    control : selfcal.io.odm.GroundControl, optional
    pixel_size_mm : float, optional
        Physical pixel size (COLMAP works in pixels only); default :data:`DEFAULT_PIXEL_SIZE_MM`, with a warning.
    control_sigma_m : (sigma_xy, sigma_z) of the control coordinates, optional
        Default :data:`DEFAULT_GCP_LIST_SIGMA_M`, with a warning when there is control.
    check_points : names of control points to use as check points.

    Returns
    -------
    block, notes (what was done: similarity residuals, dropped measurements)
    """
    from ..io.colmap import PERSPECTIVE_MODELS

    notes: list[str] = []
    pixel_size_mm = pixel_size_or_default(pixel_size_mm, "COLMAP", notes)
    if control_sigma_m is None:
        control_sigma_m = DEFAULT_GCP_LIST_SIGMA_M
        if control is not None:
            notes.append(f"warning: no control sigma given: {control_sigma_m[0]:g} m in plan, {control_sigma_m[1]:g} m "
                         f"in height assumed for every point of {control.path} (gcp_list.txt has no accuracy "
                         f"column; metre level, as a hand-held GPS); give surveyed targets theirs with "
                         f"--gcp-sigma-xy and --gcp-sigma-z (e.g. 0.01 and 0.02)")
    if control is not None:
        from .gnss import projected_control
        control, note = projected_control(control)
        if note:
            notes.append(note)
    cameras = {}
    for cid, cam in model.cameras.items():
        if cam.model not in PERSPECTIVE_MODELS:
            raise BlockError("cameras", f"camera {cid}: model {cam.model} is not a perspective model "
                                        f"(supported: {', '.join(PERSPECTIVE_MODELS)})")
        fx, fy, cx, cy, _ = _intrinsics(cam)
        p = pixel_size_mm
        camera = FrameCamera(f"cam{cid}", cam.width, cam.height, p, focal_mm=0.5 * (fx + fy) * p,
                             x0_mm=(cx - cam.width / 2) * p, y0_mm=(cam.height / 2 - cy) * p)
        initial, misfit_px = colmap_distortion_as_brown(cam, camera)
        if initial is not None:
            camera = replace(camera, initial_ap=initial)
            notes.append(f"camera {cid} ({cam.model}): its distortion is the initial value of the brown APs "
                         f"(largest misfit of the conversion {misfit_px:.3f} px)")
        cameras[camera.camera_id] = camera
    R = matrix_from_quaternion(model.qvec)                       # world -> COLMAP camera
    centres = -np.einsum("nji,nj->ni", R, model.tvec)
    M = FLIP @ R                                                # object -> image axes (photogrammetric)
    xyz = model.point_xyz.copy()

    gcp_xyz = gcp_obs = None
    if control is not None:
        # the images of the measurements joined to the model's by name (exactly, else after the normalisations of
        # selfcal.convert.labels: case, a folder prefix, ...); none at all is a BlockError naming the file
        match = match_labels(control.obs_image, model.image_names, path=control.path, other_path="the model",
                             what="image names")
        notes.extend(f"warning: {m}" for m in match.messages if m != match.unmatched_message)
        index_of = {n: k for k, n in enumerate(model.image_names)}
        index_of = {name: index_of[other] for name, other in match.partner.items()}
        known = np.array([img in index_of for img in control.obs_image])
        for img in sorted(set(control.obs_image[~known])):
            notes.append(f"ground control measurements in image '{img}' dropped: the image is not in the model")
        img = np.array([index_of[i] for i in control.obs_image[known]], dtype=np.int64)
        pt = control.obs_point[known]
        pix = control.obs_pixel[known]
        rays_cam = np.column_stack([np.zeros(len(img)), np.zeros(len(img)), np.ones(len(img))])
        for j, im in enumerate(img):
            cam = model.cameras[int(model.image_camera[im])]
            rays_cam[j, :2] = colmap_undistort(cam, pix[j:j + 1])[0]
        directions = np.einsum("nji,nj->ni", R[img], rays_cam)   # R^T ray
        local = intersect_rays(centres[img], directions, pt, len(control.point_names))
        ok = np.isfinite(local).all(axis=1)
        for k in np.flatnonzero(~ok):
            notes.append(f"gcp '{control.point_names[k]}' seen in fewer than two images: not used for the "
                         f"georeference")
        # rays of a point that miss each other by more than MAX_RAY_MISS_DEG hold a blunder
        to_point = local[pt] - centres[img]
        unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        along = np.einsum("ni,ni->n", to_point, unit)
        miss = np.degrees(np.arctan2(np.linalg.norm(to_point - along[:, None] * unit, axis=1), np.abs(along)))
        for k in np.flatnonzero(ok):
            worst = np.nanmax(miss[pt == k])
            in_front = np.all(along[pt == k] > 0)
            if worst > MAX_RAY_MISS_DEG or not in_front:
                ok[k] = False
                notes.append(f"gcp '{control.point_names[k]}': its image measurements do not intersect (rays miss "
                             f"by up to {worst:.1f} deg); not used for the georeference")
        plan_only = ~np.isfinite(control.xyz[:, 2])
        for k in np.flatnonzero(plan_only & ok):
            notes.append(f"gcp '{control.point_names[k]}' has no height (NaN): plan control only, not used for the "
                         f"3-D georeference")
        sim, used = _robust_similarity(local, control.xyz, ok & ~plan_only, control.point_names, notes,
                                       path=control.path)
        centres = sim.apply(centres)
        xyz = sim.apply(xyz)
        M = M @ sim.rotation.T
        gcp_xyz = control.xyz.copy()
        if plan_only.any():
            # a plan-only point is held at its intersected height (else the others' median) with a loose sigma
            ground = sim.apply(np.where(np.isfinite(local), local, 0.0))[:, 2]
            gcp_xyz[plan_only, 2] = np.where(ok[plan_only], ground[plan_only],
                                             np.median(control.xyz[~plan_only, 2]))
        # a measurement whose ray misses its surveyed point by far more than the point's sigma allows is a
        # misidentified target: left out (the adjustment would not converge with it)
        focal_px = np.array([np.mean(_intrinsics(model.cameras[int(model.image_camera[i])])[:2]) for i in img])
        to_point = gcp_xyz[pt] - centres[img]
        depth = np.linalg.norm(to_point, axis=1)
        unit = (directions @ sim.rotation.T) / np.linalg.norm(directions, axis=1, keepdims=True)
        angle = np.arccos(np.clip(np.einsum("ni,ni->n", to_point, unit) / depth, -1.0, 1.0))
        miss_px = focal_px * np.tan(np.minimum(angle, 1.5))
        allowed_px = MEASUREMENT_MISS_SIGMAS * np.hypot(max(control_sigma_m) * focal_px / depth, image_sigma_px)
        bad = miss_px > allowed_px
        for k in np.flatnonzero(bad):
            notes.append(f"gcp '{control.point_names[pt[k]]}' in image '{model.image_names[img[k]]}': the "
                         f"measurement is {miss_px[k]:.0f} px from the georeferenced point ({allowed_px[k]:.0f} px "
                         f"allowed by its sigma); dropped as a misidentified target")
        gcp_obs = (img[~bad], pt[~bad], pix[~bad])

    # images
    n = len(model.image_ids)
    images = Images(
        image_id=np.array([str(s) for s in model.image_names], dtype=object),
        camera_id=np.array([f"cam{c}" for c in model.image_camera], dtype=object),
        strip_id=np.full(n, "", dtype=object),
        time_s=np.full(n, np.nan),
        position_m=centres,
        attitude_rad=opk_from_matrix(M),
        line=np.arange(1, n + 1),
    )
    # points: control (with their names) then tie points
    names, roles, coords, sigmas = [], [], [], []
    if gcp_xyz is not None:
        checks = set(check_points)
        unknown = checks - set(control.point_names)
        if unknown:
            raise BlockError(control.path, f"check point(s) {', '.join(sorted(unknown))} not in the file")
        for g, pname in enumerate(control.point_names):
            names.append(str(pname))
            roles.append("chk" if pname in checks else "gcp")
            coords.append(gcp_xyz[g])
            plan = not np.isfinite(control.xyz[g, 2])
            if plan and pname in checks:
                raise BlockError(control.path, f"check point '{pname}' has no height (NaN): a check point needs "
                                                 f"all three coordinates")
            sigmas.append([control_sigma_m[0], control_sigma_m[0], PLAN_ONLY_SIGMA_Z_M if plan else control_sigma_m[1]])
    n_ctl = len(names)
    tie_names = [f"colmap{pid}" for pid in model.point_ids]
    points = Points(
        point_id=np.array(names + tie_names, dtype=object),
        role=np.array(roles + ["tie"] * len(tie_names), dtype=object),
        xyz_m=np.vstack([np.array(coords).reshape(-1, 3), xyz]),
        sigma_m=np.vstack([np.array(sigmas).reshape(-1, 3), np.full((len(tie_names), 3), np.nan)]),
        line=np.arange(1, n_ctl + len(tie_names) + 1),
    )
    # observations
    image_of = {int(i): k for k, i in enumerate(model.image_ids)}
    point_of = {int(p): n_ctl + k for k, p in enumerate(model.point_ids)}
    o_img = np.array([image_of[int(i)] for i in model.obs_image], dtype=np.int64)
    o_pt = np.array([point_of[int(p)] for p in model.obs_point], dtype=np.int64)
    o_pix = model.obs_xy
    if gcp_obs is not None:
        o_img = np.concatenate([gcp_obs[0], o_img])
        o_pt = np.concatenate([gcp_obs[1], o_pt])
        o_pix = np.vstack([gcp_obs[2], o_pix])
    # a COLMAP 2-D point may see the same 3-D point twice in one image: keep the first
    pair = o_img * (len(points.point_id) + 1) + o_pt
    _, first = np.unique(pair, return_index=True)
    if len(first) < len(pair):
        notes.append(f"{len(pair) - len(first)} repeated observations of a point in the same image dropped")
    first = np.sort(first)
    m = len(first)
    observations = Observations(o_img[first], o_pt[first], o_pix[first], np.full(m, image_sigma_px),
                                np.arange(1, m + 1))
    crs = control.crs if control is not None else "local"
    # without ground control the model is a relative network (its datum is COLMAP's arbitrary frame)
    n_gcp = int(np.sum(points.role == "gcp"))
    block = Block(name=name, crs=crs, cameras=cameras, images=images, points=points,
                  observations=observations, image_sigma_px=image_sigma_px,
                  datum="control" if n_gcp >= 3 else "free")
    if n_gcp < 3 and control is not None and gcp_xyz is not None and n_gcp == 0:
        notes.append("every control point is a check point: the block is a free network (datum = \"free\") in the "
                     "frame of the similarity above")
    elif n_gcp < 3:
        notes.append(f"{n_gcp} ground control points: the block is a free network (datum = \"free\"); give --gcp "
                     f"with at least 3 points to georeference it")
    return block, notes
