"""Turn a results folder (as data) into the adjustment report: ``report.html`` and ``figures/``.

:func:`render_report` takes a :class:`selfcal.io.results.ResultsFolder` (read
from disk by ``selfcal report`` or built in memory by ``selfcal adjust``) and
returns the report's files as data: ``{"report.html": str, "figures/NAME.png":
bytes, "figures/NAME.svg": bytes}``; :mod:`selfcal.io.results` writes them.
:func:`render_comparison_report` does the same for the table of ``selfcal
compare`` (Figs. 3-5 of seed 000). Nothing is re-adjusted: every number comes
from the results files.
"""
from __future__ import annotations

import html
import io
import math
from collections import Counter
from typing import Callable

import numpy as np

from ..io.results import ResultsFolder
from . import figures
from .page import Page, fmt, summary_cell
from .calibration_precision import calibration_precision_section
from .rolling import rolling_shutter_section
from .sigma_section import sigma_section

__all__ = ["render_report", "render_comparison_report", "best_cells", "images_per_point", "FIGURE_DPI",
           "MAX_CAMERA_FIGURES", "MAX_AP_ROWS"]

FIGURE_DPI = 110
#: image-space figures are drawn for this many cameras at most (those with the most observations)
MAX_CAMERA_FIGURES = 4
#: images drawn in the map of rejected observations (most rejections first)
MAX_REJECTION_PANELS = 6
#: rejected observations listed in the report (largest |w| first); all of them are in residuals.csv
MAX_REJECTED_ROWS = 200
#: an AP table longer than this is folded (<details>) to the coefficients with the largest t; all are in
#: parameters.csv; the camera table of initial against adjusted values lists a camera's APs only up to this many
MAX_AP_ROWS = 20
#: rows of the table of initial against adjusted camera values (all are in parameters.csv)
MAX_CAMERA_CHANGE_ROWS = 60

#: the summary table: a label and the summary.json keys (with their formats) printed on its row
_SUMMARY_ROWS = [
    ("AP model", [("ap_model", "")]), ("converged", [("converged", "")]), ("iterations", [("iterations", "")]),
    ("σ̂0 [px]", [("sigma0_px", ".4f")]), ("variance factor σ̂0²/σ0²", [("variance_factor", ".4f")]),
    ("observations / unknowns / redundancy", [("n_observations", ""), ("n_unknowns", ""), ("redundancy", "")]),
    ("RMS image residual [px]", [("rms_image_residual_px", ".4f")]),
    ("ground sample distance [m]", [("gsd_m", ".4f")]),
    ("datum", [("datum_detail", "")]),
    ("control points used (GCP)", [("n_gcp_used", "")]), ("check points used (CHK)", [("n_chk_used", "")]),
    ("RMSD XY at check points [m]", [("rmsd_chk_xy_m", ".4f")]),
    ("RMSD Z at check points [m]", [("rmsd_chk_z_m", ".4f")]),
    ("RMSD XY at check points [GSD]", [("rmsd_chk_xy_gsd", ".3f")]),
    ("RMSD Z at check points [GSD]", [("rmsd_chk_z_gsd", ".3f")]),
    ("CE90 / LE90 at check points [m]", [("ce90_chk_m", ".4f"), ("le90_chk_m", ".4f")]),
    ("RMS residual at control points XY / Z [m]", [("rms_gcp_residual_xy_m", ".4f"),
                                                    ("rms_gcp_residual_z_m", ".4f")]),
    ("RMS σ̂ of tie points XY / Z [m]", [("rms_sigma_tie_xy_m", ".4f"), ("rms_sigma_tie_z_m", ".4f")]),
    ("RMS σ̂ of tie points XY / Z [GSD]", [("rms_sigma_tie_xy_gsd", ".3f"), ("rms_sigma_tie_z_gsd", ".3f")]),
    ("APs significant / initial", [("n_ap_significant", ""), ("n_ap_initial", "")]),
    ("observations rejected", [("n_obs_rejected", "")]),
    ("images / tie points / image observations", [("n_images", ""), ("n_tie_points", ""),
                                                  ("n_image_observations", "")]),
    ("seconds", [("seconds", ".1f")]),
]


def _fix_layout(fig) -> None:
    """Solve the figure's constrained layout once, at the PNG's dpi, and leave the figure without a layout engine.

    With a layout engine (even the placeholder that ``set_layout_engine("none")`` leaves) ``savefig`` draws the
    whole figure once without output, to solve the layout, before it draws the file: a figure saved as PNG and SVG
    was drawn four times (PNG 2, SVG 2). Solved here as that extra draw solved it (same dpi, an Agg renderer), each
    file is drawn once with the layout of before: the same PNG bytes, the same SVG but for its random ids. The
    figure keeps the Agg canvas: the PNG is drawn with the renderer that measured the texts (their sizes cached)."""
    engine = fig.get_layout_engine()
    if engine is None:
        return
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    FigureCanvasAgg(fig)                          # becomes fig.canvas
    if fig.axes:
        dpi = fig.dpi
        fig.dpi = FIGURE_DPI
        try:
            engine.execute(fig)
        except ValueError:                        # as Figure.draw: an unsolvable layout leaves the axes in place
            pass
        finally:
            fig.dpi = dpi
    import matplotlib                             # loaded with the figure
    if matplotlib.rcParams["figure.autolayout"] or matplotlib.rcParams["figure.constrained_layout.use"]:
        fig.set_layout_engine("none")             # None would be the rcParams' layout: keep the one solved
    else:
        fig.set_layout_engine(None)


def _figure_files(fig, stem: str) -> tuple[dict, bytes]:
    png, svg = io.BytesIO(), io.BytesIO()
    # the layout solved once and kept for both copies; each copy drawn once (see _fix_layout)
    _fix_layout(fig)
    fig.savefig(png, format="png", dpi=FIGURE_DPI)
    fig.savefig(svg, format="svg", metadata={"Date": None})
    return {f"figures/{stem}.png": png.getvalue(), f"figures/{stem}.svg": svg.getvalue()}, png.getvalue()


def _add_figure(page: Page, files: dict, fig, stem: str, caption: str) -> None:
    out, png = _figure_files(fig, stem)
    files.update(out)
    page.figure(png, f"figures/{stem}.svg", caption, alt=caption.split(".")[0])


#: the rows of the report's Table 4 (summary.json keys; all but the first with selfcal adjust --orthonormal)
_CORRELATION_ROWS = (("max_abs_corr", "max |rho|, the APs as estimated"),
                     ("max_abs_corr_orthonormal", "max |rho|, orthonormal AP basis"),
                     ("canonical_corr", "canonical correlation (any basis)"),
                     ("design_cosine", "max |cos| of design columns"))


def _summary_section(page: Page, s: dict) -> None:
    rows = []
    for label, keys in _SUMMARY_ROWS:
        cells = [summary_cell(s, key, spec) for key, spec in keys]
        rows.append(f'<tr><td class="text">{html.escape(label)}</td>{"".join(cells)}</tr>')
    page.add("<table><tbody>" + "".join(rows) + "</tbody></table>")
    corr = s.get("max_abs_corr") or {}
    if corr:
        head = "".join(f"<th>{html.escape(k)}</th>" for k in corr)
        shown = [(key, label) for key, label in _CORRELATION_ROWS if isinstance(s.get(key), dict)]
        body = "".join(f'<tr><td class="text">{html.escape(label)}</td>'
                       + "".join(summary_cell(s, f"{key}.{k}", ".3f") for k in corr) + "</tr>" for key, label in shown)
        page.add('<p class="note">Table 4 of seed 000: the largest |correlation| of an AP coefficient with a '
                 "parameter of each group, from the cofactors of the final (snooped, screened) adjustment. A "
                 "correlation belongs to the AP basis, not to the fitted field: another basis of the same fields "
                 "(the orthonormal one) gives other figures for the same fit, and no basis brings a group below its "
                 "canonical correlation (the best-correlated combinations of each side); design cosines are angles "
                 "between the design matrix's columns, not correlations of the estimates (selfcal.stats.correlation)."
                 "</p>"
                 f'<table><thead><tr><th></th>{head}</tr></thead><tbody>{body}</tbody></table>')


