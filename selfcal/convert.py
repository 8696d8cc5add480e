"""Foreign models (read by :mod:`selfcal.io`) turned into selfcal blocks.

The conventions of each source are translated here, once:

* COLMAP: world-to-camera poses with the camera looking along +z (y down)
  become perspective centres and M = R3(kappa) R2(phi) R1(omega) of a camera
  looking along -z (y up); camera models become principal distance and
  principal point; their distortion becomes the initial values of the
  ``brown`` additional parameters (a least-squares fit, as selfcal's Delta is
  a function of the measured, COLMAP's of the ideal position).
  With ground control, the arbitrary frame of the reconstruction is moved
  into the control's CRS by a 3-D similarity estimated from the control
  points intersected in that frame.
* A results folder to a COLMAP dense workspace (:func:`colmap_workspace`):
  the inverse of the COLMAP import's conventions (R = F M, t = -R (C - origin)
  with F = diag(1, -1, -1)), a PINHOLE camera of the ideal (undistorted)
  image, and the observations moved to their ideal positions, measured -
  Delta(measured), as the adjustment itself computes them.
* BAL: every camera becomes a ``bal`` camera of its own with one image;
  image coordinates (centred, y up) become pixel positions on a frame just
  large enough to hold the camera's observations.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from .ap import ImageFrame, create_ap, fit_displacement, frame_nodes_mm
from .block import BalCamera, Block, FrameCamera, Images, InitialAP, Observations, Points
from .errors import BlockError
from .geometry.rotation import matrix_from_opk, matrix_from_quaternion, opk_from_matrix, quaternion_from_matrix
from .geometry.similarity import fit_similarity, intersect_rays
from .sensors.frame import pixel_from_photo, project

__all__ = ["block_from_isis", "block_from_colmap", "colmap_workspace", "ColmapWorkspace", "WORKSPACE_ROLES",
           "colmap_undistort", "colmap_distortion_as_brown", "block_from_bal", "bal_behind_camera",
           "camera_from_calibration"]

#: camera-axis flip between COLMAP (y down, looking along +z) and photogrammetry (y up, looking along -z)
_FLIP = np.diag([1.0, -1.0, -1.0])


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


def _robust_similarity(local, target, ok, names, notes, factor: float = 3.0):
    """Similarity from the usable control points, dropping the worst while it stands out.

    A point is dropped when its residual exceeds ``factor`` times the median
    residual of the others (and at least 3 points remain).
    """
    ok = ok.copy()
    if ok.sum() < 3:
        raise BlockError("gcp_list.txt", f"only {int(ok.sum())} ground control points are seen consistently in two "
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


def block_from_colmap(model, control=None, pixel_size_mm: float = 0.005, image_sigma_px: float = 1.0,
                      control_sigma_m: tuple[float, float] = (3.0, 5.0), check_points=(),
                      name: str = "colmap") -> tuple[Block, list[str]]:
    """A block from a COLMAP model, georeferenced by ground control when given.

    Parameters
    ----------
    model : selfcal.io.colmap.ColmapModel
    control : selfcal.io.odm.GroundControl, optional
    pixel_size_mm : float
        Physical pixel size (COLMAP works in pixels only).
    control_sigma_m : (sigma_xy, sigma_z) of the control coordinates.
    check_points : names of control points to use as check points.

    Returns
    -------
    block, notes (what was done: similarity residuals, dropped measurements)
    """
    from .io.colmap import PERSPECTIVE_MODELS

    notes: list[str] = []
    if control is not None:
        from .convert_gnss import projected_control
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
    M = _FLIP @ R                                                # object -> image axes (photogrammetric)
    xyz = model.point_xyz.copy()

    gcp_xyz = gcp_obs = None
    if control is not None:
        index_of = {n: k for k, n in enumerate(model.image_names)}
        known = np.array([img in index_of for img in control.obs_image])
        for img in sorted(set(control.obs_image[~known])):
            notes.append(f"ground control measurements in image '{img}' dropped: the image is not in the model")
        img = np.array([index_of[i] for i in control.obs_image[known]], dtype=np.int64)
        pt = control.obs_point[known]
        pix = control.obs_pixel[known]
        rays_cam = np.column_stack([np.zeros(len(img)), np.zeros(len(img)), np.ones(len(img))])
        for k, im in enumerate(img):
            cam = model.cameras[int(model.image_camera[im])]
            rays_cam[k, :2] = colmap_undistort(cam, pix[k:k + 1])[0]
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
        sim, used = _robust_similarity(local, control.xyz, ok & ~plan_only, control.point_names, notes)
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
            raise BlockError("gcp_list.txt", f"check point(s) {', '.join(sorted(unknown))} not in the file")
        for k, pname in enumerate(control.point_names):
            names.append(str(pname))
            roles.append("chk" if pname in checks else "gcp")
            coords.append(gcp_xyz[k])
            plan = not np.isfinite(control.xyz[k, 2])
            if plan and pname in checks:
                raise BlockError("gcp_list.txt", f"check point '{pname}' has no height (NaN): a check point needs "
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


def bal_behind_camera(problem) -> np.ndarray:
    """Observations (bool over the file's) whose point lies behind its camera; BAL's formula
    p = -P/P_z still gives them a residual, fitted by a mirrored projection; COLMAP's cost
    function would ignore them."""
    from .sensors.bal import behind_camera

    return behind_camera(problem.points[problem.obs_point], problem.cameras[problem.obs_camera, :6])


def block_from_bal(problem, image_sigma_px: float = 1.0, name: str = "bal") -> Block:
    """A block from a BAL problem (:class:`selfcal.io.bal.BalProblem`), one camera and image per BAL camera."""
    from .sensors.bal import eop_from_params

    n_cam = len(problem.cameras)
    cameras, widths, heights = {}, np.zeros(n_cam), np.zeros(n_cam)
    for k in range(n_cam):
        sel = problem.obs_camera == k
        half_w = np.ceil(np.max(np.abs(problem.obs_xy[sel, 0]), initial=1.0)) + 1.0
        half_h = np.ceil(np.max(np.abs(problem.obs_xy[sel, 1]), initial=1.0)) + 1.0
        widths[k], heights[k] = 2 * half_w, 2 * half_h
        f, k1, k2 = problem.cameras[k, 6:9]
        cameras[f"cam{k}"] = BalCamera(f"cam{k}", int(widths[k]), int(heights[k]), float(f), float(k1), float(k2))
    position, opk = eop_from_params(problem.cameras[:, :6])
    images = Images(
        image_id=np.array([f"img{k}" for k in range(n_cam)], dtype=object),
        camera_id=np.array([f"cam{k}" for k in range(n_cam)], dtype=object),
        strip_id=np.full(n_cam, "", dtype=object),
        time_s=np.full(n_cam, np.nan),
        position_m=position,
        attitude_rad=opk,
        line=np.arange(1, n_cam + 1),
    )
    n_pt = len(problem.points)
    points = Points(point_id=np.array([f"p{k}" for k in range(n_pt)], dtype=object),
                    role=np.full(n_pt, "tie", dtype=object), xyz_m=problem.points.copy(),
                    sigma_m=np.full((n_pt, 3), np.nan), line=np.arange(1, n_pt + 1))
    cam = problem.obs_camera
    pixel = np.column_stack([problem.obs_xy[:, 0] + widths[cam] / 2, heights[cam] / 2 - problem.obs_xy[:, 1]])
    m = len(cam)
    observations = Observations(cam.copy(), problem.obs_point.copy(), pixel, np.full(m, image_sigma_px),
                                np.arange(1, m + 1))
    return Block(name=name, crs="local", cameras=cameras, images=images, points=points,
                 observations=observations, image_sigma_px=image_sigma_px, datum="free")


#: a control coordinate with this sigma (m) is as good as free: jigsaw's radius=no holds a Free point's radius only
FREE_SIGMA_M = 1.0e6


def block_from_isis(network, images: dict, image_sigma_px: float = 0.35, name: str = "isis",
                    camera_settings: dict | None = None, fixed_sigma_m: float = 0.001,
                    hold_radii_m: float | None = None) -> tuple[Block, dict]:
    """A block from an ISIS control network (:func:`selfcal.io.isis.read_control_network`) and the images of
    its measures (``images``: serial number -> (cube label, sensor file), :func:`selfcal.io.isis.read_image_folder`).

    One ``usgscsm`` camera per instrument (spacecraft and instrument id), each image's ISD as its sensor_file;
    Fixed and Constrained points become ``gcp`` (Fixed held by ``fixed_sigma_m``, Constrained with their
    a-priori sigmas: the mean of latitude and longitude sigma in plan, the radius sigma in height, ISIS's
    body-fixed covariance turned into north, east, radial), Free points ``tie`` with their a-priori XYZ as
    start values. Ignored points and measures, and measures of images not in ``images``, are left out and
    counted (the second return value). Points are body-fixed metres (``crs = "body-fixed"``). With
    ``hold_radii_m`` Free points with a-priori coordinates keep their radius within that sigma, latitude and
    longitude free (sigma :data:`FREE_SIGMA_M`): jigsaw's ``radius=no``; they are then ``gcp`` of the block.
    ``image_sigma_px`` (cube pixels): jigsaw's default weight of a measure is 1.4 detector pixels, 0.35
    pixels of the Apollo cubes reduced 4x. ``camera_settings``: block.toml keys of the cameras (sigmas)."""
    from .geometry.body import sigmas_from_covariance
    from .sensors.usgscsm_frame import UsgscsmCamera

    counts = {"ignored_points": 0, "ignored_measures": 0, "measures_without_image": 0}
    used = {}
    for point in network.points:
        if point.ignored:
            counts["ignored_points"] += 1
            continue
        for m in point.measures:
            if m.ignored:
                counts["ignored_measures"] += 1
            elif m.serial_number not in images:
                counts["measures_without_image"] += 1
            else:
                used.setdefault(m.serial_number, len(used))
    serials = sorted(used, key=lambda s: os.path.basename(images[s][1]))
    index = {s: k for k, s in enumerate(serials)}
    instrument = {s: f"{images[s][0].spacecraft_name}_{images[s][0].instrument_id}".replace(" ", "_") for s in serials}
    settings = dict(camera_settings or {})
    cameras = {c: UsgscsmCamera(c, **settings) for c in dict.fromkeys(instrument.values())}
    image_ids = [os.path.splitext(os.path.basename(images[s][1]))[0] for s in serials]
    n_img = len(serials)
    nan3 = np.full((n_img, 3), np.nan)
    block_images = Images(np.array(image_ids, object), np.array([instrument[s] for s in serials], object),
                          np.full(n_img, "", object), np.full(n_img, np.nan), nan3, nan3.copy(), np.arange(2, n_img + 2))
    ids, roles, xyz, sigma, lines = [], [], [], [], []
    obs_img, obs_pt, pixel = [], [], []
    for point in network.points:
        measures = [m for m in point.measures if not point.ignored and not m.ignored and m.serial_number in index]
        if point.ignored or not measures:
            continue
        k = len(ids)
        ids.append(point.point_id)
        start = point.apriori_xyz_m if point.apriori_xyz_m is not None else np.full(3, np.nan)
        xyz.append(start)
        if point.point_type == "Fixed":
            roles.append("gcp")
            sigma.append([fixed_sigma_m] * 3)
        elif point.point_type == "Constrained" and point.apriori_covariance_m2 is not None:
            roles.append("gcp")
            s_lat, s_lon, s_rad = sigmas_from_covariance(start, point.apriori_covariance_m2)
            s_xy = float(np.sqrt((s_lat ** 2 + s_lon ** 2) / 2))
            sigma.append([s_xy, s_xy, s_rad])
        elif hold_radii_m is not None and point.apriori_xyz_m is not None:
            roles.append("gcp")
            sigma.append([FREE_SIGMA_M, FREE_SIGMA_M, hold_radii_m])
        else:
            roles.append("tie")
            sigma.append([np.nan] * 3)
        lines.append(point.source_line)
        for m in measures:
            obs_img.append(index[m.serial_number])
            obs_pt.append(k)
            pixel.append((m.col_px, m.row_px))
    points = Points(np.array(ids, object), np.array(roles, object), np.array(xyz, float).reshape(-1, 3),
                    np.array(sigma, float).reshape(-1, 3), np.array(lines))
    m = len(obs_img)
    observations = Observations(np.array(obs_img, np.int64), np.array(obs_pt, np.int64), np.array(pixel, float),
                                np.full(m, image_sigma_px), np.arange(2, m + 2))
    files = {image_id: os.path.abspath(images[s][1]) for image_id, s in zip(image_ids, serials)}
    block = Block(name=name, crs="body-fixed", cameras=cameras, images=block_images, points=points,
                  observations=observations, image_sigma_px=image_sigma_px, image_files=files)
    return block, counts


def camera_from_calibration(calibration, camera: FrameCamera, ap_spec: str = "brown",
                            fixed: bool = False) -> tuple[FrameCamera, float]:
    """A block camera whose initial interior orientation and APs are another tool's calibration.

    ``calibration`` is a :class:`selfcal.io.calibration_files.ToolCalibration` of ``camera``'s image size
    (the caller checks it); its model (:data:`selfcal.calibration_models.MODELS`) gives c, x0, y0 and the
    initial ``ap_spec`` coefficients by :func:`selfcal.calibration_models.initial_from_model`, on ``camera``'s
    pixel size. With ``fixed`` they are held in the adjustment (sigma 0 for c, x0, y0 and the APs). Returns
    the camera and the largest misfit of the AP fit over the image (pixels).
    """
    from .calibration_models import MODELS, initial_from_model
    model = MODELS[calibration.tool, calibration.model]
    values = [calibration.values.get(name, 0.0) for name in model.parameter_names]
    initial = initial_from_model(model, values, camera.width_px, camera.height_px, camera.pixel_size_mm, ap_spec)
    hold = 0.0 if fixed else None
    return replace(camera, focal_mm=initial.focal_mm, x0_mm=initial.x0_mm, y0_mm=initial.y0_mm,
                   sigma_focal_mm=hold if fixed else camera.sigma_focal_mm,
                   sigma_x0_mm=hold if fixed else camera.sigma_x0_mm,
                   sigma_y0_mm=hold if fixed else camera.sigma_y0_mm,
                   initial_ap=InitialAP(initial.ap_spec, initial.ap_names, initial.ap_values_px, hold)), \
        initial.misfit_max_px


#: the points of a results folder that go into a dense workspace: those the bundle adjusted (check points
#: are left out: they check the block, they do not tie it)
WORKSPACE_ROLES = ("tie", "gcp")


@dataclass
class ColmapWorkspace:
    """A COLMAP sparse model of the ideal images, and what ties it back to selfcal's results."""

    model: object                   # selfcal.io.colmap.ColmapModel
    origin_m: np.ndarray            # (3,) object coordinates = model coordinates + origin_m
    point_id: np.ndarray            # (k,) selfcal point id of each 3-D point (COLMAP ids 1..k)
    point_role: np.ndarray          # (k,)
    camera_id: dict                 # COLMAP camera id -> selfcal camera id
    image_id: np.ndarray            # (n,) selfcal image id of each image (COLMAP ids 1..n)
    projected_px: np.ndarray        # (m,) x 2: selfcal's projection of each observation's adjusted point
    n_points_short_track: int       # points left out because fewer than min_track exported images see them


def colmap_workspace(calibrations: dict, images: dict, points: dict, residuals: dict, image_names: dict,
                     min_track: int = 2) -> ColmapWorkspace:
    """The COLMAP sparse model of the ideal images of a results folder.

    Parameters
    ----------
    calibrations : camera id -> :class:`selfcal.calibration.Calibration` (frame cameras)
    images, points, residuals : columns of images.csv, points.csv, residuals.csv (DESIGN.md §4)
    image_names : image id -> file name in the workspace; only these images are exported (images of other
        cameras than ``calibrations`` must not be given)
    min_track : 3-D points seen in fewer exported images are left out

    The model has one PINHOLE camera per frame camera: fx = fy = the principal
    distance in pixels and the principal point, the ideal camera of
    :func:`selfcal.calibration.undistortion_maps` in COLMAP's pixel convention
    (that of selfcal: the first pixel's centre at (0.5, 0.5)). Poses are
    world-to-camera, x_cam = R X + t with R = F M, F = diag(1, -1, -1) (COLMAP
    looks along +z with y down, selfcal along -z with y up) and t = -R (C - origin).
    The 3-D points are the adjusted tie and control points minus ``origin_m``
    (their centroid rounded to whole metres); the 2-D points the
    observations that the adjustment kept (``rejected`` 0), each at its ideal
    position measured - Delta(measured); a point's error is the mean distance
    of its ideal observations to selfcal's projection of it (px).
    """
    from .io.colmap import ColmapCamera, ColmapModel

    img_ids = np.asarray(images["image_id"], object)
    pick = np.array([i in image_names for i in img_ids], bool)
    unknown = sorted(set(images["camera_id"][pick]) - set(calibrations))
    if unknown:
        raise ValueError(f"images of camera(s) {', '.join(unknown)}, which is not a frame camera")
    img_ids, cam_of_image = img_ids[pick], np.asarray(images["camera_id"], object)[pick]
    centre = np.column_stack([images["X0"], images["Y0"], images["Z0"]])[pick]
    opk = np.radians(np.column_stack([images["omega_deg"], images["phi_deg"], images["kappa_deg"]]))[pick]
    good = np.isfinite(centre).all(axis=1) & np.isfinite(opk).all(axis=1)
    img_ids, cam_of_image, centre, opk = img_ids[good], cam_of_image[good], centre[good], opk[good]
    image_index = {i: k for k, i in enumerate(img_ids)}

    xyz = np.column_stack([points["X"], points["Y"], points["Z"]])
    role = np.asarray(points["role"], object)
    use_point = np.isin(role, WORKSPACE_ROLES) & np.isfinite(xyz).all(axis=1)
    point_index = {p: k for k, p in enumerate(np.asarray(points["point_id"], object)) if use_point[k]}

    kept = (residuals["rejected"] == 0) & np.isfinite(residuals["vx_px"]) & np.isfinite(residuals["vy_px"])
    o_img = np.array([image_index.get(i, -1) for i in residuals["image_id"]], np.int64)
    o_pt = np.array([point_index.get(p, -1) for p in residuals["point_id"]], np.int64)
    use = kept & (o_img >= 0) & (o_pt >= 0)
    track = np.bincount(o_pt[use], minlength=len(xyz))
    short = use_point & (track < min_track) & (track > 0)
    use &= track[np.maximum(o_pt, 0)] >= min_track
    o_img, o_pt = o_img[use], o_pt[use]
    measured = np.column_stack([residuals["col_px"], residuals["row_px"]])[use]

    exported = np.unique(o_pt)                              # selfcal point indices, COLMAP ids 1..k
    new_id = np.zeros(len(xyz), np.int64)
    new_id[exported] = np.arange(1, len(exported) + 1)
    base = xyz[exported] if len(exported) else centre
    origin = np.round(base.mean(axis=0)) + 0.0 if len(base) else np.zeros(3)     # + 0.0: no -0

    cam_ids = [c for c in calibrations if c in set(cam_of_image)]
    colmap_cam = {c: k for k, c in enumerate(cam_ids, start=1)}
    cameras = {}
    for c in cam_ids:
        cal = calibrations[c]
        col, row = cal.principal_point_px
        cameras[colmap_cam[c]] = ColmapCamera(colmap_cam[c], "PINHOLE", cal.width_px, cal.height_px,
                                              {"fx": cal.focal_px, "fy": cal.focal_px, "cx": col, "cy": row})

    M = matrix_from_opk(opk)
    R = _FLIP @ M
    tvec = -np.einsum("nij,nj->ni", R, centre - origin)
    ideal = np.empty_like(measured)
    projected = np.empty_like(measured)
    eop = np.column_stack([centre, opk])
    for c in cam_ids:
        cal = calibrations[c]
        rows = np.flatnonzero(cam_of_image[o_img] == c)
        ideal[rows] = cal.ideal_from_measured(measured[rows])
        photo = project(xyz[o_pt[rows]], eop[o_img[rows]], np.array([cal.focal_mm, cal.x0_mm, cal.y0_mm]))
        projected[rows] = pixel_from_photo(photo, cal.width_px, cal.height_px, cal.pixel_size_mm)
    miss = np.hypot(*(ideal - projected).T)
    error = np.bincount(o_pt, miss, minlength=len(xyz))[exported] / np.maximum(track[exported], 1)

    model = ColmapModel(
        cameras=cameras,
        image_ids=np.arange(1, len(img_ids) + 1),
        image_names=np.array([image_names[i] for i in img_ids], object),
        image_camera=np.array([colmap_cam[c] for c in cam_of_image], np.int64),
        qvec=quaternion_from_matrix(R).reshape(-1, 4),
        tvec=tvec.reshape(-1, 3),
        obs_image=o_img + 1,
        obs_xy=ideal,
        obs_point=new_id[o_pt],
        point_ids=np.arange(1, len(exported) + 1),
        point_xyz=xyz[exported] - origin,
        point_error=error,
    )
    return ColmapWorkspace(model, origin, np.asarray(points["point_id"], object)[exported], role[exported],
                           {k: c for c, k in colmap_cam.items()}, img_ids, projected, int(short.sum()))
