"""Side by side with ISIS jigsaw: the Apollo 15 Metric network of ISIS's tests (../../../shared/data/isis).

Prints, for every value of EXPECTED_VALUES.txt, jigsaw's number, selfcal's and their ratio: per image the
residual RMS (sample, line, both; jigsaw's unit: pixels of the full scanned frame), the corrections of
X, Y, Z (km, J2000) and RA, DEC, TWIST (deg) with their a-posteriori sigmas; per spot-checked point the
sigmas of latitude, longitude and radius (m). Then selfcal's own results on the same network (data
snooping, variance components, self-calibration of the Metric camera) as one table.

Run: ``python compare.py [RESULTS] [EXPECTED_VALUES.txt]`` after ``run.sh`` (RESULTS defaults to results/ beside
this file, the expected values to ../shared/data/isis/EXPECTED_VALUES.txt). The tables are printed in Markdown: the
README's rows are copies of them, and tests/test_readme.py checks every one against a fresh run.
"""
from __future__ import annotations

import csv
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
EXPECTED = os.path.join(HERE, "..", "..", "..", "shared", "data", "isis", "EXPECTED_VALUES.txt")
#: cube k of jigsaw's bundleout is apolloImage k
AXES = ("X", "Y", "Z", "RA", "DEC", "TWIST")


def read_jigsaw(path: str = EXPECTED) -> dict:
    """jigsaw's Apollo results of EXPECTED_VALUES.txt: ``images`` cube number -> {rms_sample, rms_line, rms,
    and per axis (initial, correction, final, a-priori sigma, adjusted sigma)}; ``points`` id -> {sigma_lat_m,
    sigma_lon_m, sigma_radius_m, lat, lon, radius_km}."""
    images, points = {}, {}
    with open(path, encoding="utf-8") as handle:
        lines = handle.read().splitlines()
    section = None
    for line in lines:
        text = line.strip()
        if text.startswith("- spot-checked points"):
            section = "points"
        elif text.startswith("- spot-checked measures") or text.startswith("LRO NAC"):
            section = None
        if text.startswith("cube") and "|" in text:
            parts = [p.strip() for p in text.split("|")]
            name, rms = parts[0].split(" ", 1)
            rs, rl, rt = (float(v) for v in rms.split(","))
            entry = {"rms_sample": rs, "rms_line": rl, "rms": rt}
            for part in parts[1:]:
                axis, values = part.split(" ", 1)
                entry[axis] = tuple(float(v) for v in values.split(","))
            images[int(name[4:])] = entry
        elif section == "points" and text.startswith("AS15_"):
            v = text.split(",")
            points[v[0]] = {"lat": float(v[5]), "lon": float(v[6]), "radius_km": float(v[7]),
                            "sigma_lat_m": float(v[8]), "sigma_lon_m": float(v[9]), "sigma_radius_m": float(v[10])}
    return {"images": images, "points": points}


def _table(path: str, key: str) -> dict:
    with open(path, newline="", encoding="utf-8") as handle:
        return {row[key]: row for row in csv.DictReader(handle)}


def image_rows(results: str, jigsaw: dict) -> list[tuple[str, float, float]]:
    """(quantity, jigsaw, selfcal) of every image value, from a results folder's isis_images.csv."""
    ours = _table(os.path.join(results, "isis_images.csv"), "image_id")
    rows = []
    for k, theirs in sorted(jigsaw["images"].items()):
        mine = ours.get(f"apolloImage{k}")
        if mine is None:                 # left out of the adjustment (the robust cleaning names it)
            continue
        rows += [(f"cube{k} residual RMS sample [px]", theirs["rms_sample"], float(mine["rms_sample_px"])),
                 (f"cube{k} residual RMS line [px]", theirs["rms_line"], float(mine["rms_line_px"])),
                 (f"cube{k} residual RMS [px]", theirs["rms"], float(mine["rms_px"]))]
        for axis in AXES:
            initial, correction, final, apriori, sigma = theirs[axis]
            unit = "km" if axis in "XYZ" else "deg"
            rows += [(f"cube{k} {axis} correction [{unit}]", correction, float(mine[f"d{axis}_{unit}"])),
                     (f"cube{k} {axis} sigma [{unit}]", sigma, float(mine[f"sigma_{axis}_{unit}"]))]
    return rows


