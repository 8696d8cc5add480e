"""The UAV tools' tie points, orientations and control (read by :mod:`selfcal.io`) turned into selfcal blocks.

Each tool's conventions are translated here, once, into DESIGN.md §2's (pixels with the origin at the upper-left
corner of the upper-left pixel, photo coordinates in mm with y up, M = R3(kappa) R2(phi) R1(omega) object to
image, the camera looking along -z):

* PAT-B (Metashape's export) and BINGO (Pix4D's): photo coordinates in mm, x right, y up; PAT-B's relative to
  the principal point, BINGO's to the image centre (Pix4D's "What is the bingo file"). col = W/2 + x'/p,
  row = H/2 - y'/p with x' the coordinate from the image centre. PAT-B's rotation matrix A maps image to
  object vectors: M = A^T. Pix4D's omega, phi, kappa are PAT-B's (Pix4D's "How are the internal and external
  camera parameters defined": R = Rx(omega) Ry(phi) Rz(kappa), image to object), which are selfcal's angles.
* OpenSfM: world-to-camera angle-axis poses with the camera looking along +z, y down (as COLMAP's), normalized
  image coordinates (origin at the image centre, the larger side 1): col = x_n max(w, h) + w/2.
  Camera models become focal length and principal point, their distortion initial values of the ``brown``
  APs (the fit of :func:`selfcal.convert.colmap_distortion_as_brown`: OpenSfM's brown model is OpenCV's).
* Metashape markers: pixel positions with Metashape's origin at the image's corner (its calibration puts the
  image centre at (w/2, h/2)), selfcal's convention; taken as they are.
"""
from __future__ import annotations

import os
import re
from dataclasses import replace

import numpy as np

from ..block import Block, FrameCamera, Images, Observations, Points
from ..errors import BlockError, UsageError
from ..geometry.rotation import matrix_from_rotation_vector, opk_from_matrix
from .control import crs_kind, swapped_axes
from .labels import match_labels

__all__ = ["block_from_opensfm", "block_from_patb", "block_from_pix4d", "block_with_markers", "camera_key"]

#: camera-axis flip between OpenSfM/COLMAP (y down, looking along +z) and photogrammetry (y up, along -z)
_FLIP = np.diag([1.0, -1.0, -1.0])
#: a rotation matrix read from a file is orthonormal to this (|A^T A - I|)
ORTHONORMAL_TOLERANCE = 1e-6


def camera_key(name: str) -> str:
    """A camera id block.toml takes as a bare key (letters, digits, ``_`` and ``-``)."""
    key = re.sub(r"[^A-Za-z0-9_-]+", "_", str(name)).strip("_")
    return key or "camera"


def _assemble(name, crs, cameras, image_ids, image_camera, position, opk, point_ids, roles, xyz, sigma,
              obs_img, obs_pt, pixel, obs_sigma, image_sigma_px, datum=None) -> Block:
    n, k, m = len(image_ids), len(point_ids), len(obs_img)
    images = Images(np.array(image_ids, object), np.array(image_camera, object), np.full(n, "", object),
                    np.full(n, np.nan), np.asarray(position, float).reshape(n, 3),
                    np.asarray(opk, float).reshape(n, 3), np.arange(1, n + 1))
    points = Points(np.array(point_ids, object), np.array(roles, object), np.asarray(xyz, float).reshape(k, 3),
                    np.asarray(sigma, float).reshape(k, 3), np.arange(1, k + 1))
    observations = Observations(np.asarray(obs_img, np.int64), np.asarray(obs_pt, np.int64),
                                np.asarray(pixel, float).reshape(m, 2), np.asarray(obs_sigma, float),
                                np.arange(1, m + 1))
    if datum is None:
        datum = "control" if int(np.sum(points.role == "gcp")) >= 3 else "free"
    return Block(name=name, crs=crs, cameras=cameras, images=images, points=points, observations=observations,
                 image_sigma_px=image_sigma_px, datum=datum)


