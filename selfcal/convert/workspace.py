"""A results folder as a COLMAP dense workspace's sparse model: the inverse of the COLMAP import's conventions
(R = F M, t = -R (C - origin) with F = diag(1, -1, -1)), a PINHOLE camera of the ideal (undistorted) image, and the
observations moved to their ideal positions, measured - Delta(adjusted): the correction where the adjustment evaluated
it, at the adjusted image coordinates (residuals.csv's measured + v).
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
                     min_track: int = 2, rolling: RollingShutters | None = None) -> ColmapWorkspace:
    """The COLMAP sparse model of the ideal images of a results folder.

    Parameters
    ----------
    calibrations : camera id -> :class:`selfcal.calibration.Calibration` (frame cameras)
    images, points, residuals : columns of images.csv, points.csv, residuals.csv (DESIGN.md §4)
    image_names : image id -> file name in the workspace; only these images are exported (images of other
        cameras than ``calibrations`` must not be given)
    min_track : 3-D points seen in fewer exported images are left out
    rolling : the rolling shutters of the cameras that have one (:class:`RollingShutters`): their 2-D points are
        moved to where the image's middle line, whose pose the model has, would have seen the adjusted point

    The model has one PINHOLE camera per frame camera: fx = fy = the principal
    distance in pixels and the principal point, the ideal camera of
    :func:`selfcal.calibration.undistortion_maps` in COLMAP's pixel convention
    (that of selfcal: the first pixel's centre at (0.5, 0.5)). Poses are
    world-to-camera, x_cam = R X + t with R = F M, F = diag(1, -1, -1) (COLMAP
    looks along +z with y down, selfcal along -z with y up) and t = -R (C - origin).
    The 3-D points are the adjusted tie and control points minus ``origin_m``
    (their centroid rounded to whole metres); the 2-D points the
    observations that the adjustment kept (``rejected`` 0), each at its ideal
    position measured - Delta(adjusted), the correction where the adjustment
    evaluated it (at the adjusted image coordinates); a point's error is the mean distance
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
    # the adjusted image coordinates (v = adjusted - measured along the photo axes, y up), where the adjustment
    # evaluated the APs' correction (DESIGN-NOTES "Honest precision")
    adjusted = measured + np.column_stack([residuals["vx_px"], -np.asarray(residuals["vy_px"], float)])[use]

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
        ideal[rows] = measured[rows] - cal.delta_px(adjusted[rows])
        iop = np.array([cal.focal_mm, cal.x0_mm, cal.y0_mm])
        photo = project(xyz[o_pt[rows]], eop[o_img[rows]], iop)
        projected[rows] = pixel_from_photo(photo, cal.width_px, cal.height_px, cal.pixel_size_mm)
        if rolling is not None and c in rolling.readout_ms:
            ideal[rows] += projected[rows] - rolling.line_pixels(c, cal, img_ids[o_img[rows]], measured[rows],
                                                                 xyz[o_pt[rows]], eop[o_img[rows]], iop)
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


@dataclass
class RollingShutters:
    """The rolling shutters of a results folder: each rolling camera's ``readout_ms`` and ``direction``
    (camera.json), each image's velocity (m/s) and attitude rate (rad/s) from rolling_shutter.csv."""

    readout_ms: dict                # camera id -> readout (ms)
    direction: dict                 # camera id -> readout direction
    velocity: dict                  # image id -> (3,) m/s
    rate: dict                      # image id -> (3,) rad/s
    largest_shear_px: float = 0.0   # the largest image motion between an image's first and last line

    def line_pixels(self, camera_id: str, cal, image_ids: np.ndarray, measured: np.ndarray, points: np.ndarray,
                    eop: np.ndarray, iop: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) where the lines of the ``measured`` points saw the ``points``: the collinearity at the
        time of the line (:mod:`selfcal.sensors.rolling`), without the lens."""
        from ..sensors.rolling import line_share
        dt = line_share(measured, cal.width_px, cal.height_px, self.direction[camera_id]) * \
            self.readout_ms[camera_id] / 1000.0
        zero = np.zeros(3)
        velocity = np.array([self.velocity.get(i, zero) for i in image_ids]).reshape(-1, 3)
        rate = np.array([self.rate.get(i, zero) for i in image_ids]).reshape(-1, 3)
        moved = eop + np.column_stack([velocity, rate]) * dt[:, None]
        return pixel_from_photo(project(points, moved, iop), cal.width_px, cal.height_px, cal.pixel_size_mm)


#: the colour of a 3-D point that no 2-D point inside an undistorted image sees (COLMAP's own default grey)
FALLBACK_GREY = 128


def image_rgb_at(image: np.ndarray, xy_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear RGB (0..255, float) of ``image`` (as OpenCV holds it: grey, BGR or BGRA) at the pixel positions
    ``xy_px`` (m x 2, selfcal's and COLMAP's convention: the first pixel's centre at (0.5, 0.5)), and whether each
    position lies within the pixel centres (the four neighbours all inside the image; else its colour is 0).

    8-bit images are taken as they are, other integer depths scaled by 255 / their largest value, floating-point
    images as 0..1 (clipped)."""
    pixels = np.asarray(image)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None][:, :, [0, 0, 0]]
    elif pixels.shape[2] == 1:
        pixels = pixels[:, :, [0, 0, 0]]
    else:
        pixels = pixels[:, :, [2, 1, 0]]                    # BGR(A) -> RGB
    if pixels.dtype == np.uint8:
        scale = 1.0
    elif np.issubdtype(pixels.dtype, np.integer):
        scale = 255.0 / np.iinfo(pixels.dtype).max
    else:
        scale = 255.0
    height, width = pixels.shape[:2]
    xy = np.asarray(xy_px, float).reshape(-1, 2) - 0.5     # array coordinates (pixel centres at integers)
    inside = (np.isfinite(xy).all(axis=1) & (xy[:, 0] >= 0) & (xy[:, 0] <= width - 1)
              & (xy[:, 1] >= 0) & (xy[:, 1] <= height - 1))
    rgb = np.zeros((len(xy), 3))
    if not inside.any():
        return rgb, inside
    col, row = xy[inside, 0], xy[inside, 1]
    c0 = np.minimum(np.floor(col).astype(np.int64), max(width - 2, 0))
    r0 = np.minimum(np.floor(row).astype(np.int64), max(height - 2, 0))
    c1, r1 = np.minimum(c0 + 1, width - 1), np.minimum(r0 + 1, height - 1)
    fc, fr = (col - c0)[:, None], (row - r0)[:, None]
    value = ((1 - fr) * ((1 - fc) * pixels[r0, c0] + fc * pixels[r0, c1])
             + fr * ((1 - fc) * pixels[r1, c0] + fc * pixels[r1, c1])) * scale
    if not np.issubdtype(pixels.dtype, np.integer):
        value = np.clip(value, 0.0, 255.0)
    rgb[inside] = value
    return rgb, inside