#: the colour of a quality check's status
_STATUS_STYLE = {"pass": "color:#176b1a", "warn": "color:#9a6700", "fail": "color:#b00;font-weight:bold", "n/a": ""}


def _quality_section(page: Page, s: dict) -> None:
    """summary.json ``quality_check``: each check with its value, threshold and status (selfcal.stats.quality)."""
    quality = s.get("quality_check")
    if not quality:
        page.paragraph("This results folder has no quality check (summary.json has no 'quality_check': written by "
                       "an older selfcal).", "note")
        return
    rows = []
    for key, c in (quality.get("checks") or {}).items():
        name = f"quality_check.checks.{key}"
        shown = str(c.get("shown", ""))
        status = str(c.get("status", ""))
        # the value as summary.json shows it ("0.9 % (57 of 6087)"; the number itself is its "value")
        rows.append(f'<tr><td class="text">{html.escape(str(c.get("check", key)))}</td>'
                    f'<td data-summary="{html.escape(name)}.shown" data-value="{html.escape(repr(shown))}">'
                    f'{html.escape(shown)}</td>'
                    f'<td class="text">{html.escape(str(c.get("threshold", "")))}</td>'
                    f'<td class="text" data-summary="{html.escape(name)}.status" data-value="{html.escape(repr(status))}"'
                    f' style="{_STATUS_STYLE.get(status, "")}">{html.escape(status)}</td>'
                    f'<td class="text">{html.escape(str(c.get("detail", "")))}</td></tr>')
    page.add('<table id="quality-check"><thead><tr><th class="text">check</th><th>value</th>'
             '<th class="text">threshold</th><th class="text">status</th><th class="text"></th></tr></thead>'
             f'<tbody>{"".join(rows)}</tbody></table>')
    page.paragraph(f"Overall: {quality.get('status', '–')} (the worst check). Each check is computed from this "
                   "adjustment's results; the thresholds and their reasons are in selfcal.stats.quality.", "note")


#: the rows of the accuracy statement: a label and the keys of summary.json ``accuracy`` (horizontal, vertical,
#: 3-D; None: no figure)
_ACCURACY_ROWS = [
    ("RMSE measured at the check points [m]", ("rmse_h_measured_m", "rmse_v_measured_m", None), ".4f"),
    ("RMSE of the check points' survey (their σ) [m]", ("rmse_h_survey_m", "rmse_v_survey_m", None), ".4f"),
    ("RMSE of the product, survey included [m]", ("rmse_h_m", "rmse_v_m", "rmse_3d_m"), ".4f"),
    ("accuracy class met [cm]", ("horizontal_class_cm", "vertical_class_cm", None), "g"),
]


def _accuracy_section(page: Page, s: dict) -> None:
    """summary.json ``accuracy``: ASPRS Edition 2's RMSE_H, RMSE_V, RMSE_3D with the check points' survey error
    included, and the classes met (selfcal.stats.asprs)."""
    a = s.get("accuracy")
    if not a:
        page.paragraph("This results folder has no accuracy statement (summary.json has no 'accuracy': written by "
                       "an older selfcal).", "note")
        return
    rows = []
    for label, keys, spec in _ACCURACY_ROWS:
        cells = "".join(summary_cell(s, f"accuracy.{k}", spec) if k else "<td>–</td>" for k in keys)
        rows.append(f'<tr><td class="text">{html.escape(label)}</td>{cells}</tr>')
    page.add('<table id="accuracy"><thead><tr><th class="text"></th><th>horizontal (H)</th><th>vertical (V)</th>'
             f'<th>3-D</th></tr></thead><tbody>{"".join(rows)}</tbody></table>')
    page.paragraph(
        f"{a.get('standard', 'ASPRS Edition 2')}, from {a.get('n_checkpoints')} check points "
        f"({a.get('n_survey_sigma')} with a survey σ): RMSE_H = sqrt(RMSE_x² + RMSE_y²) (RMSE_x "
        f"{fmt(a.get('rmse_x_m'))} m, RMSE_y {fmt(a.get('rmse_y_m'))} m), RMSE_V = sqrt(mean dZ²); the product's "
        "RMSE = sqrt(measured² + survey²), the survey's from the check points' a-priori σ (RMS); RMSE_3D = "
        "sqrt(RMSE_H² + RMSE_V²). A result meets the smallest '#-cm' class at or above its RMSE (classes of "
        "selfcal.stats.asprs.CLASSES_CM). CE90 / LE90 (Edition 1) stay in the summary above.", "note")
    for warning in a.get("warnings") or []:
        page.add(f'<p class="bad">{html.escape(str(warning))}</p>')


def images_per_point(results) -> dict[str, int]:
    """How many images observe each point in the final adjustment: the distinct images of its observations in
    residuals.csv that were not rejected (and have a residual). Points without one are absent."""
    res = results.tables["residuals"]
    keep = (res["rejected"] == 0) & np.isfinite(res["vx_px"])
    pairs = set(zip(res["image_id"][keep].tolist(), res["point_id"][keep].tolist()))
    return dict(Counter(point for _, point in pairs))


def _projection_centres(results, points_xy: np.ndarray) -> tuple[np.ndarray | None, str]:
    """The images' projection centres X0, Y0 from images.csv (None where its sensor writes none, or where they lie
    far outside the block, as a satellite's do) and a sentence for the caption."""
    im = results.tables["images"]
    if "X0" not in im or "Y0" not in im or not len(im["X0"]):
        return None, "The images' sensor writes no projection centre (images.csv): the points only. "
    centres = np.column_stack([im["X0"], im["Y0"]])
    if not np.isfinite(centres).all():
        return None, "Some projection centres are not finite (images.csv): the points only. "
    if len(points_xy):
        middle = points_xy.mean(axis=0)
        span = max(float(np.ptp(points_xy[:, 0])), float(np.ptp(points_xy[:, 1])), 1.0)
        if float(np.max(np.hypot(*(centres - middle).T))) > 10.0 * span:
            return None, ("The projection centres lie more than ten times the block's extent from it (a satellite, "
                          "a far camera) and are not drawn. ")
    return centres, "Black crosses: the projection centres X0, Y0 (images.csv), joined along each strip. "


def _layout_section(page: Page, files: dict, results) -> None:
    """The camera layout over the points coloured by their overlap, and the table of the overlap's counts."""
    pts = results.tables["points"]
    by_point = images_per_point(results)
    counts = np.array([by_point.get(p, 0) for p in pts["point_id"]], dtype=int)
    xy = np.column_stack([pts["X"], pts["Y"]])
    centres, said = _projection_centres(results, xy)
    im = results.tables["images"]
    fig = figures.camera_layout_figure(xy, counts, pts["role"], centres, list(im["strip_id"]), list(im["image_id"]),
                                       "Camera layout and overlap")
    _add_figure(page, files, fig, "camera-layout",
                f"Camera layout and overlap. In plan (X right, Y up, from the mean of the points), every object "
                f"point coloured by the number of images that observe it in the final adjustment (observations "
                f"rejected excluded; from residuals.csv), {figures.OVERLAP_TOP} and more in the last colour; "
                f"control points as triangles, check points as circles. {said}")
    control = np.isin(pts["role"], ("gcp", "chk"))
    rows = []
    for k in sorted(set(counts.tolist())):
        mine = counts == k
        rows.append([k, int((mine & ~control).sum()), int((mine & control).sum()),
                     fmt(100.0 * mine.sum() / max(len(counts), 1), ".1f")])
    page.table(["images per point", "tie points", "control and check points", "share of the points [%]"], rows,
               text_columns=0, ident="overlap")
    if (counts < 2).any():
        page.paragraph(f"{int((counts < 2).sum())} points are seen in fewer than two images after the rejections "
                       "(0: all their observations rejected, or the point left the adjustment).", "note")


def _known(summary: dict, key: str) -> bool:
    """Whether the dotted ``key`` names a scalar of summary.json (None included): a cell that holds it exactly."""
    value: object = summary
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            return False
        value = value[part]
    return not isinstance(value, (dict, list))