def _check_axes(control, positions, crs: str) -> None:
    """A BlockError naming the control file when its X and Y look swapped against the camera positions
    (:func:`selfcal.convert.control.swapped_axes`)."""
    if control is None or positions is None:
        return
    reason = swapped_axes(control.xyz_m, positions, geographic=crs_kind(crs) == "geographic",
                          point_ids=control.point_id, lines=control.line)
    if reason:
        raise BlockError(control.path, reason)


def _control_points(control, checks, default_sigma_m, notes):
    """ids, roles, xyz, sigma of a :class:`selfcal.io.patb.ControlPoints`: ``chk`` where named in ``checks`` or
    disabled in the file, ``gcp`` otherwise; sigma from the file where given, else ``default_sigma_m``."""
    checks = set(checks)
    unknown = checks - set(control.point_id)
    if unknown:
        raise UsageError(f"--check names point(s) not in {control.path}: {', '.join(sorted(unknown))}")
    roles = np.where([p in checks or not e for p, e in zip(control.point_id, control.enabled)], "chk", "gcp")
    sigma = control.sigma_m.copy()
    default = np.array([default_sigma_m[0], default_sigma_m[0], default_sigma_m[1]])
    missing = np.isnan(sigma)
    sigma[missing] = np.broadcast_to(default, sigma.shape)[missing]
    if missing.any():
        notes.append(f"{int(missing.any(axis=1).sum())} control point(s) without a sigma in {control.path}: "
                     f"{default_sigma_m[0]:g} m in plan, {default_sigma_m[1]:g} m in height")
    return list(control.point_id), list(roles), control.xyz_m, sigma


def _points_and_observations(measurements, control, checks, control_sigma_m, to_pixel, image_index, notes):
    """Points (control first, then tie points in the order of the file) and observations of photo measurements.

    Control labels are joined to the measured points by :func:`selfcal.convert.labels.match_labels` (a measured
    point matched after a normalisation takes the control file's label); none matching is a BlockError naming the
    control file."""
    ids, roles, xyz, sigma = [], [], np.zeros((0, 3)), np.zeros((0, 3))
    measured = np.asarray(measurements.point, object)
    if control is not None:
        match = match_labels(control.point_id, dict.fromkeys(measured), path=control.path,
                             other_path=measurements.path, what="control labels")
        notes.extend(f"warning: {m}" for m in match.messages)
        renamed = match.renamed
        if renamed:
            measured = np.array([renamed.get(p, p) for p in measured], object)
            checks = [renamed.get(c, c) for c in checks]
        ids, roles, xyz, sigma = _control_points(control, checks, control_sigma_m, notes)
    elif checks:
        raise UsageError("--check needs control points (a control file)")
    index = {p: i for i, p in enumerate(ids)}
    ties = [p for p in dict.fromkeys(measured) if p not in index]
    for p in ties:
        index[p] = len(index)
    n_tie = len(ties)
    ids = list(ids) + ties
    roles = list(roles) + ["tie"] * n_tie
    xyz = np.vstack([xyz, np.full((n_tie, 3), np.nan)])
    sigma = np.vstack([sigma, np.full((n_tie, 3), np.nan)])
    obs_img = np.array([image_index[i] for i in measurements.image], np.int64)
    obs_pt = np.array([index[p] for p in measured], np.int64)
    pixel = to_pixel(measurements.xy_mm, obs_img)
    return ids, roles, xyz, sigma, obs_img, obs_pt, pixel


def _rotation_from_image_to_object(orientations, k) -> np.ndarray:
    a = orientations.rotation[k]
    error = float(np.max(np.abs(a.T @ a - np.eye(3))))
    if error > ORTHONORMAL_TOLERANCE or np.linalg.det(a) < 0:
        raise BlockError(orientations.path, f"the rotation matrix of photo '{orientations.image[k]}' is not a "
                                            f"rotation (|A^T A - I| = {error:.2g}, det {np.linalg.det(a):.3g})",
                         int(orientations.line[k]))
    return a


