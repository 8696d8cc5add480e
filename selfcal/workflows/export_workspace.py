"""A COLMAP dense workspace of a results folder (``selfcal export colmap-workspace``), laid out as
``colmap image_undistorter`` writes it::

    WS/images/NAME              each image found, resampled to the ideal camera (exact for every AP model:
                                selfcal.calibration.undistortion_maps), same name and format
    WS/sparse/cameras.bin       one PINHOLE camera per frame camera: fx = fy = principal distance, principal point
    WS/sparse/images.bin        adjusted poses (world to camera) and the kept observations, undistorted
    WS/sparse/points3D.bin      adjusted tie and control points seen in two or more exported images, with tracks;
                                colour: bilinear in the undistorted images at the point's 2-D points, mean over
                                its images (grey 128 where none lies inside its image)
    WS/sparse/selfcal_origin.json   object coordinates = model coordinates + origin_m (and the CRS, when the
                                results name it); COLMAP camera ids -> selfcal camera ids
    WS/sparse/selfcal_points.csv    point3D_id,point_id,role: the selfcal id of each 3-D point
    WS/stereo/patch-match.cfg, fusion.cfg, depth_maps/, normal_maps/, consistency_graphs/
    WS/database.db              for ``colmap point_triangulator``: the cameras, images (same ids and names), each
                                image's 2-D points as keypoints and, per image pair, one verified match per
                                3-D point both see
    WS/sparse/triangulator_input/   cameras, images (poses, no 2-D points) and no 3-D points: its --input_path

    colmap point_triangulator --database_path WS/database.db --image_path WS/images \
        --input_path WS/sparse/triangulator_input --output_path OUT

(COLMAP keeps only image pairs with at least ``--Mapper.min_num_matches`` matches, 15 by default.)

The observations and tracks come from the results folder alone: residuals.csv holds every image measurement
(col_px, row_px) and whether the adjustment rejected it; only kept ones are written. Pixel convention:
COLMAP's and selfcal's are the same (the upper-left corner of the first pixel at (0, 0)).
"""
from __future__ import annotations

import os
from typing import Callable

import numpy as np

from ..calibration import Calibration, undistort_image, undistortion_maps
from ..convert import FALLBACK_GREY, PointColours, RollingShutters, colmap_workspace, keypoints_and_matches
from ..errors import BlockError
from ..io.colmap_workspace import find_images, write_workspace
from ..io.images import check_file_name, read_image
from ..io.results import read_results

__all__ = ["export_workspace", "rolling_shutters"]