def _cell(summary: dict, key: str, spec: str = "") -> str:
    """The summary.json value ``key`` in a (left-aligned) cell that names it (:func:`summary_cell`), or '–' where
    it is absent."""
    if not _known(summary, key):
        return _text_cell("–")
    return summary_cell(summary, key, spec).replace("<td ", '<td class="text" ', 1)


def _text_cell(text: str) -> str:
    return f'<td class="text">{html.escape(text)}</td>'


def _processing_rows(s: dict) -> list[tuple[str, list[str]]]:
    """The processing parameters: what the run was asked to do (summary.json ``options``) and what it did."""
    from ..ap import takes_grid
    o = s.get("options") or {}
    rows: list[tuple[str, list[str]]] = [("selfcal version", [_cell(s, "selfcal_version")]),
                                         ("block", [_cell(s, "block")]),
                                         ("sensors", [_text_cell(", ".join(s.get("sensors") or []))]),
                                         ("coordinate reference system", [_cell(s, "crs")])]
    if o.get("ap_model"):
        rows.append(("AP model asked for", [_cell(s, "options.ap_model")]))
    if o.get("ap_candidates"):
        rows.append(("AP candidates (the smallest BIC chosen)", [_text_cell(", ".join(o["ap_candidates"]))]))
    rows.append(("AP model used", [_cell(s, "ap_model")]))
    try:
        gridded = takes_grid(str(s.get("ap_model", "none")))
    except ValueError:
        gridded = False
    grid = s.get("grid") or o.get("grid")
    if gridded and grid:
        rows.append(("AP grid Gx × Gy", [_text_cell(f"{grid[0]} × {grid[1]}")]))
    if o:
        rows.append(("a-priori σ of the AP coefficients [px]",
                     [_cell(s, "options.ap_sigma_px", ".3g") if o.get("ap_sigma_px") is not None
                      else _text_cell("none: free")]))
        rows.append(("a-priori σ of an image coordinate [px]", [_cell(s, "options.image_sigma_px", ".3g")]))
    rows.append(("datum", [_cell(s, "datum_detail")]))
    if o.get("n_control"):
        for axis, key in (("XY", "control_sigma_xy_m"), ("Z", "control_sigma_z_m")):
            rows.append((f"a-priori σ of the control points {axis} [m] (median)", [_cell(s, f"options.{key}", ".3g")]))
    for key, label in (("gnss_sigma_m", "a-priori σ of GNSS X0, Y0, Z0 [m]"),
                       ("imu_sigma_deg", "a-priori σ of IMU ω, φ, κ [deg]")):
        if o.get(key):
            rows.append((label, [_text_cell(", ".join(fmt(v, ".3g") for v in o[key]))]))
    robust = s.get("robust")
    scale = (o.get("robust") or {}).get("scale")
    rows.append(("robust cleaning", [_text_cell(
        f"{robust['loss']} loss, c = {fmt(robust.get('c'), 'g')} × the scale{f' ({scale})' if scale else ''}; "
        f"gross errors beyond {fmt(robust.get('reject_u'), 'g')} robust σ rejected" if robust
        else "none: least squares throughout")]))
    snooping = s.get("snooping") or {}
    critical = snooping.get("critical")
    mode = (o.get("snooping") or {}).get("mode")
    if critical:
        rows.append(("data snooping (Baarda): critical |w|", [_cell(s, "snooping.critical", "g")]))
        if mode:
            rows.append(("data snooping: rejections per round", [_text_cell(
                "the largest |w| of the block (single)" if mode == "single" else
                f"the largest |w| of each point above it ({mode})")]))
    else:
        rows.append(("data snooping (Baarda)", [_text_cell("off" if snooping or o else "–")]))
    if o:
        screening = o.get("screening")
        rows.append(("parameter screening", [_text_cell(
            f"one at a time while t < {fmt(screening.get('significance'), 'g')} or |ρ| > "
            f"{fmt(screening.get('max_correlation'), 'g')}; joint F-test α = {fmt(screening.get('joint_alpha'), 'g')}"
            + (f"; c, x0, y0 kept within {fmt(screening.get('max_iop_move_sigma'), 'g')} σ"
               if screening.get('max_iop_move_sigma') else "")
            if screening else "off: every parameter kept")]))
        rows.append(("variance components", [_text_cell("estimated per observation group"
                                                        if o.get("variance_components") else "not estimated")]))
        rows.append(("iteration limit", [_cell(s, "options.max_iterations")]))
    rows.append(("iterations", [_cell(s, "iterations")]))
    return rows


def _processing_section(page: Page, s: dict) -> None:
    rows = _processing_rows(s)
    page.add('<table id="processing"><tbody>' + "".join(
        f'<tr><td class="text">{html.escape(label)}</td>{"".join(cells)}</tr>' for label, cells in rows) +
        "</tbody></table>")
    if not s.get("options"):
        page.paragraph("This results folder does not record the run's options (summary.json has no 'options': "
                       "written by an older selfcal); the rows above are those summary.json holds.", "note")


#: the number format of a camera value by its unit
_UNIT_FORMAT = {"mm": ".5f", "px": ".4f", "m": ".4f", "deg": ".6f"}


def _camera_change_section(page: Page, results) -> None:
    """Each camera's parameters: initial (parameters.csv ``start``), adjusted, their difference and σ; the APs of
    a model with at most MAX_AP_ROWS coefficients too (longer ones: the AP table below)."""
    cameras = results.camera.get("cameras", {})
    t = results.tables.get("parameters")
    if t is None:
        page.paragraph("This results folder has no parameters.csv (an older selfcal): the initial values are not "
                       "recorded; the adjusted values are in the camera tables below.", "note")
        return
    many = len(cameras) > 1
    rows, notes = [], []
    for camera_id in cameras:
        mine = np.flatnonzero(t["owner"] == camera_id)
        ap = [i for i in mine if t["group"][i] == "AP"]
        shown = [i for i in mine if t["group"][i] != "AP" or len(ap) <= MAX_AP_ROWS]
        if len(ap) > MAX_AP_ROWS:
            notes.append(f"{camera_id}: {len(ap)} APs, in the AP table below (folded) and parameters.csv")
        for i in shown:
            spec = _UNIT_FORMAT.get(str(t["unit"][i]), ".6g")
            value, start, sigma = float(t["value"][i]), float(t["start"][i]), float(t["sigma"][i])
            active = bool(t["active"][i])
            ratio = abs(value - start) / sigma if active and sigma > 0 else None
            rows.append(([camera_id] if many else []) +
                        [t["parameter"][i], t["unit"][i], fmt(start, spec), fmt(value, spec), fmt(value - start, spec),
                         fmt(sigma if active else None, ".3g"), fmt(ratio, ".1f"), "estimated" if active else "held"])
    if not rows:
        return
    header = (["camera"] if many else []) + ["parameter", "unit", "initial", "adjusted", "adjusted − initial", "σ",
                                             "|Δ|/σ", ""]
    text = {0, 1, 2, 9} if many else {0, 1, 8}
    more = len(rows) - MAX_CAMERA_CHANGE_ROWS
    page.table(header, rows[:MAX_CAMERA_CHANGE_ROWS], text_columns=text, ident="camera-change")
    page.paragraph("Initial = the start value of the adjustment (the block's camera, or the calibration it was "
                   "given), adjusted ± σ its a-posteriori estimate; |Δ|/σ = |adjusted − initial| / σ. From "
                   "parameters.csv" + (f"; {more} more rows there" if more > 0 else "") + "."
                   + (f" {'; '.join(notes)}." if notes else ""), "note")


def _residual_cameras(results) -> np.ndarray:
    """The camera of each row of residuals.csv (through its image)."""
    images = results.tables["images"]
    camera_of = dict(zip(images["image_id"], images["camera_id"]))
    return np.array([camera_of.get(i) for i in results.tables["residuals"]["image_id"]], dtype=object)