def _stem(name: str) -> str:
    """An image name without its file extension."""
    base, ext = os.path.splitext(str(name))
    return base if ext else str(name)


def _orientations(orientations, photos, image_index, notes, angles=False):
    """Perspective centres and angles (rad) of ``photos`` (NaN where the file has none)."""
    n = len(photos)
    position, opk = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    if orientations is None:
        notes.append("no exterior orientations: the adjustment computes initial values")
        return position, opk
    stems = {_stem(p): i for p, i in image_index.items()}
    for k, image in enumerate(orientations.image):
        # Pix4D's BINGO names an image without its extension (P1060498), the external parameters with it
        i = image_index.get(image, stems.get(_stem(image)))
        if i is None:
            raise BlockError(orientations.path, f"photo '{image}' has no image measurements (it is not in "
                                                f"{', '.join(sorted(set(photos)))[:200]})", int(orientations.line[k]))
        position[i] = orientations.position_m[k]
        if angles:
            opk[i] = np.radians(orientations.opk_deg[k])
        else:
            opk[i] = opk_from_matrix(_rotation_from_image_to_object(orientations, k).T)
    without = [p for p in photos if np.isnan(position[image_index[p]]).any()]
    if without:
        notes.append(f"{len(without)} photo(s) without an exterior orientation: {', '.join(without[:5])}"
                     + (" ..." if len(without) > 5 else ""))
    return position, opk


def block_from_patb(measurements, control=None, orientations=None, *, width_px: int, height_px: int,
                    pixel_size_mm: float, focal_mm: float | None = None, principal_point_mm=(0.0, 0.0),
                    image_unit_mm: float = 1.0,
                    image_sigma_px: float = 1.0, control_sigma_m=(0.01, 0.02), check_points=(),
                    crs: str = "local", name: str = "patb") -> tuple[Block, list[str]]:
    """A block from PAT-B files (:mod:`selfcal.io.patb`): one frame camera, the photos of the ``.im``.

    ``principal_point_mm``: (x0, y0) of the principal point from the image centre (selfcal's photo coordinates);
    PAT-B's image coordinates are relative to it. ``focal_mm``: the camera constant; by default the one the
    ``.im`` headers give (all alike). Control points come from the ``.con`` (``gcp``, or ``chk`` when named in
    ``check_points``) with ``control_sigma_m`` = (plan, height); other points are tie points without initial
    coordinates. ``image_unit_mm``: the length of the ``.im`` coordinates' unit in mm (0.001 for microns, as
    the export's ``.pro`` may state). Returns the block and notes of what was done.
    """
    notes: list[str] = []
    _check_axes(control, None if orientations is None else orientations.position_m, crs)
    if focal_mm is None:
        constants = {}
        for photo in measurements.photos:
            head = measurements.header[photo]
            try:
                constants[photo] = float(head[0])
            except (IndexError, ValueError):
                raise BlockError(measurements.path, f"photo '{photo}': the header gives no camera constant; give "
                                                    f"--focal-mm", measurements.header_line[photo]) from None
        values = sorted(set(constants.values()))
        if len(values) > 1:
            photo = next(p for p in measurements.photos if constants[p] != constants[measurements.photos[0]])
            raise BlockError(measurements.path, f"photos have different camera constants ({values[0]:g} and "
                                                f"{values[1]:g} mm); selfcal imports one camera: give --focal-mm",
                             measurements.header_line[photo])
        focal_mm = values[0]
    x0, y0 = principal_point_mm
    camera = FrameCamera("patb", int(width_px), int(height_px), float(pixel_size_mm), float(focal_mm), float(x0),
                         float(y0))
    photos = list(measurements.photos)
    image_index = {p: i for i, p in enumerate(photos)}

    def to_pixel(xy, img):
        col = width_px / 2.0 + (xy[:, 0] * image_unit_mm + x0) / pixel_size_mm
        row = height_px / 2.0 - (xy[:, 1] * image_unit_mm + y0) / pixel_size_mm
        return np.column_stack([col, row])

    ids, roles, xyz, sigma, obs_img, obs_pt, pixel = _points_and_observations(
        measurements, control, check_points, control_sigma_m, to_pixel, image_index, notes)
    position, opk = _orientations(orientations, photos, image_index, notes)
    block = _assemble(name, crs, {"patb": camera}, photos, ["patb"] * len(photos), position, opk, ids, roles, xyz,
                      sigma, obs_img, obs_pt, pixel, np.full(len(obs_img), image_sigma_px), image_sigma_px)
    if block.datum == "free":
        notes.append(_free_patb_warning(roles.count("gcp"), orientations is not None))
    return block, notes


