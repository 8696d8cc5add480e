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

from ..ap import frame_nodes_mm
from ..sensors.frame import pixel_from_photo
from ..stats.accuracy import ce90, le90
from ..stats.correlation import max_abs_correlation_by_group

__all__ = ["ground_sample_distance", "model_choice_table", "summary", "camera_json", "image_table", "point_table",
           "residual_table", "screening_json", "correlation_table", "distortion_grid_table", "trajectory_table",
           "result_files"]


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


def summary(tested, extra: dict | None = None) -> dict:
    """summary.json of DESIGN.md §4 for a (tested) adjustment."""
    result = tested.result
    block = result.block
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
        "ce90_chk_m": ce90(diff[chk, :2]),
        "le90_chk_m": le90(diff[chk, 2]),
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
        "n_obs_rejected": int(len(tested.rejected_rows)),
        "n_ap_initial": int(tested.n_ap_initial),
        "n_ap_significant": int(tested.n_ap_significant),
        "mean_redundancy_image": float(np.mean(tested.tests.image_redundancy)),
        "snooping": {"critical": tested.tests.critical, "delta0": tested.tests.delta0,
                     "rounds": [vars(r) for r in tested.rounds]},
        "max_abs_corr": max_abs_correlation_by_group(result.problem, result.Q_theta),
        "variance_components": None if tested.variance_components is None else {
            "converged": tested.variance_converged,
            "groups": [c.as_dict() for c in tested.variance_components]},
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
        ap = {**cam.ap.to_dict(), "coefficient_unit": "px", "n_active": int(cam.free[3:].sum())}
        if hasattr(cam.ap, "active_ranges"):
            # the translation ranges that remain after screening (Table 3 of seed 000)
            ap["active_ranges"] = cam.ap.active_ranges(cam.free[3:])
        cameras[cam.camera_id] = {
            "model": "frame",
            "width_px": cfg.width_px,
            "height_px": cfg.height_px,
            "pixel_size_mm": cfg.pixel_size_mm,
            "focal_mm": entry(0),
            "x0_mm": entry(1),
            "y0_mm": entry(2),
            "ap": {**ap, "coefficients": coefficients},
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


def point_table(block, result, tests=None):
    """points.csv: adjusted points with sigma; for control and check points d = adjusted - reference.

    For weighted control points, ``w_X, w_Y, w_Z`` are Baarda's w of the control
    coordinates (``tests``, :func:`selfcal.stats.observation_tests`); empty elsewhere.
    """
    pts = block.points
    xyz = result.state.points
    sd = np.sqrt(np.einsum("nii->ni", result.point_covariance()))
    diff = np.where((pts.role != "tie")[:, None], xyz - pts.xyz_m, np.nan)
    n_images = np.bincount(block.observations.point_index, minlength=len(pts))
    w = np.full((len(pts), 3), np.nan)
    if tests is not None:
        w[result.problem.control_index] = tests.control_w
    header = ["point_id", "role", "X", "Y", "Z", "sigma_X_m", "sigma_Y_m", "sigma_Z_m", "n_images",
              "dX_m", "dY_m", "dZ_m", "w_X", "w_Y", "w_Z"]
    cols = [pts.point_id, pts.role, *xyz.T, *sd.T, n_images, *diff.T, *w.T]
    fmts = ["", ""] + [".4f"] * 3 + [".5f"] * 3 + ["d"] + [".4f"] * 3 + [".3f"] * 3
    return header, cols, fmts


def residual_table(block_read, tested):
    """residuals.csv: every observation of the block as read, rejected ones included.

    v = adjusted - observed in pixels along the photo axes; w, redundancy numbers,
    minimal detectable blunder (px) and Baarda's external reliability factor per
    coordinate. For a rejected observation, v is computed at the final estimate
    (NaN if its image or point left the adjustment), and w_test and the MDB are
    those of the adjustment that rejected it.
    """
    result, tests = tested.result, tested.tests
    ob = block_read.observations
    n = len(ob)
    used = result.block.observations
    pos = np.full(ob.row.max() + 1 if n else 0, -1)
    pos[used.row] = np.arange(len(used))
    where = pos[ob.row]
    kept = where >= 0
    pix = np.array([block_read.cameras[c].pixel_size_mm for c in block_read.images.camera_id])[ob.image_index]
    v = np.full((n, 2), np.nan)
    v[kept] = result.residuals_mm[where[kept]] / pix[kept, None]
    lost = ~kept
    if lost.any():
        pred = result.predict_pixels(block_read.images.image_id[ob.image_index[lost]],
                                     block_read.points.point_id[ob.point_index[lost]])
        d = pred - ob.pixel[lost]
        v[lost] = np.column_stack([d[:, 0], -d[:, 1]])
    def per_obs(values):
        out = np.full((n, 2), np.nan)
        out[kept] = values[where[kept]]
        return out
    w = per_obs(tests.image_w)
    red = per_obs(tests.image_redundancy)
    mdb = per_obs(tests.image_mdb_px)
    ext = per_obs(tests.image_external)
    w_test = np.full(n, np.nan)
    pick = np.argmax(np.nan_to_num(np.abs(w[kept])), axis=1)
    w_test[kept] = w[kept][np.arange(int(kept.sum())), pick]
    rejected = np.isin(ob.row, tested.rejected_rows)
    rej_pos = np.searchsorted(tested.rejected_rows, ob.row[rejected])
    w_test[rejected] = tested.rejected_w[rej_pos]
    mdb[rejected] = tested.rejected_mdb_px[rej_pos]
    header = ["image_id", "point_id", "vx_px", "vy_px", "w_test", "rejected", "col_px", "row_px", "w_x", "w_y",
              "redundancy_x", "redundancy_y", "mdb_x_px", "mdb_y_px", "external_x", "external_y"]
    cols = [block_read.images.image_id[ob.image_index], block_read.points.point_id[ob.point_index],
            v[:, 0], v[:, 1], w_test, rejected.astype(int), ob.pixel[:, 0], ob.pixel[:, 1], w[:, 0], w[:, 1],
            red[:, 0], red[:, 1], mdb[:, 0], mdb[:, 1], ext[:, 0], ext[:, 1]]
    fmts = ["", "", ".4f", ".4f", ".3f", "d", ".3f", ".3f", ".3f", ".3f", ".4f", ".4f", ".3f", ".3f", ".3f", ".3f"]
    return header, cols, fmts


def screening_json(tested, options=None) -> dict:
    """screening.json: which AP coefficient was dropped, in which round, and why."""
    return {
        "options": None if options is None else vars(options),
        "n_ap_initial": int(tested.n_ap_initial),
        "n_ap_significant": int(tested.n_ap_significant),
        "dropped": [{"round": k, "camera_id": d.camera_id, "name": d.name, "t": d.t, "reason": d.reason}
                    for k, d in tested.screening_log],
        "joint_tests": [{"round": k, "n_dropped": j.n_dropped, "f_statistic": j.f_statistic,
                         "f_critical": j.f_critical, "jointly_significant": j.jointly_significant,
                         **({"groups": [{"group": g.group, "n_dropped": g.n_dropped, "f_statistic": g.f_statistic,
                                         "f_critical": g.f_critical, "jointly_significant": g.jointly_significant}
                                        for g in j.groups]} if j.groups else {})}
                        for k, j in tested.screening_rounds],
    }


def correlation_table(result):
    """correlation.csv: correlation matrix of the interior orientation and the active APs of each camera."""
    from ..stats.correlation import correlation_matrix
    names, index = [], []
    for cam, start in zip(result.problem.cameras, result.problem.d_offset):
        pos = start + np.cumsum(cam.free) - 1
        for i in range(cam.size):
            if cam.free[i]:
                names.append(f"{cam.camera_id}:{cam.names[i]}")
                index.append(int(pos[i]))
    if not index:
        return ["parameter"], [np.array([], dtype=object)], [""]
    rho = correlation_matrix(result.Q_theta, np.array(index))
    return (["parameter"] + names, [np.array(names, dtype=object)] + [rho[:, j] for j in range(len(names))],
            [""] + [".4f"] * len(names))


def distortion_grid_table(block, result, nodes_x: int = 61):
    """Estimated Delta in pixels on a regular grid over each camera's frame.

    The grid has ``nodes_x`` nodes across and as many down as keep the cells
    square (41 for a 3:2 frame). ``dcol``, ``drow`` follow the pixel axes.
    """
    multi = len(result.problem.cameras) > 1
    cols_out = {k: [] for k in ("camera_id", "col", "row", "dcol", "drow")}
    for cam, values in zip(result.problem.cameras, result.state.cameras):
        cfg = block.cameras[cam.camera_id]
        x, y = frame_nodes_mm(cam.ap.frame, nodes_x)
        col, row = pixel_from_photo(np.column_stack([x, y]), cfg.width_px, cfg.height_px, cfg.pixel_size_mm).T
        dx, dy = cam.ap.displacement_px(x, y, values[3:] * cam.free[3:])
        cols_out["camera_id"].append(np.full(col.size, cam.camera_id, dtype=object))
        cols_out["col"].append(col)
        cols_out["row"].append(row)
        cols_out["dcol"].append(dx)
        cols_out["drow"].append(-dy)
    header = (["camera_id"] if multi else []) + ["col", "row", "dcol", "drow"]
    cols = [np.concatenate(cols_out[h]) for h in header]
    fmts = ([""] if multi else []) + [".2f", ".2f", ".5f", ".5f"]
    return header, cols, fmts


def result_files(block_read, tested, summary_extra: dict | None = None, screening_options=None) -> dict:
    """Every file of the results folder as data: dicts become JSON, tuples CSV."""
    result = tested.result
    return {
        "summary.json": summary(tested, summary_extra),
        "camera.json": camera_json(result.block, result),
        "images.csv": image_table(result.block, result),
        "points.csv": point_table(result.block, result, tested.tests),
        "residuals.csv": residual_table(block_read, tested),
        "distortion_grid.csv": distortion_grid_table(result.block, result),
        "screening.json": screening_json(tested, screening_options),
        "correlation.csv": correlation_table(result),
    } | ({"trajectory.csv": trajectory_table(result)} if result.problem.trajectory else {})


def trajectory_table(result):
    """trajectory.csv: the strip-wise shift/drift (Eq. 12 of seed 000) and the mounting of each trajectory sensor.

    One row per parameter: ``sensor`` (GNSS, IMU), ``strip_id`` (empty for the mounting),
    ``term`` (D0, D1, D2, lever_arm, boresight), ``axis``, value and a-posteriori sigma in
    ``unit`` (m, m/s, m/s^2 for GNSS; deg, deg/s, deg/s^2 for IMU), and ``active``
    (false: held at zero by screening, sigma empty).
    """
    problem, state = result.problem, result.state
    diag = np.diag(result.Q_theta)
    cols = {k: [] for k in ("sensor", "strip_id", "term", "axis", "value", "sigma", "unit", "active")}
    full, free_col = 0, problem.n_e + problem.n_d
    for t in problem.trajectory:
        gnss = t.offset == 0
        axes = ("X", "Y", "Z") if gnss else ("omega", "phi", "kappa")
        base = "m" if gnss else "deg"
        scale = 1.0 if gnss else float(np.degrees(1.0))
        meta = [(t.strips[s], f"D{k}", axes[a], base + ("" if k == 0 else "/s" if k == 1 else "/s^2"))
                for s in range(len(t.strips)) for k in range(t.order + 1) for a in range(3)]
        if t.estimate_mounting:
            meta += [("", "lever_arm", a, "m") for a in "xyz"] if gnss else \
                [("", "boresight", a, "deg") for a in axes]
        for j, (strip, term, axis, unit) in enumerate(meta):
            active = bool(t.free[j])
            sigma = np.sqrt(result.variance_factor * diag[free_col]) * scale if active else np.nan
            free_col += int(active)
            for key, value in zip(cols, (t.sensor, strip, term, axis, state.extra[full + j] * scale, sigma, unit,
                                         int(active))):
                cols[key].append(value)
        full += t.n_params
    header = list(cols)
    columns = [np.array(cols[h], dtype=object) if h in ("sensor", "strip_id", "term", "axis", "unit")
               else np.array(cols[h], dtype=float if h != "active" else int) for h in header]
    return header, columns, ["", "", "", "", ".6f", ".6f", "", "d"]


def model_choice_table(choice) -> tuple:
    """model_choice.csv: every candidate of ``--ap auto`` with its score (selfcal.stats.model_choice)."""
    header = ["model", "grid", "n_camera_parameters", "n_observations", "n_unknowns", "omega", "sigma0_px",
              "bic", "delta_bic", "chosen", "rmsd_chk_xy_m", "rmsd_chk_z_m", "error"]
    best = min(s.bic for s in choice.candidates if s.bic is not None)

    def num(value):
        return np.nan if value is None else value
    rows = choice.candidates
    cols = [np.array([s.model for s in rows], dtype=object),
            np.array([f"{s.grid[0]}x{s.grid[1]}" if s.model.startswith("wavelet") else "" for s in rows],
                     dtype=object),
            np.array([s.n_ap for s in rows]), np.array([s.n_observations for s in rows]),
            np.array([s.n_unknowns for s in rows]), np.array([s.omega for s in rows]),
            np.array([s.sigma0_px for s in rows]), np.array([num(s.bic) for s in rows]),
            np.array([num(s.bic) - best for s in rows]),
            np.array([int(s.model == choice.model and s.grid == choice.grid) for s in rows]),
            np.array([num(s.rmsd_chk_xy_m) for s in rows]), np.array([num(s.rmsd_chk_z_m) for s in rows]),
            np.array([s.error.splitlines()[0].replace(",", ";") if s.error else "" for s in rows], dtype=object)]
    fmts = ["", "", "d", "d", "d", ".3f", ".4f", ".2f", ".2f", "d", ".4f", ".4f", ""]
    return header, cols, fmts
