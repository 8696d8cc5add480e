"""Does COLMAP see the exported dense workspace as selfcal adjusted it?

pycolmap (COLMAP's own reader and camera model) reprojects every 3-D point of WS/sparse into every image of
its track; each projection is compared with selfcal's projection of the adjusted point (collinearity without
Delta, from RESULTS' images.csv, points.csv and camera.json, in the results' CRS) and with the workspace's
2-D point plus selfcal's residual v (RESULTS/residuals.csv). Prints the RMS and the largest difference in
pixels; exits 1 if the largest exceeds 0.05 px.

Run: python examples/copr/check_workspace.py RESULTS WS
"""
from __future__ import annotations

import csv
import json
import os
import sys

import numpy as np
import pycolmap

from selfcal.io.results import read_results
from selfcal.sensors.frame import pixel_from_photo, project

#: the acceptance bound of issue 23 (px)
BOUND_PX = 0.05


def main() -> int:
    results, ws = sys.argv[1], sys.argv[2]
    r = read_results(results)
    rec = pycolmap.Reconstruction(os.path.join(ws, "sparse"))
    with open(os.path.join(ws, "sparse", "selfcal_origin.json"), encoding="utf-8") as handle:
        meta = json.load(handle)
    with open(os.path.join(ws, "sparse", "selfcal_points.csv"), newline="", encoding="utf-8") as handle:
        point_of = {int(row["point3D_id"]): row["point_id"] for row in csv.DictReader(handle)}
    im, pt, res = r.tables["images"], r.tables["points"], r.tables["residuals"]
    image_row = {i: k for k, i in enumerate(im["image_id"])}
    point_row = {p: k for k, p in enumerate(pt["point_id"])}
    v_of = {(i, p): (vx, -vy) for i, p, vx, vy in zip(res["image_id"], res["point_id"], res["vx_px"], res["vy_px"])}
    cameras = r.camera["cameras"]

    def image_id(name):
        return name if name in image_row else os.path.splitext(name)[0]

    colmap_px, ideal_px, v, rows_i, rows_p, cams = [], [], [], [], [], []
    for point3d_id, point in rec.points3D.items():
        for el in point.track.elements:
            image = rec.images[el.image_id]
            colmap_px.append(rec.cameras[image.camera_id].img_from_cam(image.cam_from_world() * point.xyz))
            ideal_px.append(image.points2D[el.point2D_idx].xy)
            iid, pid = image_id(image.name), point_of[point3d_id]
            v.append(v_of[(iid, pid)])
            rows_i.append(image_row[iid])
            rows_p.append(point_row[pid])
            cams.append(meta["cameras"][str(image.camera_id)])
    colmap_px, ideal_px, v = np.array(colmap_px), np.array(ideal_px), np.array(v)
    ii, pp = np.array(rows_i), np.array(rows_p)
    selfcal_px = np.empty_like(colmap_px)
    for camera_id in set(cams):
        cam = cameras[camera_id]
        k = np.flatnonzero(np.array(cams) == camera_id)
        eop = np.column_stack([im["X0"][ii[k]], im["Y0"][ii[k]], im["Z0"][ii[k]],
                               np.radians(np.column_stack([im["omega_deg"][ii[k]], im["phi_deg"][ii[k]],
                                                           im["kappa_deg"][ii[k]]]))])
        xyz = np.column_stack([pt["X"][pp[k]], pt["Y"][pp[k]], pt["Z"][pp[k]]])
        photo = project(xyz, eop, np.array([cam["focal_mm"]["value"], cam["x0_mm"]["value"], cam["y0_mm"]["value"]]))
        selfcal_px[k] = pixel_from_photo(photo, cam["width_px"], cam["height_px"], cam["pixel_size_mm"])
    miss = np.hypot(*(colmap_px - selfcal_px).T)
    via_v = np.hypot(*(ideal_px + v - selfcal_px).T)
    print(f"workspace {ws}: {len(rec.images)} images, {len(rec.points3D)} points, {len(miss)} observations; "
          f"origin {meta['origin_m']} m in {meta['crs']}")
    print(f"pycolmap projection - selfcal projection: RMS {np.sqrt(np.mean(miss ** 2)):.2e} px, "
          f"max {miss.max():.2e} px (bound {BOUND_PX} px)")
    print(f"2-D point + selfcal residual - selfcal projection: RMS {np.sqrt(np.mean(via_v ** 2)):.2e} px, "
          f"max {via_v.max():.2e} px (residuals.csv rounds v to 1e-4 px, col/row to 1e-3 px)")
    print(f"pycolmap's mean reprojection error of the 2-D points: {rec.compute_mean_reprojection_error():.3f} px")
    return 0 if miss.max() <= BOUND_PX else 1


if __name__ == "__main__":
    sys.exit(main())