def _free_patb_warning(n_gcp: int, has_orientations: bool) -> str:
    """What a PAT-B block with fewer than 3 control points is: a free network, and what that costs."""
    control = "no control (no .con)" if n_gcp == 0 else f"only {n_gcp} control point(s)"
    if has_orientations:
        return (f"warning: {control}: the block is a free network; the adjustment keeps the datum (position, "
                f"rotation and scale) of the .ori orientations, the principal distance and the heights are held "
                f"only by the relief and the photos' convergence, the precision is relative and no check point "
                f"measures the accuracy; give a .con with at least 3 control points to tie it to the ground")
    return (f"warning: {control} and no orientations (no .ori): the block is a free network the adjustment "
            f"cannot start (no photo can be oriented); give a .ori, or a .con with at least 4 control points "
            f"in every photo (a space resection each), before `selfcal adjust`")


def block_from_pix4d(params, control=None, *, image_sigma_px: float = 1.0, control_sigma_m=(0.01, 0.02),
                     check_points=(), crs: str = "local", name: str = "pix4d") -> tuple[Block, list[str]]:
    """A block from Pix4D's ``params/`` folder (:class:`selfcal.io.pix4d.Pix4dParams`).

    BINGO image coordinates (mm from the image centre, y up) become pixels with the pixel size of the
    calibrated camera (sensor width / image width); the calibrated internal parameters give focal length and
    principal point, and their radial distortion initial values of the ``brown`` APs; the calibrated external
    ones the images' positions and omega, phi, kappa. Control
    (``control``: a :class:`selfcal.io.patb.ControlPoints`, e.g. from a GCP file) matches BINGO point ids.
    """
    notes: list[str] = []
    _check_axes(control, None if params.external is None else params.external.position_m, crs)
    cam = params.camera
    p = cam.sensor_width_mm / cam.width_px
    if abs(cam.sensor_height_mm / cam.height_px - p) > 1e-6 * p:
        notes.append(f"the sensor ({cam.sensor_width_mm:g} x {cam.sensor_height_mm:g} mm) and the image "
                     f"({cam.width_px} x {cam.height_px} px) differ in aspect; the pixel size is taken from the width")
    # Pix4D's principal point: mm from the upper-left corner of the sensor, x right, y down
    camera = FrameCamera("pix4d", cam.width_px, cam.height_px, p, cam.focal_mm,
                         cam.principal_point_mm[0] - cam.width_px * p / 2.0,
                         cam.height_px * p / 2.0 - cam.principal_point_mm[1])
    # Pix4D's lens model ("How are the internal and external camera parameters defined") is OpenCV's on the
    # homogeneous point with x right, y down: x_d = x_h (1 + R1 r^2 + R2 r^4 + R3 r^6) + 2 T1 x_h y_h + T2 (r^2 +
    # 2 x_h^2), y_d = y_h (...) + T1 (r^2 + 2 y_h^2) + 2 T2 x_h y_h, so R1..R3 are k1..k3 and T1, T2 are p1, p2.
    # (Issue 45 reports a real project whose BINGO observations reproject at 1.55 px so, at 2.9-5.1 px otherwise.)
    # They are fitted as initial brown APs the way a COLMAP camera's distortion is.
    opencv = {k: cam.distortion[name] for k, name in (("k1", "K1"), ("k2", "K2"), ("k3", "K3"), ("p1", "T1"),
                                                      ("p2", "T2")) if cam.distortion[name] != 0.0}
    if opencv:
        from .colmap import colmap_distortion_as_brown
        from ..io.colmap import ColmapCamera
        f_px = cam.focal_mm / p
        colmap = ColmapCamera(0, "PIX4D", cam.width_px, cam.height_px,
                              {"fx": f_px, "fy": f_px, "cx": cam.principal_point_mm[0] / p,
                               "cy": cam.principal_point_mm[1] / p, **opencv})
        initial, misfit_px = colmap_distortion_as_brown(colmap, camera)
        camera = replace(camera, initial_ap=initial)
        carried = " and ".join(w for w, keys in (("radial (R1..R3)", "k"), ("tangential (T1, T2)", "p"))
                               if any(k.startswith(keys) for k in opencv))
        notes.append(f"Pix4D's {carried} distortion is the initial value of the brown APs (largest misfit of "
                     f"the conversion {misfit_px:.3f} px)")
    measurements = params.bingo
    photos = list(measurements.photos)
    image_index = {ph: i for i, ph in enumerate(photos)}
    w, h = cam.width_px, cam.height_px

    def to_pixel(xy_mm, img):
        return np.column_stack([w / 2.0 + xy_mm[:, 0] / p, h / 2.0 - xy_mm[:, 1] / p])

    ids, roles, xyz, sigma, obs_img, obs_pt, pixel = _points_and_observations(
        measurements, control, check_points, control_sigma_m, to_pixel, image_index, notes)
    position, opk = _orientations(params.external, photos, image_index, notes, angles=True)
    block = _assemble(name, crs, {"pix4d": camera}, photos, ["pix4d"] * len(photos), position, opk, ids, roles, xyz,
                      sigma, obs_img, obs_pt, pixel, np.full(len(obs_img), image_sigma_px), image_sigma_px)
    return block, notes