class PointColours:
    """The colour of each 3-D point of a sparse model: the mean, over the images whose 2-D points see it, of the
    bilinear colour of the (undistorted) image at those 2-D points; :data:`FALLBACK_GREY` where no 2-D point
    of the point lies inside its image. Images are added one at a time (:meth:`add`)."""

    def __init__(self, model: ColmapModel):
        self.model = model
        self.point_index = {int(p): k for k, p in enumerate(model.point_ids)}
        self.obs_index = np.array([self.point_index.get(int(p), -1) for p in model.obs_point], np.int64)
        self.total = np.zeros((len(model.point_ids), 3))
        self.count = np.zeros(len(model.point_ids), np.int64)

    def add(self, image_id: int, image: np.ndarray) -> None:
        """Sample ``image`` (the model's image ``image_id``) at its 2-D points."""
        rows = np.flatnonzero((np.asarray(self.model.obs_image) == image_id) & (self.obs_index >= 0))
        rgb, inside = image_rgb_at(image, self.model.obs_xy[rows])
        np.add.at(self.total, self.obs_index[rows[inside]], rgb[inside])
        np.add.at(self.count, self.obs_index[rows[inside]], 1)

    def rgb(self) -> tuple[np.ndarray, int]:
        """(k x 3) uint8 colours of the model's points, and how many of them are the fallback grey."""
        seen = self.count > 0
        out = np.full((len(self.count), 3), FALLBACK_GREY, np.uint8)
        out[seen] = np.clip(np.round(self.total[seen] / self.count[seen, None]), 0, 255).astype(np.uint8)
        return out, int(np.sum(~seen))


def keypoints_and_matches(model: ColmapModel) -> tuple[dict[int, np.ndarray], dict[tuple[int, int], np.ndarray]]:
    """The feature data of a COLMAP database that gives ``model``'s tracks back: each image's keypoints (its
    2-D points, n x 2, in the order of the model's ``obs_*``, which is the order of :func:`selfcal.io.colmap.write_colmap_bin`'s
    POINT2D_IDX) and, for each pair of images (id1 < id2) that see common 3-D points, the matches (k x 2
    keypoint indices in image 1 and image 2): one per 3-D point seen in both (the first 2-D point in each
    image when an image sees a point twice)."""
    obs_image = np.asarray(model.obs_image, np.int64)
    obs_point = np.asarray(model.obs_point, np.int64)
    order = np.argsort(obs_image, kind="stable")
    index_in_image = np.empty(len(obs_image), np.int64)
    keypoints = {}
    for image_id in model.image_ids:
        lo, hi = np.searchsorted(obs_image[order], [image_id, image_id + 1])
        rows = order[lo:hi]
        index_in_image[rows] = np.arange(len(rows))
        keypoints[int(image_id)] = np.asarray(model.obs_xy, float)[rows].reshape(-1, 2)
    first: dict[int, dict[int, int]] = {}          # image id -> point id -> keypoint index
    for image_id, point_id, idx in zip(obs_image.tolist(), obs_point.tolist(), index_in_image.tolist()):
        first.setdefault(image_id, {}).setdefault(point_id, idx)
    matches = {}
    ids = sorted(first)
    for a, id1 in enumerate(ids):
        for id2 in ids[a + 1:]:
            common = sorted(set(first[id1]) & set(first[id2]))
            if common:
                matches[(id1, id2)] = np.array([[first[id1][p], first[id2][p]] for p in common], np.int64)
    return keypoints, matches
