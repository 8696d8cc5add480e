"""Results of pushbroom adjustments: the files of one run and the M1-M7 comparison table (seed 001,
Tables 3, 4 and 6)."""
from __future__ import annotations

import numpy as np

from ..adjust.pushbroom import track_frame
from ..sensors.pushbroom import PARAMETER_NAMES, PARAMETER_UNITS

__all__ = ["pushbroom_files", "study_markdown", "study_csv", "render_pushbroom_report"]

_DISPLAY = {"rad": ("deg", np.degrees), "rad/s": ("deg/s", np.degrees), "mm": ("mm", lambda v: v),
            "px": ("px", lambda v: v)}
#: detector_line.csv samples the estimated line APs every this many columns
DETECTOR_LINE_STEP = 16


def _rms(values) -> float | None:
    return None if values is None or not len(values) else float(np.sqrt(np.mean(np.square(values))))


def pushbroom_files(data, case, sensor_model: str, image_labels: list[str], extra: dict) -> dict:
    """summary.json, parameters.csv, points.csv and residuals.csv of one pushbroom case."""
    result = case.result
    rmse = case.rmse_m
    summary = {
        "sensor": "pushbroom",
        "sensor_model": sensor_model,
        "images": image_labels,
        "converged": bool(result is not None and result.converged),
        "failure": case.failure or None,
        "iterations": None if result is None else result.iterations,
        "sigma0_px": None if result is None else float(result.sigma0 * data.image_sigma_px),
        "variance_factor": None if result is None else float(result.sigma0 ** 2),
        "redundancy": None if result is None else int(result.redundancy),
        "rmse_chk_across_m": None if rmse is None else float(rmse[0]),
        "rmse_chk_along_m": None if rmse is None else float(rmse[1]),
        "rmse_chk_up_m": None if rmse is None else float(rmse[2]),
        "n_gcp_used": int(len(case.gcps)),
        "n_chk_used": int(case.n_check),
        "gcp_ids": [str(data.point_ids[p]) for p in case.gcps],
        "n_obs_rejected": len(case.rejected or []),
    } | extra
    files = {"summary.json": summary}
    if case.screening is not None:
        files["screening.json"] = screening_json(case.screening)
        summary["n_parameters_initial"] = case.screening.n_initial
        summary["n_parameters_kept"] = case.screening.n_kept
    if result is None:
        return files
    image_ids, names, values, sigmas, units = [], [], [], [], []
    for name, value, sigma in zip(result.parameter_names, result.parameter_values, result.parameter_sigma):
        image_id, parameter = name.split(".", 1)
        unit, convert = _DISPLAY[PARAMETER_UNITS[PARAMETER_NAMES.index(parameter)]] \
            if parameter in PARAMETER_NAMES else _DISPLAY["px"]       # line APs
        image_ids.append(image_id)
        names.append(parameter)
        values.append(convert(value))
        sigmas.append(convert(sigma))
        units.append(unit)
    files["parameters.csv"] = (["image_id", "parameter", "value", "sigma", "unit"],
                               [np.array(image_ids, object), np.array(names, object), np.array(values),
                                np.array(sigmas), np.array(units, object)], ["", "", ".9g", ".3g", ""])
    if case.line_aps and result.line_ap_coefficients:
        files["detector_line.csv"] = detector_line_table(case.line_aps, result.line_ap_coefficients)
    if case.check_errors_m is not None and len(case.checks):
        e = case.check_errors_m
        centre, R = track_frame(case.result.images[len(case.result.images) // 2])
        where = (data.reference_ecef[case.checks] - centre) @ R.T / 1000.0
        # the role in the block: a gcp left out of this case's control is checked too
        files["check_points.csv"] = (["point_id", "role", "x_across_km", "y_along_km", "d_across_m", "d_along_m",
                                      "d_up_m"],
                                     [data.point_ids[case.checks].astype(object), data.role[case.checks].astype(object),
                                      where[:, 0], where[:, 1], e[:, 0], e[:, 1], e[:, 2]],
                                     ["", "", ".3f", ".3f", ".4f", ".4f", ".4f"])
    obs = case.observations
    image_ids = np.array([img.image_id for img in data.images], object)
    v, w, r = result.residuals_px, result.w_test, result.redundancy_numbers
    files["residuals.csv"] = (["image_id", "point_id", "v_row_px", "v_col_px", "w_row", "w_col", "r_row", "r_col"],
                              [image_ids[data.obs_image[obs]], data.point_ids[data.obs_point[obs]].astype(object),
                               v[:, 0], v[:, 1], w[:, 0], w[:, 1], r[:, 0], r[:, 1]],
                              ["", "", ".4f", ".4f", ".3f", ".3f", ".4f", ".4f"])
    if case.rejected:
        k = np.array([i for i, _ in case.rejected])
        files["rejected.csv"] = (["image_id", "point_id", "abs_w"],
                                 [image_ids[data.obs_image[k]], data.point_ids[data.obs_point[k]].astype(object),
                                  np.array([w for _, w in case.rejected])], ["", "", ".2f"])
    names = result.parameter_names
    files["correlation.csv"] = (["parameter"] + names,
                                [np.array(names, object)] + [result.correlation[:, j] for j in range(len(names))],
                                [""] + [".4f"] * len(names))
    observed = np.flatnonzero(~np.isnan(result.point_cov[:, 0, 0]))
    sd = np.sqrt(np.einsum("nii->ni", result.point_cov[observed]))
    p = result.points_ecef[observed]
    files["points.csv"] = (["point_id", "X", "Y", "Z", "sigma_X_m", "sigma_Y_m", "sigma_Z_m"],
                           [data.point_ids[observed].astype(object), p[:, 0], p[:, 1], p[:, 2], sd[:, 0], sd[:, 1],
                            sd[:, 2]], ["", ".4f", ".4f", ".4f", ".4f", ".4f", ".4f"])
    return files


def detector_line_table(line_aps: dict, coefficients: dict):
    """detector_line.csv: the estimated displacement of the detectors (along, across track, px) of every
    camera with line APs, every DETECTOR_LINE_STEP columns."""
    ids, cols, along, across = [], [], [], []
    for cid, ap in line_aps.items():
        if cid not in coefficients:
            continue
        col = np.arange(0.5, ap.columns, DETECTOR_LINE_STEP)
        d = ap.displacement_px(col, coefficients[cid])
        ids += [cid] * len(col)
        cols.append(col)
        along.append(d[:, 0])
        across.append(d[:, 1])
    return (["camera_id", "col", "d_along_px", "d_across_px"],
            [np.array(ids, object), np.concatenate(cols), np.concatenate(along), np.concatenate(across)],
            ["", ".1f", ".4f", ".4f"])


def screening_json(screened) -> dict:
    """screening.json of a pushbroom case: the parameters dropped, in order, and the joint test."""
    joint = screened.joint
    return {
        "n_parameters_initial": screened.n_initial,
        "n_parameters_kept": screened.n_kept,
        "dropped": [{"round": k + 1, "camera_id": d.camera_id, "name": d.name, "t": d.t, "reason": d.reason}
                    for k, d in enumerate(screened.dropped)],
        "joint_tests": [] if joint is None else [{"round": len(screened.dropped), "n_dropped": joint.n_dropped,
                                                  "f_statistic": joint.f_statistic, "f_critical": joint.f_critical,
                                                  "jointly_significant": joint.jointly_significant}],
    }


def study_rows(cases) -> list[dict]:
    return [{"images": c.images, "model": c.model, "n_gcp": c.n_gcp, "n_chk": c.n_check,
             "rmse_across_m": None if c.rmse_m is None else float(c.rmse_m[0]),
             "rmse_along_m": None if c.rmse_m is None else float(c.rmse_m[1]),
             "rmse_up_m": None if c.rmse_m is None else float(c.rmse_m[2]),
             "sigma0": None if c.result is None else float(c.result.sigma0),
             "failure": c.failure} for c in cases]


def study_csv(cases):
    rows = study_rows(cases)
    keys = list(rows[0]) if rows else []
    columns = []
    for k in keys:
        values = [r[k] for r in rows]
        columns.append(np.array([np.nan if v is None else v for v in values], dtype=object if k in
                                ("images", "model", "failure") else float))
    formats = ["" if k in ("images", "model", "failure") else (".0f" if k.startswith("n_") else ".3f") for k in keys]
    return keys, columns, formats


def study_markdown(cases, focal: dict, focal_sigma: dict, title: str = "selfcal compare (pushbroom)") -> str:
    """One table per image set: models down, GCP counts across, RMSE X/Y/Z (m) at the check points."""
    lines = [f"# {title}", ""]
    if focal:
        lines += ["Focal lengths calibrated first (M7 on all images, every GCP), then held:", ""]
        lines += [f"- {k}: {v:.3f} mm (σ {focal_sigma[k]:.3f} mm)" for k, v in focal.items()]
        lines.append("")
    lines += ["RMSE at the check points in metres: X across track / Y along track / Z up. "
              "Mono: restituted on the terrain; stereo: intersected in the adjustment.", ""]
    sets = list(dict.fromkeys(c.images for c in cases))
    counts = sorted({c.n_gcp for c in cases})
    for label in sets:
        mine = [c for c in cases if c.images == label]
        lines += [f"## {label}", "", "| model | " + " | ".join(f"{n} GCP" for n in counts) + " |",
                  "| --- |" + " ---: |" * len(counts)]
        for model in dict.fromkeys(c.model for c in mine):
            cells = []
            for n in counts:
                case = next((c for c in mine if c.model == model and c.n_gcp == n), None)
                if case is None:
                    cells.append("")
                elif case.rmse_m is None:
                    cells.append("—")
                else:
                    cells.append(" / ".join(f"{v:.2f}" for v in case.rmse_m))
            lines.append(f"| {model} | " + " | ".join(cells) + " |")
        lines.append("")
    failures = [c for c in cases if c.rmse_m is None]
    if failures:
        lines += ["—: no solution. " + "; ".join(sorted({f"{c.model} with {c.n_gcp} GCP: {c.failure.splitlines()[0]}"
                                                        for c in failures}))[:2000], ""]
    return "\n".join(lines)


_SUMMARY = [
    ("sensor model / images", ("sensor_model", "images")),
    ("σ̂0 [px] / redundancy", ("sigma0_px", "redundancy")),
    ("RMSE at check points across / along / up [m]", ("rmse_chk_across_m", "rmse_chk_along_m", "rmse_chk_up_m")),
    ("GCP / check points used", ("n_gcp_used", "n_chk_used")),
    ("image points rejected (data snooping)", ("n_obs_rejected",)),
    ("iterations / seconds", ("iterations", "seconds")),
]


def render_pushbroom_report(results) -> dict:
    """report.html and figures/ of a pushbroom results folder (:class:`~selfcal.io.results.ResultsFolder`)."""
    import html

    from .figures import control_error_figure, correlation_figure, residual_histogram_figure
    from .page import Page, fmt
    from .render import _add_figure

    s, tables = results.summary, results.tables
    title = f"selfcal pushbroom adjustment: {s.get('sensor_model')} on {'+'.join(s.get('images') or [])}"
    page, files = Page(title), {}
    page.heading(title, 1)
    status = "converged" if s.get("converged") else f"FAILED: {s.get('failure')}"
    page.add(f'<p class="lede">{html.escape(status)}; every number comes from summary.json and the CSV tables '
             "beside this page. X is across track, Y along track, Z up, at the scene centre.</p>")
    page.heading("Summary", anchor="summary")
    rows = []
    for label, keys in _SUMMARY:
        values = [s.get(k) for k in keys]
        rows.append([label, " / ".join(", ".join(v) if isinstance(v, list) else fmt(v, ".3f") for v in values)])
    page.table(["", "value"], rows, text_columns=2)
    if "calibrated_focal_mm" in s:
        page.paragraph("Focal lengths calibrated first (M7 on all images): " + ", ".join(
            f"{k} {v['value']:.3f} ± {v['sigma']:.3f} mm" for k, v in s["calibrated_focal_mm"].items()))
    if "parameters" in tables:
        t = tables["parameters"]
        page.heading("Calibration parameters", anchor="parameters")
        page.table(["image", "parameter", "value", "σ", "unit", "|value|/σ"],
                   [[i, n, f"{v:.6g}", f"{e:.2g}", u, f"{abs(v) / e:.1f}" if e > 0 else "–"]
                    for i, n, v, e, u in zip(t["image_id"], t["parameter"], t["value"], t["sigma"], t["unit"])],
                   text_columns={0, 1, 4})
    dropped = (results.screening or {}).get("dropped", [])
    if results.screening:
        page.heading("Screening", anchor="screening")
        page.paragraph(f"{s.get('n_parameters_kept')} of {s.get('n_parameters_initial')} calibration parameters kept; "
                       "a dropped parameter is held at its start value. t = |value − start| / σ when dropped.")
        if dropped:
            page.table(["image", "parameter", "t", "reason"],
                       [[d["camera_id"], d["name"], f"{d['t']:.2f}", d["reason"]] for d in dropped],
                       text_columns={0, 1, 3})
    if "correlation" in tables and len(tables["correlation"]["parameter"]) > 1:
        t = tables["correlation"]
        names = list(t["parameter"])
        rho = np.column_stack([t[n] for n in names])
        _add_figure(page, files, correlation_figure(names, rho, "Correlations of the calibration parameters"),
                    "correlation", "Correlation matrix of the estimated calibration parameters.")
    if "check_points" in tables:
        t = tables["check_points"]
        page.heading("Check points", anchor="check")
        xy = np.column_stack([t["x_across_km"], t["y_along_km"]]) * 1000.0
        d = np.column_stack([t["d_across_m"], t["d_along_m"], t["d_up_m"]])
        _add_figure(page, files, control_error_figure(xy, d, np.array(["chk"] * len(d), object), t["point_id"],
                                                      "Errors at the check points (axes: across / along track)"),
                    "check_points", "Check-point errors: restituted or intersected minus reference.")
        page.table(["point", "role", "X across [km]", "Y along [km]", "dX [m]", "dY [m]", "dZ [m]"],
                   [[p, r, f"{x:.2f}", f"{y:.2f}", f"{a:.3f}", f"{b:.3f}", f"{c:.3f}"]
                    for p, r, x, y, a, b, c in zip(t["point_id"], t["role"], t["x_across_km"], t["y_along_km"],
                                                   t["d_across_m"], t["d_along_m"], t["d_up_m"])], text_columns=2)
    if "residuals" in tables:
        t = tables["residuals"]
        page.heading("Image residuals", anchor="residuals")
        r = np.concatenate([t["r_row"], t["r_col"]])
        _add_figure(page, files, residual_histogram_figure(t["v_col_px"], t["v_row_px"], s.get("sigma0_px") or 0.0,
                                                           float(np.mean(r)) if r.size else 1.0,
                                                           "Residuals: v_x = column (across), v_y = row (along)"),
                    "residual_histogram", "Histograms of the image residuals in bins of σ̂0.")
    if "rejected" in tables:
        t = tables["rejected"]
        page.heading("Rejected image points", anchor="rejected")
        page.table(["image", "point", "|w|"], [[i, p, f"{w:.1f}"] for i, p, w in
                                               zip(t["image_id"], t["point_id"], t["abs_w"])], text_columns=2)
    files["report.html"] = page.html()
    return files