def point_rows(results: str, jigsaw: dict) -> list[tuple[str, float, float]]:
    """(quantity, jigsaw, selfcal) of the spot-checked points, from isis_points.csv."""
    ours = _table(os.path.join(results, "isis_points.csv"), "point_id")
    rows = []
    for point_id, theirs in jigsaw["points"].items():
        mine = ours[point_id]
        for key in ("lat", "lon", "radius"):
            rows.append((f"{point_id} sigma {key} [m]", theirs[f"sigma_{key}_m"], float(mine[f"sigma_{key}_m"])))
    return rows


def _print(rows) -> None:
    print("| quantity | jigsaw | selfcal | ratio |\n|---|---:|---:|---:|")
    for name, theirs, mine in rows:
        ratio = mine / theirs if theirs else float("nan")
        print(f"| {name} | {theirs:.6g} | {mine:.6g} | {ratio:.4f} |")


def _summary(folder: str) -> dict:
    with open(os.path.join(folder, "summary.json"), encoding="utf-8") as handle:
        return json.load(handle)


def extras(results: str) -> None:
    """selfcal's own tests on the network, one line per run."""
    print("\n| run | sigma0 [px] | rejected | cube7 RMS [px] | notes |\n|---|---:|---:|---:|---|")
    for name, label in (("jigsaw", "jigsaw's settings (no snooping)"), ("snooped", "data snooping k = 3"),
                        ("variance", "snooping + variance components"), ("selfcal", "self-calibration, screened")):
        folder = os.path.join(results, name)
        if not os.path.isdir(folder):
            continue
        s = _summary(folder)
        cube7_row = _table(os.path.join(folder, "isis_images.csv"), "image_id").get("apolloImage7")
        cube7 = "left out" if cube7_row is None else f"{float(cube7_row['rms_px']):.3f}"
        notes = []
        if s.get("variance_components"):
            notes += [f"{g['group']} sigma {g['sigma_apriori'][0]:.3g} -> {g['sigma_aposteriori'][0]:.3g} {g['unit']}"
                      for g in s["variance_components"]["groups"]]
        if name == "snooped" or name == "selfcal":
            with open(os.path.join(folder, "residuals.csv"), newline="", encoding="utf-8") as handle:
                rejected = [r["image_id"] for r in csv.DictReader(handle) if r["rejected"] == "1"]
            by_image = {i: rejected.count(i) for i in sorted(set(rejected))}
            notes.append("rejected per image " + ", ".join(f"{i} {n}" for i, n in by_image.items()))
        if name == "selfcal":
            with open(os.path.join(folder, "camera.json"), encoding="utf-8") as handle:
                camera = next(iter(json.load(handle)["cameras"].values()))
            for key in ("focal_mm", "x0_mm", "y0_mm"):
                e = camera[key]
                sigma = "held" if e["sigma"] is None else f"± {e['sigma']:.4f}"
                notes.append(f"{key} {e['value']:.4f} {sigma}")
            ap = camera["ap"]
            kept = [c["name"] for c in ap["coefficients"] if c["active"]]
            notes.append(f"{ap['spec']}: {len(kept)}/{len(ap['coefficients'])} kept ({', '.join(kept)})")
        print(f"| {label} | {s['sigma0_px']:.3f} | {s['n_obs_rejected']} | {cube7} | " + "; ".join(notes) + " |")


def main() -> None:
    results = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "results")
    jigsaw = read_jigsaw(sys.argv[2] if len(sys.argv) > 2 else EXPECTED)
    rows = image_rows(os.path.join(results, "jigsaw"), jigsaw) + point_rows(os.path.join(results, "jigsaw"), jigsaw)
    _print(rows)
    extras(results)


if __name__ == "__main__":
    main()