def _camera_rows(results, cameras: np.ndarray, camera_id: str) -> dict[str, np.ndarray]:
    """The used observations of one camera, in pixel axes: col, row, v along col and row."""
    res = results.tables["residuals"]
    pick = (cameras == camera_id) & (res["rejected"] == 0) & np.isfinite(res["vx_px"]) & np.isfinite(res["vy_px"])
    return {"col": res["col_px"][pick], "row": res["row_px"][pick],
            "vcol": res["vx_px"][pick], "vrow": -res["vy_px"][pick]}


def _cameras_to_draw(results, cameras: np.ndarray) -> list[str]:
    """At most MAX_CAMERA_FIGURES cameras, those with the most observations first."""
    names, counts = np.unique(cameras.astype(str), return_counts=True)
    count = dict(zip(names, counts))
    order = sorted(results.camera.get("cameras", {}), key=lambda c: -count.get(c, 0))
    return order[:MAX_CAMERA_FIGURES]


def _grid_of(results, camera: dict) -> tuple[int, int]:
    grid = camera.get("ap", {}).get("grid") or results.summary.get("grid") or (9, 6)
    return int(grid[0]), int(grid[1])


def _image_space_section(page: Page, files: dict, results) -> None:
    s = results.summary
    dist = results.tables.get("distortion_grid")
    cameras = results.camera.get("cameras", {})
    of_residual = _residual_cameras(results)
    chosen = _cameras_to_draw(results, of_residual)
    if len(cameras) > len(chosen):
        page.paragraph(f"{len(cameras)} cameras; the image-space figures show the {len(chosen)} with the most "
                       "observations (all are in distortion_grid.csv and residuals.csv).", "note")
    for k, camera_id in enumerate(chosen):
        cam = cameras[camera_id]
        width, height = float(cam["width_px"]), float(cam["height_px"])
        suffix = f"-{k + 1}" if len(chosen) > 1 else ""
        label = f"camera {camera_id}" if len(cameras) > 1 else "camera"
        model = cam.get("ap", {}).get("spec", s.get("ap_model", ""))
        pick = None if dist is None else dist["camera_id"] == camera_id if "camera_id" in dist else \
            np.ones(len(dist["col"]), bool)
        if pick is not None and pick.any():
            fig = figures.distortion_figure(dist["col"][pick], dist["row"][pick], dist["dcol"][pick],
                                            dist["drow"][pick], width, height, f"Estimated distortion Δ, {model}")
            _add_figure(page, files, fig, f"distortion{suffix}",
                        f"Estimated distortion Δ of the {label} ({model}, active APs only) on a "
                        f"{int(np.unique(dist['col'][pick]).size)}-column grid: colour |Δ|, arrows on every 4th "
                        "node, along the pixel axes (column right, row down).")
        obs = _camera_rows(results, of_residual, camera_id)
        grid = _grid_of(results, cam)
        fig = figures.residual_grid_figure(obs["col"], obs["row"], obs["vcol"], obs["vrow"], width, height, grid,
                                           "Grid-averaged image residuals")
        _add_figure(page, files, fig, f"residual-grid{suffix}",
                    f"Image residuals v = adjusted − observed of the {label}, averaged in {grid[0]}×{grid[1]} "
                    f"cells ({obs['col'].size} observations, rejected ones excluded): the systematic error "
                    "the AP model left.")
        redundancy = float(s.get("mean_redundancy_image") or 1.0)
        fig = figures.residual_histogram_figure(obs["vcol"], -obs["vrow"], float(s.get("sigma0_px") or 0.0),
                                                redundancy, f"Image residuals of the {label}")
        _add_figure(page, files, fig, f"residual-histogram{suffix}",
                    "Histograms of v_x (right) and v_y (up) with bins of width σ̂0 and the share within ±σ̂0. "
                    f"A residual has σ̂0·√r (r its redundancy number; mean r = {redundancy:.3f}), so the curve, "
                    "the normal density with σ̂0·√r̄, and the expected share are those of the residuals.")


def _point_rows(results):
    pts = results.tables["points"]
    role = pts["role"]
    ctl = (role == "gcp") | (role == "chk")
    d = np.column_stack([pts["dX_m"], pts["dY_m"], pts["dZ_m"]])
    sigma = np.column_stack([pts["sigma_X_m"], pts["sigma_Y_m"], pts["sigma_Z_m"]])
    w = np.column_stack([pts.get(f"w_{c}", np.full(len(role), np.nan)) for c in "XYZ"])
    return pts, ctl, d, sigma, w


def _track_section(page: Page, files: dict, results) -> None:
    """check_points.csv of seed 001's cases: errors across / along track and up at the scene centre."""
    t = results.tables["check_points"]
    xy = np.column_stack([t["x_across_km"], t["y_along_km"]]) * 1000.0
    d = np.column_stack([t["d_across_m"], t["d_along_m"], t["d_up_m"]])
    _add_figure(page, files, figures.control_error_figure(xy, d, np.array(["chk"] * len(d), object), list(t["point_id"]),
                                                          "Errors at the check points (axes: across / along track)"),
                "check-points", f"Check-point errors ({results.summary.get('check_method', '')}): estimated minus "
                "reference, across track (X) and along track (Y) at the scene centre, and up (Z).")
    page.table(["point", "role", "X across [km]", "Y along [km]", "dX [m]", "dY [m]", "dZ [m]"],
               [[p, r, f"{x:.2f}", f"{y:.2f}", f"{a:.3f}", f"{b:.3f}", f"{c:.3f}"]
                for p, r, x, y, a, b, c in zip(t["point_id"], t["role"], t["x_across_km"], t["y_along_km"],
                                               t["d_across_m"], t["d_along_m"], t["d_up_m"])], text_columns=2,
               ident="check-points")


def _control_section(page: Page, files: dict, results) -> None:
    if "check_points" in results.tables:
        _track_section(page, files, results)
        return
    pts, ctl, d, sigma, w = _point_rows(results)
    critical = float((results.summary.get("snooping") or {}).get("critical") or 3.0)
    if not ctl.any():
        page.paragraph("The block has no control or check points (free network): no object-space errors.", "note")
        return
    xy = np.column_stack([pts["X"], pts["Y"]])[ctl]
    fig = figures.control_error_figure(xy, d[ctl], pts["role"][ctl], list(pts["point_id"][ctl]),
                                       "Errors at control and check points (adjusted − reference)")
    _add_figure(page, files, fig, "control-errors",
                "Errors at check points (circles) and residuals at control points (triangles), adjusted − "
                "reference: in plan (left) and in height (right, arrows up where the adjusted point is too high).")
    rows, flags = [], []
    for i in np.flatnonzero(ctl):
        role = pts["role"][i]
        if role == "chk":
            z = np.abs(d[i]) / sigma[i]
            flag = bool(np.nanmax(z) > 3.0) if np.isfinite(z).any() else False
            test = f"|d|/σ {np.nanmax(z):.1f}" if np.isfinite(z).any() else ""
        else:
            flag = bool(np.nanmax(np.abs(w[i])) > critical) if np.isfinite(w[i]).any() else False
            test = f"|w| {np.nanmax(np.abs(w[i])):.1f}" if np.isfinite(w[i]).any() else ""
        rows.append([pts["point_id"][i], role, fmt(d[i, 0]), fmt(d[i, 1]), fmt(d[i, 2]),
                     fmt(float(np.hypot(d[i, 0], d[i, 1]))), fmt(sigma[i, 0], ".4f"), fmt(sigma[i, 1], ".4f"),
                     fmt(sigma[i, 2], ".4f"), int(pts["n_images"][i]), test, "⚑" if flag else ""])
        flags.append(flag)
    page.table(["point", "role", "dX [m]", "dY [m]", "dZ [m]", "|dXY| [m]", "σX [m]", "σY [m]", "σZ [m]", "images",
                "test", "flag"], rows, text_columns=2, flagged=flags, ident="control-points")
    page.paragraph(f"d = adjusted − reference. Check points are flagged when a coordinate error exceeds 3σ, σ the "
                   "a-posteriori standard deviation of the adjusted point (the reference's own error is not "
                   f"included); control points when Baarda's w of a coordinate exceeds {critical:g}.", "note")


