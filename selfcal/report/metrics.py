"""What an adjustment achieved, as plain tables and a summary dictionary.

These are the contents of the results folder (DESIGN.md §4). The functions
compute; :mod:`selfcal.io.results` writes. Conventions:

* RMSD(XY) at check points = sqrt(mean(dX^2 + dY^2)), RMSD(Z) = sqrt(mean(dZ^2)),
  with d = adjusted - reference;
* RMS(sigma_XY) of tie points = sqrt(mean(sigma_X^2 + sigma_Y^2)), a-posteriori;
* GSD = mean over images of pixel_size · (Z0 - mean height of the image's points) / c;
* image residuals v = adjusted - observed, in pixels along the photo axes (x right, y up).
"""
from __future__ import annotations

import numpy as np

from ..sensors.frame import photo_from_pixel
from ..stats.correlation import max_abs_correlation_by_group

__all__ = ["ground_sample_distance", "summary", "camera_json", "image_table", "point_table",
           "residual_table", "distortion_grid_table", "result_files"]


def ground_sample_distance(block, result) -> float:
    """Mean ground sample distance of the block in metres."""
    prob, st = result.problem, result.state
    heights = np.bincount(prob.obs_image, weights=st.points[prob.obs_point, 2], minlength=prob.n_images)
    heights /= np.maximum(np.bincount(prob.obs_image, minlength=prob.n_images), 1)
    gsd = []
    for i in range(prob.n_images):
        cam = prob.cameras[prob.image_camera[i]]
        c = st.cameras[prob.image_camera[i]][0]
        gsd.append(cam.pixel_size_mm * (st.eop[i, 2] - heights[i]) / c)
    return float(np.mean(np.abs(gsd)))


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values))) if values.size else None


def summary(block, result, extra: dict | None = None) -> dict:
    """summary.json of DESIGN.md §4."""
    pts = block.points
    st = result.state
    diff = st.points - pts.xyz_m
    chk = pts.role == "chk"
    gcp = pts.role == "gcp"
    tie = pts.role == "tie"
    cov = result.point_covariance()
    var = np.einsum("nii->ni", cov)
    gsd = ground_sample_distance(block, result)
    rmsd_xy = _rms(np.sum(diff[chk, :2] ** 2, axis=1))
    rmsd_z = _rms(diff[chk, 2] ** 2)
    sig_xy = _rms(var[tie, 0] + var[tie, 1])
    sig_z = _rms(var[tie, 2])
    n_ap_initial = int(sum(c.ap.n_params for c in result.problem.cameras))
    n_ap_active = int(sum(int(c.free[3:].sum()) for c in result.problem.cameras))
    v = result.residuals_mm / np.array([c.pixel_size_mm for c in result.problem.cameras])[
        result.problem.image_camera[block.observations.image_index]][:, None]

    def gsd_of(x):
        return None if x is None else x / gsd

    out = {
        "block": block.name,
        "ap_model": result.problem.cameras[0].ap.spec if result.problem.cameras else "none",
        "converged": bool(result.converged),
        "convergence": result.reason,
        "iterations": int(result.iterations),
        "sigma0_px": result.sigma0_px,
        "variance_factor": result.variance_factor,
        "redundancy": int(result.redundancy),
        "n_observations": int(result.n_observations),
        "n_unknowns": int(result.n_unknowns),
        "gsd_m": gsd,
        "rmsd_chk_xy_m": rmsd_xy,
        "rmsd_chk_z_m": rmsd_z,
        "rmsd_chk_xy_gsd": gsd_of(rmsd_xy),
        "rmsd_chk_z_gsd": gsd_of(rmsd_z),
        "rms_gcp_residual_xy_m": _rms(np.sum(diff[gcp, :2] ** 2, axis=1)),
        "rms_gcp_residual_z_m": _rms(diff[gcp, 2] ** 2),
        "rms_sigma_tie_xy_m": sig_xy,
        "rms_sigma_tie_z_m": sig_z,
        "rms_sigma_tie_xy_gsd": gsd_of(sig_xy),
        "rms_sigma_tie_z_gsd": gsd_of(sig_z),
        "rms_image_residual_px": float(np.sqrt(np.mean(np.sum(v * v, axis=1)))),
        "n_images": int(len(block.images)),
        "n_tie_points": int(tie.sum()),
        "n_image_observations": int(len(block.observations)),
        "n_gcp_used": int(gcp.sum()),
        "n_chk_used": int(chk.sum()),
        "n_obs_rejected": 0,
        "n_ap_initial": n_ap_initial,
        "n_ap_significant": n_ap_active,
        "max_abs_corr": max_abs_correlation_by_group(result.problem, result.Q_theta),
        "dropped": block.dropped.as_dict(),
        "warnings": list(block.dropped.messages),
        "notes": list(result.notes),
        "seconds": result.seconds,
    }
    if extra:
        out.update(extra)
    return out