def _opensfm_camera(cam, pixel_size_mm: float):
    """A FrameCamera and the equivalent COLMAP camera (pixels, corner origin) of an OpenSfM camera."""
    from ..io.colmap import ColmapCamera

    w, h, s = cam.width, cam.height, float(max(cam.width, cam.height))
    q = cam.params
    if cam.projection_type == "perspective":
        fx = fy = q["focal"] * s
        cx, cy = w / 2.0, h / 2.0
    else:
        fx, fy = q["focal_x"] * s, q["focal_y"] * s
        cx, cy = w / 2.0 + q["c_x"] * s, h / 2.0 + q["c_y"] * s
    params = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
    params.update({k: q[k] for k in ("k1", "k2", "k3", "p1", "p2") if q.get(k, 0.0) != 0.0})
    colmap = ColmapCamera(0, "OPENSFM_" + cam.projection_type.upper(), w, h, params)
    p = pixel_size_mm
    camera = FrameCamera(camera_key(cam.camera_id), w, h, p, focal_mm=0.5 * (fx + fy) * p,
                         x0_mm=(cx - w / 2.0) * p, y0_mm=(h / 2.0 - cy) * p)
    return camera, colmap


def block_from_opensfm(reconstruction, tracks, pixel_size_mm: float | None = None, image_sigma_px: float = 1.0,
                       name: str = "opensfm") -> tuple[Block, list[str]]:
    """A block (a free network in the reconstruction's frame) from an OpenSfM reconstruction and its tracks.

    Every observation of a reconstructed point (a track id among the reconstruction's points) in a
    reconstructed shot is kept; the others are counted in the notes. Without ``pixel_size_mm``,
    :data:`selfcal.convert.colmap.DEFAULT_PIXEL_SIZE_MM` with a warning.
    """
    from .colmap import colmap_distortion_as_brown, pixel_size_or_default

    notes: list[str] = []
    pixel_size_mm = pixel_size_or_default(pixel_size_mm, "OpenSfM", notes)
    if reconstruction.n_reconstructions > 1:
        notes.append(f"{reconstruction.path} holds {reconstruction.n_reconstructions} reconstructions; the first "
                     f"({len(reconstruction.shot_ids)} shots) is imported")
    cameras, key_of, colmap_of = {}, {}, {}
    for cid in dict.fromkeys(reconstruction.shot_camera):
        camera, colmap = _opensfm_camera(reconstruction.cameras[cid], pixel_size_mm)
        key = camera.camera_id
        while key in cameras:
            key += "_"
        camera = replace(camera, camera_id=key)
        initial, misfit_px = colmap_distortion_as_brown(colmap, camera)
        if initial is not None:
            camera = replace(camera, initial_ap=initial)
            notes.append(f"camera '{cid}' ({reconstruction.cameras[cid].projection_type}): its distortion is the "
                         f"initial value of the brown APs (largest misfit of the conversion {misfit_px:.3f} px)")
        if key != cid:
            notes.append(f"camera '{cid}' is camera '{key}' of the block")
        cameras[key], key_of[cid], colmap_of[cid] = camera, key, colmap
    R = matrix_from_rotation_vector(reconstruction.rotation)               # world -> OpenSfM camera
    centres = -np.einsum("nji,nj->ni", R, reconstruction.translation)
    opk = opk_from_matrix(_FLIP @ R)
    shots = list(reconstruction.shot_ids)
    shot_index = {s: i for i, s in enumerate(shots)}
    point_index = {p: i for i, p in enumerate(reconstruction.point_ids)}
    keep = np.array([i in shot_index and t in point_index for i, t in zip(tracks.image, tracks.track_id)], bool)
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} of {len(keep)} track observations are of points or shots not in the "
                     f"reconstruction: left out")
    img = np.array([shot_index[i] for i in tracks.image[keep]], np.int64)
    pt = np.array([point_index[t] for t in tracks.track_id[keep]], np.int64)
    size = np.array([[reconstruction.cameras[c].width, reconstruction.cameras[c].height]
                     for c in reconstruction.shot_camera], float)
    wh = size[img]
    pixel = tracks.xy_normalized[keep] * wh.max(axis=1, keepdims=True) + wh / 2.0
    pair = img * (len(point_index) + 1) + pt
    _, first = np.unique(pair, return_index=True)
    if len(first) < len(pair):
        notes.append(f"{len(pair) - len(first)} repeated observations of a point in the same shot dropped")
    first = np.sort(first)
    k = len(point_index)
    block = _assemble(name, "local", cameras, shots, [key_of[c] for c in reconstruction.shot_camera], centres, opk,
                      list(reconstruction.point_ids), ["tie"] * k, reconstruction.point_xyz, np.full((k, 3), np.nan),
                      img[first], pt[first], pixel[first], np.full(len(first), image_sigma_px), image_sigma_px,
                      datum="free")
    notes.append("OpenSfM's frame has no control: the block is a free network (datum = \"free\")")
    return block, notes