def _control_loo_section(page: Page, results) -> None:
    """control_loo.csv as a table: each control point's error when it is left out of the control (issue 40)."""
    loo = results.tables.get("control_loo")
    if loo is None or not len(loo["point_id"]):
        return
    s = results.summary.get("control_loo") or {}
    fails = np.asarray(loo["fails"]) == 1
    rows = [[loo["point_id"][i], loo["role"][i], fmt(loo["dX_m"][i]), fmt(loo["dY_m"][i]), fmt(loo["dZ_m"][i]),
             fmt(loo["sigma_X_m"][i]), fmt(loo["sigma_Y_m"][i]), fmt(loo["sigma_Z_m"][i]),
             fmt(loo["w_X"][i], ".2f"), fmt(loo["w_Y"][i], ".2f"), fmt(loo["w_Z"][i], ".2f"),
             fmt(loo["T_3d"][i], ".1f"), fmt(loo["p"][i], ".3g"), "⚑" if fails[i] else ""]
            for i in range(len(loo["point_id"]))]
    page.table(["point", "role", "dX [m]", "dY [m]", "dZ [m]", "σX [m]", "σY [m]", "σZ [m]", "w_X", "w_Y", "w_Z",
                "T", "p", "flag"], rows, text_columns=2, flagged=list(fails), ident="control-loo")
    page.paragraph("Leave-one-out: each control point left out of the control in turn, the block re-adjusted "
                   "without it; d = its estimate then − its surveyed coordinates, σ the a-priori standard deviation "
                   "of d (the estimate's and the survey's), w = d / σ, T = dᵀ C⁻¹ d ~ χ²(3) where the coordinates "
                   f"fit; flagged where T exceeds {fmt(s.get('critical_t3'), '.1f')} (the significance of the "
                   "w-test). Role 'demoted': checked instead by the tests, its error is the adjustment's own.",
                   "note")


def _terrain_section(page: Page, results) -> None:
    """summary.json terrain_observations and terrain.csv's rejected heights (issue 42); nothing without them."""
    t = results.summary.get("terrain_observations")
    if not t:
        return
    page.paragraph(f"Terrain as observations: {t['n_used']} tie points' heights from the DEM {t.get('dem') or ''} "
                   f"(σ {fmt(t.get('sigma_apriori_m'), '.3g')} m given, {fmt(t.get('sigma_m'), '.3g')} m in the final "
                   f"adjustment; redundancy {fmt(t.get('redundancy'), '.1f')}), {t['n_rejected']} rejected by data "
                   f"snooping, {t['n_off_dem']} tie points off the DEM. v = h − H (adjusted ellipsoidal height "
                   f"minus the DEM's) and Baarda's w in terrain.csv.", "note")
    table = results.tables.get("terrain")
    if table is None:
        return
    rejected = np.flatnonzero(np.asarray(table["status"]) == "rejected")
    if rejected.size:
        rows = [[table["point_id"][i], fmt(table["lat_deg"][i], ".6f"), fmt(table["lon_deg"][i], ".6f"),
                 fmt(table["v_m"][i], ".2f"), fmt(table["w"][i], ".1f")] for i in rejected]
        page.table(["point", "lat [°]", "lon [°]", "v [m]", "w when rejected"], rows, text_columns=1,
                   ident="terrain-rejected")


def _precision_section(page: Page, files: dict, results) -> None:
    pts = results.tables["points"]
    tie = pts["role"] == "tie"
    if not tie.any():
        return
    xy = np.column_stack([pts["X"], pts["Y"]])[tie]
    sigma = np.column_stack([pts["sigma_X_m"], pts["sigma_Y_m"], pts["sigma_Z_m"]])[tie]
    fig = figures.precision_map_figure(xy, sigma, f"A-posteriori precision of {int(tie.sum())} tie points")
    _add_figure(page, files, fig, "tie-precision",
                "A-posteriori standard deviations of the tie points (σ̂0² times the cofactor): σ_XY = "
                "sqrt(σX² + σY²) and σ_Z.")


def _correlation_section(page: Page, files: dict, results) -> None:
    corr = results.tables["correlation"]
    names = [str(n) for n in corr.get("parameter", [])]
    if len(names) < 2:
        page.paragraph("Fewer than two camera parameters are estimated: no correlation matrix.", "note")
        return
    rho = np.column_stack([corr[n] for n in names])
    groups, previous = [], None
    for k, name in enumerate(names):
        camera, _, parameter = name.partition(":")
        if camera != previous:
            groups.append((k, camera))
            previous = camera
        elif parameter not in ("c", "x0", "y0") and names[k - 1].partition(":")[2] in ("c", "x0", "y0"):
            groups.append((k, "AP"))
    fig = figures.correlation_figure(names, rho, "Correlations of the interior orientation and the APs", groups)
    _add_figure(page, files, fig, "correlation",
                "Correlation matrix of the estimated interior orientation (c, x0, y0) and the active APs, "
                "from the a-posteriori covariance; the full matrix is in correlation.csv.")


def _camera_section(page: Page, results) -> None:
    dropped = {}
    for entry in (results.screening or {}).get("dropped", []):
        dropped[(entry.get("camera_id"), entry.get("name"))] = entry
    for camera_id, cam in results.camera.get("cameras", {}).items():
        page.heading(f"Camera {camera_id} ({cam.get('model', 'frame')})", 3)
        rows = []
        for key, e in cam.items():
            if not isinstance(e, dict) or "value" not in e:
                continue
            entry = dropped.get((camera_id, key.rsplit("_", 1)[0])) or dropped.get((camera_id, key))
            state = "estimated" if e.get("estimated") else (f"dropped in round {entry['round']}" if entry else "fixed")
            rows.append([key, fmt(e.get("value"), ".6g"), fmt(e.get("sigma"), ".3g"), state])
        page.table(["camera parameter", "value", "σ", ""], rows)
        ap = cam.get("ap", {})
        coefficients = ap.get("coefficients", [])
        if not coefficients:
            continue
        extra = cam.get("extrapolation")
        if extra:
            page.paragraph(f"Correction at most {extra['max_inside_px']:.2f} px over the observed area "
                           f"({100 * extra['observed_share']:.0f} % of the frame's cells hold observations), "
                           f"{extra['max_outside_px']:.2f} px where none lies"
                           + (": extrapolated, not supported there." if extra.get("warning") else "."),
                           "bad" if extra.get("warning") else "note")
        rows, ts = [], []
        for c in coefficients:
            value, sigma = c.get("value_px"), c.get("sigma_px")
            t = abs(value) / sigma if value is not None and sigma else None
            entry = dropped.get((camera_id, c["name"]))
            outcome = "kept" if c.get("active") else "held at its given value" if c.get("held") else (
                f"dropped in round {entry['round']}: {entry['reason']}" if entry else "not estimated")
            rows.append([c["name"], fmt(value, ".4f"), fmt(sigma, ".4f"), fmt(t, ".1f"), outcome])
            ts.append(-1.0 if t is None else t)
        header = ["AP", "value [px]", "σ [px]", "t", "screening"]
        said = f"{ap.get('spec', '')}: {ap.get('n_active', 0)} of {len(coefficients)} coefficients active " \
               "(in pixels; t = |value|/σ)"
        if len(rows) <= MAX_AP_ROWS:
            page.paragraph(f"{said}.", "note")
            page.table(header, rows, text_columns={0, 4}, ident=f"ap-{camera_id}")
            continue
        # a long table (wavelet APs): the coefficients with the largest t, folded; every one is in parameters.csv
        largest = sorted(np.argsort(-np.asarray(ts), kind="stable")[:MAX_AP_ROWS])
        page.paragraph(f"{said}. The full table of all {len(rows)} coefficients (value, σ, start value, active) "
                       "is in parameters.csv (group AP), their screening in screening.json.", "note")
        page.add(f'<details id="ap-fold-{html.escape(camera_id)}"><summary>The {MAX_AP_ROWS} coefficients with the '
                 f"largest t of {len(rows)} (in their order; all in parameters.csv)</summary>")
        page.table(header, [rows[i] for i in largest], text_columns={0, 4}, ident=f"ap-{camera_id}")
        page.add("</details>")


