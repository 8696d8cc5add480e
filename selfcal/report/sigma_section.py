"""The report's section on the uncertainty of the correction: the σ map of each camera's AP correction with its
observed area, the half-block check's difference, a table and a sentence (distortion_sigma.csv, summary.json
``distortion_sigma`` and ``half_block``; issue 40 item 5)."""
from __future__ import annotations

import html
from typing import Callable

import numpy as np

from . import figures
from .page import Page, fmt, summary_cell

__all__ = ["sigma_section"]


def _sentence(camera_id: str, sigma: dict, half: dict, check: dict | None) -> str:
    text = (f"The AP correction of camera {camera_id} ({sigma.get('n_estimated')} coefficients) has a σ of at most "
            f"{fmt(sigma.get('max_sigma_observed_px'), '.3f')} px (RMS {fmt(sigma.get('rms_sigma_observed_px'), '.3f')}"
            f" px) where the observations lie ({fmt(100 * (sigma.get('observed_share') or 0), '.0f')} % of the "
            f"frame), {fmt(sigma.get('max_sigma_px'), '.3f')} px at worst on the frame. ")
    if check is None:
        return text + "The half-block check was not run (--no-half-block)."
    if not check.get("done"):
        return text + f"The half-block check could not be made: {check.get('reason')}."
    halves = (" | ".join(", ".join(h) for h in check.get("halves", [])) if check.get("split") == "strips" else
              " | ".join(str(n) for n in check.get("n_images", [])))
    verdict = ("differ beyond their precision: the AP model does not describe the camera the same way in both "
               "halves (a model error, or a camera that changed)" if half.get("flag") else
               "agree within their precision")
    return text + (f"Calibrated on each half of the block on its own ({check.get('split')} {halves}), the two "
                   f"corrections {verdict}: T = {fmt(half.get('statistic'), '.1f')} against χ²({half.get('dof')}) "
                   f"(critical {fmt(half.get('critical'), '.1f')} at α = {fmt(check.get('alpha'), 'g')}, p = "
                   f"{fmt(half.get('p'), '.3g')}); they differ by {fmt(half.get('rms_difference_px'), '.3f')} px RMS, "
                   f"at most {fmt(half.get('largest_ratio'), '.1f')} σ ({half.get('largest_axis')} at "
                   f"{fmt(half.get('largest_at_col_px'), '.0f')}, {fmt(half.get('largest_at_row_px'), '.0f')} px).")


def sigma_section(page: Page, results, add_figure: Callable) -> None:
    """The section (module docstring); ``add_figure(page, files, fig, stem, caption)`` adds a figure to the page
    and the report's files (``add_figure`` takes ``files`` bound: called as ``add_figure(page, fig, stem,
    caption)``)."""
    table = results.tables.get("distortion_sigma")
    s = results.summary
    sigmas = s.get("distortion_sigma") or {}
    if table is None or not sigmas:
        page.paragraph("No camera has estimated frame APs: there is no correction whose σ to map "
                       "(distortion_sigma.csv is not written).", "note")
        return
    check = s.get("half_block")
    cameras = results.camera.get("cameras", {})
    rows = []
    for k, camera_id in enumerate(sigmas):
        pick = table["camera_id"] == camera_id if "camera_id" in table else np.ones(len(table["col"]), bool)
        cam = cameras.get(camera_id, {})
        width = float(cam.get("width_px") or np.max(table["col"][pick]))
        height = float(cam.get("height_px") or np.max(table["row"][pick]))
        half = ((check or {}).get("cameras") or {}).get(camera_id) or {}
        difference = None
        ddcol = table["half_ddcol_px"][pick]
        if half and np.isfinite(ddcol).any():
            label = (f"Half-block difference ({check.get('split')}): T {fmt(half.get('statistic'), '.1f')}, "
                     f"χ²({half.get('dof')}), p {fmt(half.get('p'), '.3g')}" +
                     (": FLAGGED" if half.get("flag") else ": consistent"))
            difference = (ddcol, table["half_ddrow_px"][pick], table["half_sigma_dcol_px"][pick],
                          table["half_sigma_drow_px"][pick], label)
        model = cam.get("ap", {}).get("spec", s.get("ap_model", ""))
        fig = figures.sigma_map_figure(table["col"][pick], table["row"][pick], table["sigma_norm_px"][pick],
                                       table["observed"][pick] == 1, width, height, f"σ of Δ, {model}", difference)
        suffix = f"-{k + 1}" if len(sigmas) > 1 else ""
        add_figure(page, fig, f"distortion-sigma{suffix}",
                   f"σ of the estimated correction Δ of camera {camera_id} ({model}), sqrt(σ_col² + σ_row²) from the "
                   "covariance of its AP coefficients (c, x0, y0 and the orientations estimated with them, by "
                   "marginalisation); outlined in blue: where observations lie, hatched: beyond them, where the σ "
                   "grows (the colours span the observed area's σ up to its 95th percentile)."
                   + (" Below: the correction of the first half of the block minus the second's, each adjusted on "
                      "its own; colour |difference| / σ of the worse axis." if difference is not None else ""))
        key = f"distortion_sigma.{camera_id}"
        hkey = f"half_block.cameras.{camera_id}"
        rows.append(f'<tr><td class="text">{html.escape(camera_id)}</td>'
                    + summary_cell(s, f"{key}.n_estimated", "")
                    + summary_cell(s, f"{key}.max_sigma_observed_px", ".3f")
                    + summary_cell(s, f"{key}.rms_sigma_observed_px", ".3f")
                    + summary_cell(s, f"{key}.max_sigma_px", ".3f")
                    + summary_cell(s, f"{hkey}.statistic", ".1f") + summary_cell(s, f"{hkey}.dof", "")
                    + summary_cell(s, f"{hkey}.critical", ".1f") + summary_cell(s, f"{hkey}.p", ".3g")
                    + summary_cell(s, f"{hkey}.largest_ratio", ".1f") + summary_cell(s, f"{hkey}.flag", "")
                    + "</tr>")
        page.paragraph(_sentence(camera_id, sigmas[camera_id], half, check))
    page.add('<table id="distortion-sigma"><thead><tr><th class="text">camera</th><th>APs</th>'
             "<th>max σ, observed [px]</th><th>RMS σ, observed [px]</th><th>max σ, frame [px]</th>"
             "<th>halves' T</th><th>dof</th><th>critical</th><th>p</th><th>max |ΔΔ|/σ</th><th>flag</th>"
             f'</tr></thead><tbody>{"".join(rows)}</tbody></table>')
    page.paragraph("σ from the a-posteriori covariance of the AP coefficients (σ̂0² Q, their block of the whole "
                   "inverse); the half-block test is T = dᵀ(C₁ + C₂)⁻¹d on the coefficients' difference d over the "
                   "directions both halves determine. Every node is in distortion_sigma.csv.", "note")