def block_with_markers(block: Block, markers, reference=None, *, marker_sigma_px: float | None = None,
                       control_sigma_m=(0.01, 0.02), check_points=()) -> tuple[Block, list[str]]:
    """``block`` with Metashape markers added: their image measurements (:class:`selfcal.io.metashape.Markers`,
    pixels as selfcal's) and their coordinates from ``reference`` (a :class:`selfcal.io.patb.ControlPoints`
    read from the reference CSV; markers not in it take the XML's reference, if any). A marker with coordinates
    is a ``gcp`` (``chk`` when its XML reference is disabled, Metashape's check point, or when named in
    ``check_points``); without, a tie point.
    Measurements of cameras the block does not have are a BlockError naming the file and the camera.
    """
    notes: list[str] = []
    if not (block.datum == "free" and not block.has_trajectory):       # a free network has no position of its own
        for control in (reference, markers.reference):
            _check_axes(control, block.images.position_m, block.crs)
    sigma_px = block.image_sigma_px if marker_sigma_px is None else marker_sigma_px
    labels = list(dict.fromkeys(markers.marker))
    image_index = {str(i): k for k, i in enumerate(block.images.image_id)}
    stem_index = {_stem(i): k for k, i in enumerate(block.images.image_id)}
    obs_img = []
    for camera, line in zip(markers.camera, markers.line):
        k = image_index.get(camera, stem_index.get(_stem(camera)))
        if k is None:
            raise BlockError(markers.path, f"camera '{camera}' is not an image of the block "
                                           f"({len(block.images)} images, e.g. {block.images.image_id[0]})",
                             int(line) if line else None)
        obs_img.append(k)
    coords = {}                                             # marker label -> xyz, sigma, enabled
    if markers.reference is not None:
        ref = markers.reference
        for k, label in enumerate(ref.point_id):
            coords[label] = (ref.xyz_m[k], ref.sigma_m[k], ref.enabled[k])
    name_of = {}                                            # marker label -> the reference CSV's label of it
    if reference is not None:
        match = match_labels(reference.point_id, labels, path=reference.path, other_path=markers.path,
                             what="control labels")
        notes.extend(f"warning: {m}" for m in match.messages)
        for k, label in enumerate(reference.point_id):      # the file's coordinates, the project's check state
            marker = match.partner.get(label)
            if marker is None:
                continue
            enabled = coords[marker][2] if marker in coords else reference.enabled[k]
            coords[marker] = (reference.xyz_m[k], reference.sigma_m[k], enabled)
            name_of[marker] = label
    marker_of = {v: k for k, v in name_of.items()}
    checks = {marker_of.get(c, c) for c in check_points}
    unknown = checks - set(coords)
    if unknown:
        raise UsageError(f"--check names marker(s) without reference coordinates: {', '.join(sorted(unknown))}")
    existing = set(block.points.point_id)
    clash = [m for m in labels if name_of.get(m, m) in existing]
    if clash:
        raise BlockError(markers.path, f"marker(s) {', '.join(name_of.get(m, m) for m in clash[:5])} have the name "
                                       f"of a point the block already has", markers.marker_line.get(clash[0]))
    default = np.array([control_sigma_m[0], control_sigma_m[0], control_sigma_m[1]])
    ids, roles, xyz, sigma = [], [], [], []
    for label in labels:
        ids.append(name_of.get(label, label))
        if label in coords:
            c, s, enabled = coords[label]
            roles.append("chk" if label in checks or not enabled else "gcp")
            xyz.append(c)
            sigma.append(np.where(np.isnan(s), default, s))
        else:
            roles.append("tie")
            xyz.append(np.full(3, np.nan))
            sigma.append(np.full(3, np.nan))
            notes.append(f"marker '{label}' has no reference coordinates: a tie point")
    n0 = len(block.points)
    index = {label: n0 + k for k, label in enumerate(labels)}
    pts = block.points
    points = Points(np.concatenate([pts.point_id, np.array(ids, object)]),
                    np.concatenate([pts.role, np.array(roles, object)]),
                    np.vstack([pts.xyz_m, np.array(xyz, float).reshape(-1, 3)]),
                    np.vstack([pts.sigma_m, np.array(sigma, float).reshape(-1, 3)]),
                    np.arange(1, n0 + len(ids) + 1))
    ob = block.observations
    m = len(markers.marker)
    observations = Observations(np.concatenate([ob.image_index, np.array(obs_img, np.int64)]),
                                np.concatenate([ob.point_index, np.array([index[p] for p in markers.marker], np.int64)]),
                                np.vstack([ob.pixel, markers.pixel]),
                                np.concatenate([ob.sigma_px, np.full(m, sigma_px)]),
                                np.arange(1, len(ob) + m + 1))
    n_gcp = int(np.sum(points.role == "gcp"))
    datum = "control" if n_gcp >= 3 or block.has_trajectory else block.datum
    new = replace(block, points=points, observations=observations, datum=datum)
    notes.append(f"added {len(ids)} markers ({roles.count('gcp')} gcp, {roles.count('chk')} chk, "
                 f"{roles.count('tie')} tie) with {m} image measurements (sigma {sigma_px:g} px)")
    return new, notes