def _trajectory_section(page: Page, results) -> None:
    traj = results.tables.get("trajectory")
    if traj is None or not len(traj["sensor"]):
        return
    page.heading("Trajectory: strip-wise shift and drift, mounting", 3)
    dropped = {entry.get("name"): entry for entry in (results.screening or {}).get("dropped", [])}

    def state(i: int) -> str:
        if traj["active"][i] == 1:
            return "estimated"
        entry = dropped.get(f"{traj['sensor'][i]} {traj['strip_id'][i]} {traj['term'][i]} {traj['axis'][i]}")
        return f"dropped in round {entry['round']} (t = {entry['t']:.2f})" if entry else "dropped by screening"

    rows = [[traj["sensor"][i], traj["strip_id"][i], traj["term"][i], traj["axis"][i],
             fmt(traj["value"][i], ".5f"), fmt(traj["sigma"][i], ".5f"), traj["unit"][i], state(i)]
            for i in range(len(traj["sensor"]))]
    page.paragraph("GNSS positions and IMU attitudes observed as P0 + D0 + D1·Δt + D2·Δt² per strip (Eq. 12 of "
                   "seed 000), Δt from the strip's middle; a lever arm (camera frame) or boresight angles "
                   "when estimated. Also in trajectory.csv.", "note")
    page.table(["sensor", "strip", "term", "axis", "value", "σ", "unit", ""], rows, text_columns={0, 1, 2, 3, 6, 7},
               ident="trajectory")


def _joint_tests_section(page: Page, results) -> None:
    """The joint F-test of everything screening dropped, after its last round: per group (APs, GNSS, IMU, each
    sensor's strip) when the block has GNSS/IMU, else of the dropped set as a whole."""
    tests = (results.screening or {}).get("joint_tests", [])
    if not tests:
        return
    last = tests[-1]
    groups = last.get("groups") or [dict(last, group="all dropped")]
    page.heading("Screening: joint tests of the dropped parameters", 3)
    page.paragraph(f"After round {last['round']}: F = (increase of the weighted sum of squared residuals / σ̂0²) / "
                   "n dropped against its 1 − α quantile; a significant group would mean that parameters dropped "
                   "one at a time are jointly there. Every decision is in screening.json.", "note")
    rows = [[g["group"], str(g["n_dropped"]), fmt(g["f_statistic"], ".3f"), fmt(g["f_critical"], ".3f"),
             "significant" if g["jointly_significant"] else "passes"] for g in groups]
    page.table(["group", "dropped", "F", "F critical", ""], rows, text_columns={0, 4}, ident="joint-tests")


def _screening_prediction_section(page: Page, results) -> None:
    """What the screening removed per group and what that cost or gained in the cross-validated prediction error
    of held-out tie points (screening.json ``prediction``)."""
    prediction = (results.screening or {}).get("prediction")
    if not prediction:
        return
    page.heading("Screening: what it cost in prediction", 3)
    if prediction.get("note"):
        page.paragraph(prediction["note"], "note")
        return
    page.paragraph(f"Prediction error of held-out tie points ({prediction['n_folds']} folds, "
                   f"{prediction['n_rays']} rays): {prediction['unscreened_cv_rmse_px']:.5f} ± "
                   f"{prediction['unscreened_cv_se_px']:.5f} px unscreened, {prediction['screened_cv_rmse_px']:.5f} px "
                   f"screened ({prediction['change_px']:+.6f} px). Per group: the error with that group's drops "
                   "alone (+ a loss, − a gain), in the unscreened adjustment's linearisation."
                   + (f" {prediction['stopped']}." if prediction.get("stopped") else ""), "note")
    rows = [[g["group"], str(g["n_removed"]), fmt(g["cv_rmse_px"], ".5f"), fmt(g["change_px"], "+.6f")]
            for g in prediction.get("groups", [])]
    page.table(["group", "removed", "prediction error [px]", "change [px]"], rows, text_columns={0},
               ident="screening-prediction")


#: images drawn in the attitude-correction figure at most (all are in attitude_corrections.csv)
MAX_ATTITUDE_IMAGES = 8


