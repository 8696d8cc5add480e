"""The report's rolling-shutter section: each rolling camera's readout, and the motion its images were read
during, per strip and per direction of flight (what Pix4D's "Rolling Shutter Statistics" give), from camera.json
and rolling_shutter.csv."""
from __future__ import annotations

import numpy as np

from .page import Page, fmt

__all__ = ["rolling_shutter_section", "COMPASS"]

#: the eight directions of flight the strips are grouped by (heading clockwise from +Y, "north")
COMPASS = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")


def _direction(heading_deg: float) -> str:
    return COMPASS[int(np.floor(((heading_deg + 22.5) % 360.0) / 45.0))]


def _mean_heading(headings: np.ndarray) -> float:
    h = np.radians(headings)
    return float(np.degrees(np.arctan2(np.sin(h).mean(), np.cos(h).mean())) % 360.0)


def rolling_shutter_section(page: Page, results) -> None:
    """Readout per rolling camera; per strip and per direction: images, speed, the projection centre's motion
    during the readout and the mean image motion between the first and the last line (the shear a global-shutter
    model would have to absorb: its sign follows the direction of flight in the image)."""
    table = results.tables.get("rolling_shutter")
    if table is None or not len(table["image_id"]):
        return
    page.heading("Rolling shutter", 3)
    rows = []
    for camera_id, cam in results.camera.get("cameras", {}).items():
        if cam.get("shutter") != "rolling":
            continue
        readout = cam.get("readout_ms") or {}
        state = "estimated" if readout.get("estimated") else "held (given, or screened out: a global shutter)"
        chi2, dof = readout.get("images_chi2"), readout.get("images_dof")
        rows.append([camera_id, fmt(readout.get("value"), ".3f"), fmt(readout.get("sigma"), ".3f"),
                     fmt(readout.get("sigma_adjustment"), ".3f"), fmt(readout.get("spread_between_images"), ".3f"),
                     f"{chi2:.1f} / {dof}" if chi2 is not None and dof is not None else "–",
                     cam.get("readout_direction", "down"), state])
    page.paragraph("Each image's pose is that of its middle line, at its time; an image point on a line read "
                   "dt = (line − lines/2)/lines × readout later was seen from X0 + v·dt, v the image's velocity from "
                   "its strip's positions and times (rolling_shutter.csv, with the values of every image). The "
                   "velocities are data with errors of their own, which the adjustment's σ does not know: an image "
                   "whose velocity is 2 % off sees a readout 2 % off. σ adds the spread of the images' own readouts "
                   "beyond their noise (χ² of their agreement over its degrees of freedom) to the adjustment's "
                   "σ.", "note")
    page.table(["camera", "readout [ms]", "σ [ms]", "σ of the adjustment [ms]", "spread between images [ms]",
                "images' χ² / dof", "lines read", ""], rows, text_columns={0, 5, 6, 7}, ident="rolling-readout")
    strips = list(dict.fromkeys(table["strip_id"].tolist()))
    shear = np.column_stack([table["shear_col_px"], table["shear_row_px"]])
    per_strip: list[list[str]] = []
    by_direction: dict[str, list[np.ndarray]] = {}
    for strip in strips:
        sel = np.flatnonzero(table["strip_id"] == strip)
        heading = _mean_heading(table["heading_deg"][sel])
        mean = shear[sel].mean(axis=0)
        per_strip.append([strip or "(none)", fmt(heading, ".1f"), _direction(heading), str(sel.size),
                          fmt(np.median(table["speed_m_s"][sel]), ".2f"), fmt(np.median(table["motion_m"][sel]), ".3f"),
                          fmt(mean[0], ".2f"), fmt(mean[1], ".2f"), fmt(float(np.hypot(*mean)), ".2f")])
        by_direction.setdefault(_direction(heading), []).append(sel)
    page.table(["strip", "heading [°]", "direction", "images", "speed [m/s]", "motion during readout [m]",
                "shear col [px]", "shear row [px]", "|shear| [px]"], per_strip, text_columns={0, 2},
               ident="rolling-strips")
    rows = []
    for direction in COMPASS:
        if direction not in by_direction:
            continue
        sel = np.concatenate(by_direction[direction])
        mean = shear[sel].mean(axis=0)
        rows.append([direction, str(len(by_direction[direction])), str(sel.size),
                     fmt(np.median(table["speed_m_s"][sel]), ".2f"), fmt(np.median(table["motion_m"][sel]), ".3f"),
                     fmt(mean[0], ".2f"), fmt(mean[1], ".2f")])
    page.paragraph("Per direction of flight: strips flown in opposite directions shear their images in opposite "
                   "senses, which no camera-wide AP field can take up; the rolling-shutter model does.", "note")
    page.table(["direction", "strips", "images", "speed [m/s]", "motion during readout [m]", "shear col [px]",
                "shear row [px]"], rows, text_columns={0}, ident="rolling-directions")
