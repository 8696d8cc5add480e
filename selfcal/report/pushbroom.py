"""Results of pushbroom adjustments: the files of one run and the M1-M7 comparison table (seed 001,
Tables 3, 4 and 6)."""
from __future__ import annotations

import numpy as np

from ..sensors.pushbroom import PARAMETER_NAMES, PARAMETER_UNITS

__all__ = ["pushbroom_files", "study_markdown", "study_csv"]

_DISPLAY = {"rad": ("deg", np.degrees), "rad/s": ("deg/s", np.degrees), "mm": ("mm", lambda v: v)}


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
    if result is None:
        return files
    image_ids, names, values, sigmas, units = [], [], [], [], []
    for name, value, sigma in zip(result.parameter_names, result.parameter_values, result.parameter_sigma):
        image_id, parameter = name.split(".", 1)
        unit, convert = _DISPLAY[PARAMETER_UNITS[PARAMETER_NAMES.index(parameter)]]
        image_ids.append(image_id)
        names.append(parameter)
        values.append(convert(value))
        sigmas.append(convert(sigma))
        units.append(unit)
    files["parameters.csv"] = (["image_id", "parameter", "value", "sigma", "unit"],
                               [np.array(image_ids, object), np.array(names, object), np.array(values),
                                np.array(sigmas), np.array(units, object)], ["", "", ".9g", ".3g", ""])
    if case.check_errors_m is not None and len(case.checks):
        e = case.check_errors_m
        # the role in the block: a gcp left out of this case's control is checked too
        files["check_points.csv"] = (["point_id", "role", "d_across_m", "d_along_m", "d_up_m"],
                                     [data.point_ids[case.checks].astype(object), data.role[case.checks].astype(object),
                                      e[:, 0], e[:, 1], e[:, 2]],
                                     ["", "", ".4f", ".4f", ".4f"])
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