def _attitude_section(page: Page, files: dict, results) -> None:
    """attitude_corrections.csv of line scanners: the corrections along each image with their sigma."""
    t = results.tables.get("attitude_corrections")
    if t is None or not len(t["image_id"]):
        return
    # the axes the adjustment corrected (a held one is zero with sigma zero everywhere)
    axes = [k[:-5] for k in t if k.endswith("_urad") and not k.startswith("sigma_")
            and (np.any(t[k] != 0) or np.any(t[f"sigma_{k}"] != 0))]
    if not axes:
        return
    series = []
    for image_id in list(dict.fromkeys(t["image_id"]))[:MAX_ATTITUDE_IMAGES]:
        mine = t["image_id"] == image_id
        series.append((image_id, t["line"][mine], np.column_stack([t[f"{a}_urad"][mine] for a in axes]),
                       np.column_stack([t[f"sigma_{a}_urad"][mine] for a in axes])))
    page.heading("Attitude corrections along the images", 3)
    _add_figure(page, files, figures.attitude_correction_figure(series, axes, "Attitude corrections"),
                "attitude-corrections",
                f"The estimated corrections of {', '.join(axes)} along each image (line), with ±σ (the "
                "coefficients' covariance carried through). Also in attitude_corrections.csv.")
    rows = []
    for image_id, lines, values, sigmas in series:
        worst = np.argmax(sigmas, axis=0)
        rows += [[image_id, a, fmt(values[0, k], ".2f"), fmt(values[len(lines) // 2, k], ".2f"),
                  fmt(values[-1, k], ".2f"), fmt(sigmas[worst[k], k], ".2f")] for k, a in enumerate(axes)]
    page.table(["image", "axis", "first line [µrad]", "centre [µrad]", "last line [µrad]", "largest σ [µrad]"],
               rows, text_columns={0, 1}, ident="attitude")


def _images_section(page: Page, results) -> None:
    """images.csv: each image's parameters with their sigma (the columns its sensor writes)."""
    im = results.tables["images"]
    values = [k for k in im if k not in ("image_id", "camera_id", "strip_id", "n_points") and not k.startswith("sigma_")]
    sigmas = [k for k in im if k.startswith("sigma_")]
    rows = [[im["image_id"][i], im["strip_id"][i]] + [fmt(im[k][i], ".6g") for k in values] +
            [fmt(im[k][i], ".3g") for k in sigmas] + [int(im["n_points"][i])] for i in range(len(im["image_id"]))]
    page.table(["image", "strip"] + values + sigmas + ["points"], rows, text_columns=2, ident="images")


def _parameters_section(page: Page, results) -> None:
    """parameters.csv: the calibration parameters of the sensors with their start values (up to 20 images)."""
    t = results.tables.get("parameters")
    if t is None:
        return
    owners = set(results.tables["images"]["image_id"])
    show = np.array([(g != "AP" and (o not in owners or len(owners) <= 20)) for o, g in zip(t["owner"], t["group"])])
    if not show.any():
        return
    page.heading("Calibration parameters", 3)
    rows = [[t["owner"][i], t["parameter"][i], fmt(t["value"][i], ".6g"), fmt(t["sigma"][i], ".3g"),
             fmt(t["start"][i], ".6g"), t["unit"][i],
             fmt(abs(t["value"][i] - t["start"][i]) / t["sigma"][i], ".1f") if t["active"][i] and t["sigma"][i] > 0
             else "–", "estimated" if t["active"][i] else "held"]
            for i in np.flatnonzero(show)]
    page.paragraph("Every image and camera parameter of the sensors (parameters.csv): value, a-posteriori σ, start "
                   "value and t = |value − start| / σ; a held parameter keeps its start value.", "note")
    page.table(["owner", "parameter", "value", "σ", "start", "unit", "t", ""], rows, text_columns={0, 1, 5, 7},
               ident="parameters")


def _robust_section(page: Page, files: dict, results) -> None:
    """The robust cleaning: its loss and scale, the weights, and where the rejected observations lie."""
    s = results.summary
    robust = s.get("robust")
    if not robust:
        page.paragraph("No robust cleaning: least squares throughout (--robust none).", "note")
        return
    res = results.tables["residuals"]
    by = res.get("rejected_by", np.array([""] * len(res["image_id"]), dtype=object))
    page.paragraph(
        f"Robust cleaning before the tests: loss {robust['loss']} (c = {fmt(robust['c'], 'g')}), scale "
        f"{fmt(robust['scale'], '.3f')} × the a-priori σ (diagnosis: {robust['diagnosis']}); "
        f"{robust['n_rejected']} image observations ({fmt(100 * robust['share_rejected'], '.2f')} %) rejected as "
        f"gross errors (more than {fmt(robust['reject_u'], 'g')} robust σ), {robust.get('n_readmitted', 0)} taken "
        f"back after they fitted the cleaned adjustment; images left out: "
        f"{', '.join(robust.get('images_left_out') or []) or 'none'}; control checked instead: "
        f"{', '.join(d['point_id'] for d in robust.get('control_demoted') or []) or 'none'}; control or check points "
        f"lost: {', '.join(robust.get('control_lost') or []) or 'none'}.", "note")
    weight = np.asarray(res.get("robust_weight", np.ones(len(by))), float)
    u = np.asarray(res.get("robust_u", np.full(len(by), np.nan)), float)
    _add_figure(page, files, figures.robust_weight_figure(weight, u, float(robust["reject_u"]),
                                                          "Weights and residual sizes of the robust adjustment"),
                "robust-weights", "The robust adjustment's final weights (logarithmic counts) and each image "
                                  "point's residual size in robust σ with the rejection threshold.")
    cameras = _residual_cameras(results)
    rejected = res["rejected"] == 1
    names, counts = np.unique(res["image_id"][rejected].astype(str), return_counts=True)
    worst = [str(n) for n in names[np.argsort(-counts)][:MAX_REJECTION_PANELS]]
    if not worst:
        return
    camera = results.camera.get("cameras", {}).get(cameras[np.flatnonzero(res["image_id"] == worst[0])[0]], {})
    panels = []
    for name in worst:
        mine = res["image_id"] == name
        xy = np.column_stack([res["col_px"], res["row_px"]])
        panels.append((name, xy[mine & ~rejected], xy[mine & rejected & (by == "robust")],
                       xy[mine & rejected & (by != "robust")]))
    _add_figure(page, files, figures.rejection_map_figure(panels, float(camera.get("width_px", 1.0)),
                                                          float(camera.get("height_px", 1.0)),
                                                          "Where the rejected observations lie"),
                "rejection-map", f"The {len(worst)} images with the most rejected observations (red: robust "
                                 "cleaning, blue: data snooping, grey: kept); per image in residuals.csv.")
    rows = [[n, int(c)] for n, c in sorted(zip(names, counts), key=lambda x: -x[1])]
    page.table(["image", "rejected"], rows, text_columns=0, ident="rejected-per-image")


def _rejected_section(page: Page, results) -> None:
    res = results.tables["residuals"]
    rejected = np.flatnonzero(res["rejected"] == 1)
    s = results.summary
    if rejected.size == 0:
        page.paragraph("No observation was rejected.", "note")
        return
    by = np.asarray(res.get("rejected_by", np.full(len(res["rejected"]), "snooping", dtype=object)), dtype=object)
    robust = rejected[by[rejected] == "robust"]
    snooped = rejected[by[rejected] != "robust"]
    # data snooping's rejections by |w|, then the robust cleaning's by their size u
    order = np.concatenate([snooped[np.argsort(-np.abs(np.nan_to_num(res["w_test"][snooped])))],
                            robust[np.argsort(-np.nan_to_num(np.asarray(res.get("robust_u", np.zeros(0)),
                                                                        float)[robust] if robust.size else []))]])
    shown = order[:MAX_REJECTED_ROWS]
    u = np.asarray(res.get("robust_u", np.full(len(by), np.nan)), float)
    rows = [[res["image_id"][i], res["point_id"][i], "robust" if by[i] == "robust" else "snooping",
             fmt(res["col_px"][i], ".1f"), fmt(res["row_px"][i], ".1f"), fmt(res["vx_px"][i], ".2f"),
             fmt(res["vy_px"][i], ".2f"), fmt(res["w_test"][i], ".2f"), fmt(u[i], ".1f"),
             fmt(res["mdb_x_px"][i], ".2f"), fmt(res["mdb_y_px"][i], ".2f")] for i in shown]
    critical = (s.get("snooping") or {}).get("critical")
    cut = (s.get("robust") or {}).get("reject_u")
    page.paragraph(f"{snooped.size} image observations rejected by data snooping (|w| > {fmt(critical, 'g')}), "
                   f"largest |w| first, then {robust.size} by the robust cleaning (u > {fmt(cut, 'g')} robust σ), "
                   f"largest u first{f'; the first {len(shown)} shown, all in residuals.csv' if len(shown) < rejected.size else ''}. "
                   "v at the final estimate (empty where its point left the adjustment); w and the minimal "
                   "detectable blunder (MDB) of the adjustment that rejected it.", "note")
    page.table(["image", "point", "by", "col [px]", "row [px]", "v_x [px]", "v_y [px]", "|w|", "u", "MDB x [px]",
                "MDB y [px]"], rows, text_columns=3, ident="rejected")


def _notes_section(page: Page, s: dict) -> None:
    rounds = (s.get("snooping") or {}).get("rounds") or []
    if rounds:
        page.heading("Testing rounds", 3)
        page.table(["round", "rejected", "APs dropped", "largest |w|", "σ̂0 before [px]"],
                   [[r.get("round"), r.get("rejected"), r.get("dropped_aps"), fmt(r.get("largest_w"), ".2f"),
                     fmt(r.get("sigma0_px"), ".4f")] for r in rounds], text_columns=0)
    vc = s.get("variance_components")
    if vc:
        page.heading("Variance components", 3)
        page.table(["group", "observations", "redundancy", "a-priori σ", "a-posteriori σ", "unit"],
                   [[g.get("group"), g.get("n_observations"), fmt(g.get("redundancy"), ".1f"),
                     _join(g.get("sigma_apriori")), _join(g.get("sigma_aposteriori")), g.get("unit", "")]
                    for g in vc.get("groups", [])])
    messages = list(s.get("warnings") or []) + list(s.get("notes") or [])
    if messages:
        page.heading("Warnings and notes", 3)
        page.add("<ul>" + "".join(f"<li>{html.escape(str(m))}</li>" for m in messages) + "</ul>")


def _diagnosis_section(page: Page, s: dict) -> None:
    """summary.json ``diagnosis``: the findings, then each test with its statistic, critical value and power."""
    d = s.get("diagnosis")
    if not d:
        page.paragraph("No diagnosis: this results folder has none (no frame camera and no check points, or written "
                       "by an older selfcal).", "note")
        return
    page.add('<ul id="diagnosis-findings">' + "".join(f"<li>{html.escape(str(f))}</li>" for f in d["findings"])
             + "</ul>")
    fields = d.get("residual_field") or []
    if fields:
        page.table(["camera", "grid", "zones", "T", "critical", "largest zone", "its critical", "largest mean [px]",
                    "RMS of the means [px]", f"detectable RMS [px] ({d['power']:.0%})", "Moran's I", "its p",
                    "found"],
                   [[f["camera_id"], f"{f['grid'][0]}x{f['grid'][1]}", f["n_zones"], fmt(f["statistic"], ".1f"),
                     fmt(f["critical"], ".1f"), fmt(f["largest_zone_statistic"], ".1f"),
                     fmt(f["largest_zone_critical"], ".1f"), fmt(f["largest_zone_mean_px"], ".3f"),
                     fmt(f["rms_zone_mean_px"], ".3f"), fmt(f["detectable_rms_px"], ".3f"),
                     fmt(f["morans_i"], ".2f"), fmt(f["morans_p"], ".3f"), "yes" if f["found"] else "no"]
                    for f in fields], text_columns=2, flagged=[bool(f["found"]) for f in fields],
                   ident="diagnosis-field")
    dome = d.get("dome")
    if dome:
        page.table(["check points", "dome height at r_max [m]", "σ [m]", "r_max [m]", "t", "critical",
                    f"detectable height [m] ({d['power']:.0%})", "found"],
                   [[dome["n_points"], fmt(dome["dome_height_m"], "+.4f"), fmt(dome["sigma_dome_height_m"], ".4f"),
                     fmt(dome["radius_m"], ".1f"), fmt(dome["t"], ".2f"), fmt(dome["critical"], ".2f"),
                     fmt(dome["detectable_height_m"], ".4f"), "yes" if dome["found"] else "no"]],
                   text_columns=0, flagged=[bool(dome["found"])], ident="diagnosis-dome")
    page.paragraph(f"Tests at α = {d['alpha']:g} (the field's grids and statistics share it); a residual field is "
                   f"found when it is significant and a zone's mean reaches the practical size; the dome is "
                   f"dZ = a + b r² over the check points (James & Robson 2014).", "note")


def _join(values) -> str:
    if isinstance(values, (list, tuple)):
        return ", ".join(fmt(v, ".4g") for v in values)
    return fmt(values, ".4g")


def load_matplotlib() -> None:
    """Import what the figures are drawn with (matplotlib, its Figure, the Agg and SVG backends) whole: a signal
    that comes meanwhile waits for the import to finish (:func:`selfcal.interrupts.deferred`). Cut short inside a
    compiled module's import, it left a half-built extension that aborted the process at exit (``Fatal Python error:
    PyThreadState_Get``, once in 200 signals) or printed a traceback of the signal handler alone."""
    from .. import interrupts
    with interrupts.deferred():
        import matplotlib.backends.backend_agg  # noqa: F401
        import matplotlib.backends.backend_svg  # noqa: F401
        import matplotlib.colors  # noqa: F401
        import matplotlib.figure  # noqa: F401


def render_report(results: ResultsFolder, title: str | None = None,
                  say: Callable[[str], None] | None = None) -> dict:
    """The report of one adjustment: ``report.html`` and its figures, as data; ``say`` (if given) is called with
    each section's title as its rendering begins (the command line's progress: the figures take seconds)."""
    load_matplotlib()
    s = results.summary
    title = title or f"selfcal adjustment report: {s.get('block', '')}, {s.get('ap_model', '')}"
    page = Page(title)

    def heading(text: str, anchor: str) -> None:
        if say is not None:
            say(text)
        page.heading(text, anchor=anchor)
    files: dict = {}
    page.heading(title, 1)
    status = "converged" if s.get("converged") else "NOT CONVERGED"
    page.add(f'<p class="lede">{html.escape(status)} ({html.escape(str(s.get("convergence", "")))}); '
             f"{html.escape(_scenario_text(s))}every number below comes from summary.json, camera.json and the "
             "CSV tables beside this page.</p>")
    heading("Quality check", anchor="quality")
    _quality_section(page, s)
    heading("Camera layout and overlap", anchor="layout")
    _layout_section(page, files, results)
    heading("Processing parameters", anchor="processing")
    _processing_section(page, s)
    heading("Camera: initial against adjusted values", anchor="camera-change")
    _camera_change_section(page, results)
    heading("Summary", anchor="summary")
    _summary_section(page, s)
    heading("Accuracy statement (ASPRS Edition 2)", anchor="accuracy")
    _accuracy_section(page, s)
    heading("Diagnosis: what the adjustment left systematic", anchor="diagnosis")
    _diagnosis_section(page, s)
    heading("Image space: distortion and residuals", anchor="image-space")
    _image_space_section(page, files, results)
    heading("Uncertainty of the correction and the half-block check", anchor="correction-sigma")
    sigma_section(page, results, lambda page_, fig, stem, caption: _add_figure(page_, files, fig, stem, caption))
    heading("Object space: control and check points", anchor="control")
    _control_section(page, files, results)
    _control_loo_section(page, results)
    _terrain_section(page, results)
    heading("Precision and correlations", anchor="precision")
    _precision_section(page, files, results)
    _correlation_section(page, files, results)
    heading("Interior orientation and additional parameters", anchor="camera")
    _camera_section(page, results)
    calibration_precision_section(page, s)
    rolling_shutter_section(page, results)
    _parameters_section(page, results)
    heading("Exterior orientation", anchor="images")
    _images_section(page, results)
    _attitude_section(page, files, results)
    _trajectory_section(page, results)
    _joint_tests_section(page, results)
    _screening_prediction_section(page, results)
    heading("Rejected observations", anchor="rejected")
    _robust_section(page, files, results)
    _rejected_section(page, results)
    _notes_section(page, s)
    files["report.html"] = page.html()
    return files


def _scenario_text(s: dict) -> str:
    return f"scenario {s['scenario']}; " if s.get("scenario") else ""


def best_cells(rows: list[dict]) -> dict[str, dict]:
    """Per scenario, the row with the smallest check-point RMSD sqrt(XY² + Z²) (rows of report.compare)."""
    best: dict[str, tuple[float, dict]] = {}
    for row in rows:
        if row.get("error") or row.get("rmsd_xy_m") is None or row.get("rmsd_z_m") is None:
            continue
        score = math.hypot(row["rmsd_xy_m"], row["rmsd_z_m"])
        if row["scenario"] not in best or score < best[row["scenario"]][0]:
            best[row["scenario"]] = (score, row)
    return {k: v[1] for k, v in best.items()}


def render_comparison_report(rows: list[dict], table_markdown: str, links: dict[tuple[str, str], str],
                             title: str) -> dict:
    """Report of a (scenario x model) comparison: bar charts of Figs. 3-5 and the table.

    ``links`` maps (scenario, model) to the relative path of a rendered cell report.
    """
    load_matplotlib()
    page = Page(title)
    files: dict = {}
    page.heading(title, 1)
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    models = list(dict.fromkeys(r["ap_model"] for r in rows))
    index = {(r["scenario"], r["ap_model"]): r for r in rows}

    def table(key):
        out = np.full((len(scenarios), len(models)), np.nan)
        for i, sc in enumerate(scenarios):
            for j, m in enumerate(models):
                value = index.get((sc, m), {}).get(key)
                if value is not None:
                    out[i, j] = value
        return out
    specs = [("rmsd", {"RMSD XY": table("rmsd_xy_gsd"), "RMSD Z": table("rmsd_z_gsd")}, "[GSD]",
              "Accuracy at check points: RMSD(XY) and RMSD(Z) in GSD (Fig. 3 of seed 000)."),
             ("precision", {"RMS σ̂XY": table("rms_sigma_xy_gsd"), "RMS σ̂Z": table("rms_sigma_z_gsd")}, "[GSD]",
              "Precision of the tie points: RMS of the a-posteriori σ in GSD (Fig. 4 of seed 000)."),
             ("sigma0", {"σ̂0": table("sigma0_px")}, "[px]", "A-posteriori σ̂0 of an image coordinate (Fig. 5).")]
    for stem, values, unit, caption in specs:
        fig = figures.comparison_figure(scenarios, models, values, unit, caption.split(":")[0])
        _add_figure(page, files, fig, f"comparison-{stem}", caption)
    best = best_cells(rows)
    if best:
        page.heading("Best model per scenario", 2)
        items = []
        for scenario, row in best.items():
            link = links.get((scenario, row["ap_model"]))
            name = html.escape(row["ap_model"])
            target = f'<a href="{html.escape(link)}">{name}</a>' if link else name
            items.append(f"<li>{html.escape(scenario)}: {target} (RMSD XY {fmt(row['rmsd_xy_m'])} m, Z "
                         f"{fmt(row['rmsd_z_m'])} m at check points)</li>")
        page.add("<ul>" + "".join(items) + "</ul>")
        page.paragraph("Best = smallest sqrt(RMSD_XY² + RMSD_Z²) at the check points. Other cells: "
                       "selfcal report SCENARIO/MODEL renders their report.", "note")
    page.heading("Table", 2)
    page.add(f"<pre>{html.escape(table_markdown)}</pre>")
    files["report.html"] = page.html()
    return files
