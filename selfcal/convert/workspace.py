"""A results folder as a COLMAP dense workspace's sparse model: the inverse of the COLMAP import's conventions
(R = F M, t = -R (C - origin) with F = diag(1, -1, -1)), a PINHOLE camera of the ideal (undistorted) image, and the
observations moved to their ideal positions, measured - Delta(measured), as the adjustment itself computes them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.rotation import matrix_from_opk, quaternion_from_matrix
from ..sensors.frame import pixel_from_photo, project
from .colmap import FLIP

if TYPE_CHECKING:
    from ..io.colmap import ColmapModel

WORKSPACE_ROLES = ("tie", "gcp")


@dataclass
class ColmapWorkspace:
    """A COLMAP sparse model of the ideal images, and what ties it back to selfcal's results."""

    model: ColmapModel
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
    from ..io.colmap import ColmapCamera, ColmapModel

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
    R = FLIP @ M
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