def camera_json(block, result) -> dict:
    """camera.json: interior orientation and AP coefficients with sigma."""
    sigmas = result.camera_sigma()
    cameras = {}
    for cam, values, sigma in zip(result.problem.cameras, result.state.cameras, sigmas):
        cfg = block.cameras[cam.camera_id]
        def entry(i):
            return {"value": float(values[i]), "sigma": None if np.isnan(sigma[i]) else float(sigma[i]),
                    "estimated": bool(cam.free[i])}
        coefficients = [
            {"name": name, "value_px": float(values[3 + k]),
             "sigma_px": None if np.isnan(sigma[3 + k]) else float(sigma[3 + k]),
             "active": bool(cam.free[3 + k])}
            for k, name in enumerate(cam.ap.parameter_names)
        ]
        cameras[cam.camera_id] = {
            "model": "frame",
            "width_px": cfg.width_px,
            "height_px": cfg.height_px,
            "pixel_size_mm": cfg.pixel_size_mm,
            "focal_mm": entry(0),
            "x0_mm": entry(1),
            "y0_mm": entry(2),
            "ap": {**cam.ap.to_dict(), "coefficient_unit": "px", "coefficients": coefficients},
        }
    return {"cameras": cameras}


def image_table(block, result):
    im = block.images
    eop = result.state.eop.copy()
    eop[:, 3:] = (eop[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    s = result.eop_sigma()
    header = ["image_id", "camera_id", "strip_id", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg",
              "sigma_X0_m", "sigma_Y0_m", "sigma_Z0_m", "sigma_omega_deg", "sigma_phi_deg", "sigma_kappa_deg",
              "n_points"]
    n_points = np.bincount(block.observations.image_index, minlength=len(im))
    cols = [im.image_id, im.camera_id, im.strip_id, *eop[:, :3].T, *np.degrees(eop[:, 3:]).T,
            *s[:, :3].T, *np.degrees(s[:, 3:]).T, n_points]
    fmts = ["", "", ""] + [".4f"] * 3 + [".6f"] * 3 + [".4f"] * 3 + [".6f"] * 3 + ["d"]
    return header, cols, fmts


def point_table(block, result):
    pts = block.points
    xyz = result.state.points
    sd = np.sqrt(np.einsum("nii->ni", result.point_covariance()))
    diff = np.where((pts.role != "tie")[:, None], xyz - pts.xyz_m, np.nan)
    n_images = np.bincount(block.observations.point_index, minlength=len(pts))
    header = ["point_id", "role", "X", "Y", "Z", "sigma_X_m", "sigma_Y_m", "sigma_Z_m", "n_images",
              "dX_m", "dY_m", "dZ_m"]
    cols = [pts.point_id, pts.role, *xyz.T, *sd.T, n_images, *diff.T]
    fmts = ["", ""] + [".4f"] * 3 + [".5f"] * 3 + ["d"] + [".4f"] * 3
    return header, cols, fmts


def residual_table(block, result, w_test=None, rejected=None):
    ob = block.observations
    pix = np.array([c.pixel_size_mm for c in result.problem.cameras])[result.problem.image_camera[ob.image_index]]
    v = result.residuals_mm / pix[:, None]
    w = np.full(len(ob), np.nan) if w_test is None else w_test
    rej = np.zeros(len(ob), int) if rejected is None else rejected.astype(int)
    header = ["image_id", "point_id", "vx_px", "vy_px", "w_test", "rejected"]
    cols = [block.images.image_id[ob.image_index], block.points.point_id[ob.point_index], v[:, 0], v[:, 1], w, rej]
    return header, cols, ["", "", ".4f", ".4f", ".3f", "d"]


def distortion_grid_table(block, result, nodes_x: int = 61):
    """Estimated Delta in pixels on a regular grid over each camera's frame.

    The grid has ``nodes_x`` nodes across and as many down as keep the cells
    square (41 for a 3:2 frame). ``dcol``, ``drow`` follow the pixel axes.
    """
    multi = len(result.problem.cameras) > 1
    cols_out = {k: [] for k in ("camera_id", "col", "row", "dcol", "drow")}
    for cam, values in zip(result.problem.cameras, result.state.cameras):
        cfg = block.cameras[cam.camera_id]
        nodes_y = int(round((nodes_x - 1) * cfg.height_px / cfg.width_px)) + 1
        col, row = np.meshgrid(np.linspace(0, cfg.width_px, nodes_x), np.linspace(0, cfg.height_px, nodes_y))
        col, row = col.ravel(), row.ravel()
        xy = photo_from_pixel(np.column_stack([col, row]), cfg.width_px, cfg.height_px, cfg.pixel_size_mm)
        dx, dy = cam.ap.displacement_px(xy[:, 0], xy[:, 1], values[3:] * cam.free[3:])
        cols_out["camera_id"].append(np.full(col.size, cam.camera_id, dtype=object))
        cols_out["col"].append(col)
        cols_out["row"].append(row)
        cols_out["dcol"].append(dx)
        cols_out["drow"].append(-dy)
    header = (["camera_id"] if multi else []) + ["col", "row", "dcol", "drow"]
    cols = [np.concatenate(cols_out[h]) for h in header]
    fmts = ([""] if multi else []) + [".2f", ".2f", ".5f", ".5f"]
    return header, cols, fmts


def result_files(block, result, summary_extra: dict | None = None, w_test=None, rejected=None) -> dict:
    """Every file of the results folder as data: dicts become JSON, tuples CSV."""
    return {
        "summary.json": summary(block, result, summary_extra),
        "camera.json": camera_json(block, result),
        "images.csv": image_table(block, result),
        "points.csv": point_table(block, result),
        "residuals.csv": residual_table(block, result, w_test, rejected),
        "distortion_grid.csv": distortion_grid_table(block, result),
    }
