"""The comparison table of a (scenario x AP model) matrix: the columns of seed 000's tables and figures.

One row per cell: GCP/CHK used (Table 1), RMSD(XY) and RMSD(Z) at check points in
GSD (Fig. 3), RMS of the tie points' a-posteriori sigma (Fig. 4), sigma0 (Fig. 5), the cross-validated
prediction error of held-out tie points with its standard error (issue 44: ``--ap auto``'s criterion),
significant/initial APs (Table 2), translation ranges of wavelet APs (Table 3),
max |rho| of the APs by group (Table 4), and the reduction of RMSD relative to
``none`` in the same scenario.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["comparison_rows", "comparison_csv", "comparison_markdown", "COLUMNS", "study_rows", "study_csv",
           "study_markdown"]

COLUMNS = [
    ("scenario", "scenario", ""), ("ap_model", "AP model", ""),
    ("gcp_chk", "GCP/CHK", ""),
    ("rmsd_xy_gsd", "RMSD XY (GSD)", ".2f"), ("rmsd_z_gsd", "RMSD Z (GSD)", ".2f"),
    ("rms_sigma_xy_gsd", "RMS σ̂XY (GSD)", ".2f"), ("rms_sigma_z_gsd", "RMS σ̂Z (GSD)", ".2f"),
    ("sigma0_px", "σ̂0 (px)", ".3f"),
    ("cv_px", "CV error (px)", ".4f"), ("cv_se_px", "CV ± (px)", ".4f"),
    ("aps", "APs sig./init.", ""), ("k_ranges", "k_x; k_y", ""),
    ("corr_iop", "max|ρ| IOP", ".2f"), ("corr_intra_ap", "max|ρ| intra-AP", ".2f"),
    ("corr_eop", "max|ρ| EOP", ".2f"), ("corr_gnss", "max|ρ| GNSS", ".2f"), ("corr_imu", "max|ρ| IMU", ".2f"),
    ("reduction_xy_pct", "ΔRMSD XY vs none (%)", ".1f"), ("reduction_z_pct", "ΔRMSD Z vs none (%)", ".1f"),
    ("rejected", "rejected obs.", ""), ("seconds", "seconds", ".1f"),
]


def _ranges(camera_json: dict) -> str:
    parts = []
    for cam in camera_json.get("cameras", {}).values():
        ap = cam.get("ap", {})
        rng = ap.get("active_ranges") or ap.get("ranges")
        if rng:
            kx0, kx1, ky0, ky1 = rng
            parts.append(f"{kx0:+d}~{kx1:+d}; {ky0:+d}~{ky1:+d}")
    return " / ".join(parts)


def comparison_rows(cells) -> list[dict]:
    """One dict per cell, in the order given."""
    rows = []
    baseline = {}
    for cell in cells:
        if cell.files and cell.model == "none":
            s = cell.files["summary.json"]
            baseline[cell.scenario] = (s["rmsd_chk_xy_m"], s["rmsd_chk_z_m"])
    for cell in cells:
        row = {"scenario": cell.scenario, "ap_model": cell.model, "seconds": cell.seconds}
        if cell.error:
            row["error"] = cell.error.splitlines()[0]
            rows.append(row)
            continue
        s = cell.files["summary.json"]
        corr = s["max_abs_corr"]
        row.update({
            "gcp_chk": f"{s['n_gcp_used']}/{s['n_chk_used']}",
            "rmsd_xy_gsd": s["rmsd_chk_xy_gsd"], "rmsd_z_gsd": s["rmsd_chk_z_gsd"],
            "rmsd_xy_m": s["rmsd_chk_xy_m"], "rmsd_z_m": s["rmsd_chk_z_m"],
            "rms_sigma_xy_gsd": s["rms_sigma_tie_xy_gsd"], "rms_sigma_z_gsd": s["rms_sigma_tie_z_gsd"],
            "sigma0_px": s["sigma0_px"],
            "cv_px": (s.get("prediction") or {}).get("cv_rmse_px"),
            "cv_se_px": (s.get("prediction") or {}).get("cv_se_px"),
            "aps": f"{s['n_ap_significant']}/{s['n_ap_initial']}",
            "k_ranges": _ranges(cell.files["camera.json"]),
            "corr_iop": corr["IOP"], "corr_intra_ap": corr["intra-AP"], "corr_eop": corr["EOP"],
            "corr_gnss": corr["GNSS"], "corr_imu": corr["IMU"],
            "rejected": s["n_obs_rejected"],
        })
        base = baseline.get(cell.scenario)
        if base and base[0] and s["rmsd_chk_xy_m"] is not None:
            row["reduction_xy_pct"] = 100.0 * (1.0 - s["rmsd_chk_xy_m"] / base[0])
            row["reduction_z_pct"] = 100.0 * (1.0 - s["rmsd_chk_z_m"] / base[1])
        rows.append(row)
    return rows


def _cell(value, fmt: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return format(value, fmt) if fmt else str(value)


def comparison_csv(rows: list[dict]):
    """(header, columns, formats) for selfcal.io.results.write_files."""
    keys = [k for k, _, _ in COLUMNS] + ["rmsd_xy_m", "rmsd_z_m", "error"]
    fmts = [f for _, _, f in COLUMNS] + [".4f", ".4f", ""]
    columns = [[_cell(r.get(k), f) for r in rows] for k, f in zip(keys, fmts)]
    return keys, columns, [""] * len(keys)


def comparison_markdown(rows: list[dict], title: str = "") -> str:
    head = "| " + " | ".join(h for _, h, _ in COLUMNS) + " |"
    rule = "|" + "|".join("---" for _ in COLUMNS) + "|"
    lines = ([f"## {title}", ""] if title else []) + [head, rule]
    for r in rows:
        if r.get("error"):
            lines.append(f"| {r['scenario']} | {r['ap_model']} | failed: {r['error']} |")
            continue
        lines.append("| " + " | ".join(_cell(r.get(k), f) for k, _, f in COLUMNS) + " |")
    return "\n".join(lines) + "\n"


# --- seed 001: the M1-M7 study of a pushbroom block (selfcal.batch.seed001) ---------------------------

def study_rows(cases) -> list[dict]:
    return [{"images": c.images, "model": c.model, "n_gcp": c.n_gcp, "n_chk": c.n_check,
             "rmse_across_m": None if c.rmse_m is None else float(c.rmse_m[0]),
             "rmse_along_m": None if c.rmse_m is None else float(c.rmse_m[1]),
             "rmse_up_m": None if c.rmse_m is None else float(c.rmse_m[2]),
             "sigma0": None if c.result is None else float(c.sigma0),
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