def export_workspace(results_folder: str, cams: dict[str, Calibration], images_folder: str, out: str,
                     say: Callable[[str], None] = lambda text: None,
                     maps: Callable = undistortion_maps) -> dict:
    """Write the workspace ``out`` (atomically) for the frame cameras ``cams`` of ``results_folder`` and the images
    of ``images_folder``; ``say`` receives the notes, warnings and progress lines; ``maps(calibration)`` gives the
    undistortion maps. Returns the counts (images, points, observations, points left grey), the origin and the mean error."""
    results = read_results(results_folder)
    images, residuals = results.tables["images"], results.tables["residuals"]
    frame_images = [i for i, c in zip(images["image_id"], images["camera_id"]) if c in cams]
    others = len(images["image_id"]) - len(frame_images)
    if others:
        say(f"note: {others} image(s) of cameras that are not frame cameras are left out")
    found, strangers = find_images(images_folder, frame_images)
    if not found:
        raise BlockError(images_folder, f"none of the block's {len(frame_images)} images is here (looked for "
                                        f"e.g. '{frame_images[0]}' or '{frame_images[0]}.*')" if frame_images
                         else "the results hold no frame image")
    missing = [i for i in frame_images if i not in found]
    if missing:
        say(f"warning: {len(missing)} of the block's {len(frame_images)} images are not in {images_folder} "
            f"(e.g. {missing[0]}): left out of the workspace (poses, 2-D points and tracks)")
    if strangers:
        say(f"note: {len(strangers)} file(s) in {images_folder} are not images of the block and are ignored "
            f"(e.g. {strangers[0]})")
    rolling = rolling_shutters(results, cams)
    if rolling is not None:
        say(f"warning: camera(s) {', '.join(rolling.readout_ms)} have a rolling shutter: the poses are those of the "
            f"images' middle lines and the 2-D points are moved to where the middle line would have seen their "
            f"adjusted points (each line's own pose from rolling_shutter.csv); the images themselves are only "
            f"undistorted, not resampled line by line: a dense matcher sees their shear (up to "
            f"{rolling.largest_shear_px:.1f} px between the first and the last line)")
    ws = colmap_workspace(cams, images, results.tables["points"], residuals, found, rolling=rolling)
    model = ws.model
    unoriented = len(found) - len(model.image_ids)
    if unoriented:
        say(f"note: {unoriented} of the images found have no adjusted orientation in images.csv and are left out")
    if ws.n_points_short_track:
        say(f"note: {ws.n_points_short_track} point(s) seen in fewer than two of the exported images are left out")
    names = list(model.image_names)
    for name in names:                  # before any work: OpenCV never sees a name that is not UTF-8
        check_file_name(os.path.join(images_folder, name))

    def undistorted():
        """(name, pixels) of each image resampled to its ideal camera, one at a time, camera by camera."""
        for colmap_id, camera_id in ws.camera_id.items():
            cal = cams[camera_id]
            try:
                map_x, map_y, _ = maps(cal)
            except ArithmeticError as exc:          # a distortion that folds over inside the frame
                raise BlockError(os.path.join(results_folder, "camera.json"), str(exc)) from None
            for k in np.flatnonzero(model.image_camera == colmap_id):
                image_id, name = ws.image_id[k], names[k]
                path = os.path.join(images_folder, name)
                image = read_image(path)
                if image.shape[:2] != (cal.height_px, cal.width_px):
                    raise BlockError(path, f"is {image.shape[1]} x {image.shape[0]} px, camera {camera_id} of image "
                                           f"{image_id} is {cal.width_px} x {cal.height_px} px")
                ideal = undistort_image(image, map_x, map_y)
                colours.add(int(model.image_ids[k]), ideal)
                yield name, ideal
                say(f"[{k + 1}/{len(names)}] {name}")
        model.point_rgb, grey = colours.rgb()       # all images taken: the model is written after them
        counts["grey_points"] = grey
        say(f"colours: {len(model.point_ids) - grey} point(s) from the undistorted images (bilinear at their 2-D "
            f"points, mean over the images), {grey} grey ({FALLBACK_GREY}: no 2-D point inside an image)")

    colours = PointColours(model)
    counts = {"grey_points": 0}
    origin = {
        "origin_m": ws.origin_m,
        "crs": results.summary.get("crs"),
        "meaning": "object coordinates (the results' CRS) = COLMAP model coordinates + origin_m; same axes and scale",
        "results": os.path.abspath(results_folder),
        "ap_model": results.summary.get("ap_model"),
        "cameras": {str(k): c for k, c in ws.camera_id.items()}}
    write_workspace(out, model, undistorted(), origin, zip(model.point_ids.tolist(), ws.point_id, ws.point_role),
                    keypoints_and_matches(model))
    rms = float(np.sqrt(np.mean(model.point_error ** 2))) if len(model.point_error) else float("nan")
    return {"images": len(names), "points": len(model.point_ids), "observations": len(model.obs_point),
            "origin_m": ws.origin_m, "mean_error_px": rms, "grey_points": counts["grey_points"]}


def rolling_shutters(results, cams: dict) -> RollingShutters | None:
    """The rolling shutters of the cameras ``cams`` of a results folder (camera.json's ``shutter``, ``readout_ms``
    and rolling_shutter.csv), or None where none has one. The velocities and rates are those the adjustment used."""
    entries = results.camera.get("cameras", {})
    rolling = {c: e for c, e in entries.items() if c in cams and e.get("shutter") == "rolling"}
    if not rolling:
        return None
    table = results.tables.get("rolling_shutter")
    if table is None:
        raise BlockError(os.path.join(results.path or "", "rolling_shutter.csv"),
                         "missing: camera.json has rolling-shutter cameras, and their images' velocities are here")
    ids = table["image_id"]
    velocity = np.column_stack([table["vx_m_s"], table["vy_m_s"], table["vz_m_s"]])
    rate = np.radians(np.column_stack([table[f"{a}_rate_deg_s"] for a in ("omega", "phi", "kappa")]))
    shutters = RollingShutters({c: float(e["readout_ms"]["value"]) for c, e in rolling.items()},
                               {c: e.get("readout_direction", "down") for c, e in rolling.items()},
                               dict(zip(ids, velocity)), dict(zip(ids, rate)))
    shear = np.hypot(table["shear_col_px"], table["shear_row_px"])
    shutters.largest_shear_px = float(np.nanmax(shear)) if len(shear) else 0.0
    return shutters
