"""The report's section on whether the calibration's sigma can be trusted (summary.json ``calibration_precision``,
:mod:`selfcal.stats.calibration_precision`): the verdict, the sentence that says why, and per camera its core
parameters (and any AP coefficient the jackknife flags) with sigma, the sigma with the APs held, the strongest
correlation and the jackknife's sigma."""
from __future__ import annotations

from .page import Page, fmt

__all__ = ["calibration_precision_section"]

_VERDICT = {True: "trusted", False: "not trusted", None: "not verified"}


def calibration_precision_section(page: Page, summary: dict) -> None:
    precision = summary.get("calibration_precision")
    if not precision:
        return
    page.heading("Precision of the calibration", 3)
    statement = precision.get("statement", "")
    page.paragraph(f"{_VERDICT[precision.get('trusted')].capitalize()}. {statement[:1].upper()}{statement[1:]}.",
                   "note" if precision.get("trusted") is not False else None)
    jack = precision.get("jackknife") or {}
    if jack.get("done"):
        said = (f"Jackknife over {jack['n_replicates']} groups of consecutive images, each left out in turn "
                f"(the AP set and basis kept; no tests): σ_J = sqrt((G−1)/G Σ (θ_g − mean)²); a ratio σ_J/σ above "
                f"{fmt(jack.get('critical_ratio'), '.2f')} (twice, or χ²(G−1)/(G−1) at α = {jack.get('alpha')} where "
                f"larger) flags a parameter; the verdict is the core parameters' (c, x0, y0), the APs' field is the "
                f"half-block check's.")
    elif jack:
        said = f"The jackknife was asked for and not done: {jack.get('reason', '')}."
    else:
        said = "No jackknife (selfcal adjust --jackknife G checks the σ against the images' spread)."
    page.paragraph(said + " σ with the APs held: the parameter's σ if the camera's active APs were known; their "
                   "ratio is 1/sqrt(1 − R²), R its multiple correlation with the APs. ρ: its largest correlation with "
                   "another parameter of the camera. c, x0, y0 in pixels (x0, y0 along the photo axes from the "
                   "frame's centre).", "note")
    rows, flagged = [], []
    for camera_id, parameters in precision.get("cameras", {}).items():
        for p in parameters:
            if not p.get("core") and not p.get("flagged"):
                continue
            partner = f"{p['partner']} {p['rho']:+.2f}" if p.get("partner") and p.get("rho") is not None else "–"
            rows.append([camera_id, p["name"], fmt(p.get("value"), ".6g"), fmt(p.get("sigma"), ".3g"),
                         fmt(p.get("sigma_aps_held"), ".3g"), fmt(p.get("ap_inflation"), ".2f"), partner,
                         fmt(p.get("sigma_jackknife"), ".3g"), fmt(p.get("ratio"), ".2f"),
                         {True: "flagged", False: "holds", None: "–"}[p.get("flagged")], p.get("unit", "")])
            flagged.append(bool(p.get("flagged")))
    if rows:
        page.table(["camera", "parameter", "value", "σ", "σ, APs held", "inflation", "largest ρ", "σ jackknife",
                    "σ_J/σ", "", "unit"], rows, text_columns={0, 1, 6, 9, 10}, flagged=flagged,
                   ident="calibration-precision")
