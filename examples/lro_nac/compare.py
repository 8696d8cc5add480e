"""Side by side with ISIS jigsaw: the LRO NAC pair of ISIS's tests (../../../shared/data/isis/lro_nac_pair).

Prints, for every LRO value of EXPECTED_VALUES.txt, jigsaw's number, selfcal's and their ratio: the mean and
largest residual (px; the magnitude of each measure's residual, ISIS's AverageResidual and
GetMaximumResidual) and the mean, standard deviation, minimum and maximum of the adjusted points' X, Y, Z
(km, body-fixed), for each run of ``run.sh`` (``no_twist``: jigsaw's options; ``twist``: with the rotation about
the sensor's Z free as well; ``degree1``: bias and drift only; ``radii_free``: bias and
drift, the points free in 3-D).

Then one summary table of the runs (the README's). Every table is printed in Markdown: the README's rows are copies
of them, and tests/test_readme.py checks every one against a fresh run.

Run: ``python compare.py [RESULTS] [EXPECTED_VALUES.txt]`` after ``run.sh`` (RESULTS defaults to results/ beside
this file, the expected values to ../shared/data/isis/EXPECTED_VALUES.txt).
"""
from __future__ import annotations

import csv
import math
import os
import re
import statistics
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
EXPECTED = os.path.join(HERE, "..", "..", "..", "shared", "data", "isis", "EXPECTED_VALUES.txt")
RUNS = {"no_twist": "jigsaw's options (RA, DEC of degree 3, no twist)",
        "twist": "RA, DEC and TWIST of degree 3",
        "degree1": "RA and DEC of degree 1 (bias and drift)",
        "radii_free": "RA and DEC of degree 1, the points' radii free"}
STATISTICS = ("mean", "sd", "min", "max")


def read_jigsaw(path: str = EXPECTED) -> dict:
    """jigsaw's LRO NAC results of EXPECTED_VALUES.txt: ``mean_residual_px``, ``max_residual_px`` and
    ``points``: axis -> {mean, sd, min, max} (km)."""
    with open(path, encoding="utf-8") as handle:
        text = handle.read()
    section = text[text.index("LRO NAC pair: jigsaw"):]
    found = re.search(r"mean residual ([0-9.]+) px, maximum residual ([0-9.]+) px", section)
    out = {"mean_residual_px": float(found.group(1)), "max_residual_px": float(found.group(2)), "points": {}}
    for axis, values in re.findall(r"\b([XYZ]) (mean [-0-9.e]+ sd [-0-9.e]+ min [-0-9.e]+ max [-0-9.e]+)", section):
        words = values.split()
        out["points"][axis] = {words[k]: float(words[k + 1]) for k in range(0, 8, 2)}
    return out


def read_selfcal(results: str) -> dict:
    """The same values from a selfcal results folder (residuals.csv, points.csv)."""
    with open(os.path.join(results, "residuals.csv"), newline="", encoding="utf-8") as handle:
        magnitude = [math.hypot(float(r["vx_px"]), float(r["vy_px"])) for r in csv.DictReader(handle)
                     if r["rejected"] == "0"]
    with open(os.path.join(results, "points.csv"), newline="", encoding="utf-8") as handle:
        points = list(csv.DictReader(handle))
    out = {"mean_residual_px": statistics.fmean(magnitude), "max_residual_px": max(magnitude), "points": {}}
    for axis in "XYZ":
        km = [float(p[axis]) / 1000.0 for p in points]
        out["points"][axis] = {"mean": statistics.fmean(km), "sd": statistics.stdev(km), "min": min(km),
                               "max": max(km)}
    return out


def rows(results: str, jigsaw: dict | None = None) -> list[tuple[str, float, float]]:
    """(quantity, jigsaw, selfcal) of every LRO value of EXPECTED_VALUES.txt."""
    jigsaw = jigsaw or read_jigsaw()
    ours = read_selfcal(results)
    out = [("mean residual [px]", jigsaw["mean_residual_px"], ours["mean_residual_px"]),
           ("maximum residual [px]", jigsaw["max_residual_px"], ours["max_residual_px"])]
    for axis in "XYZ":
        for stat in STATISTICS:
            out.append((f"points {axis} {stat} [km]", jigsaw["points"][axis][stat], ours["points"][axis][stat]))
    return out


def _signed(value: float) -> str:
    return f"{value:+.2f}".replace("-", "\u2212")


def summary_rows(results: str, jigsaw: dict) -> list[str]:
    """The README's table: per run the mean and largest residual beside jigsaw's, and the points' mean X, Y, Z
    minus jigsaw's."""
    out = ["| run | mean residual [px] | max residual [px] | points X / Y / Z mean \u2212 jigsaw [km] |",
           "|---|---:|---:|---|",
           f"| jigsaw | {jigsaw['mean_residual_px']:.4f} | {jigsaw['max_residual_px']:.4f} | |"]
    for run, title in RUNS.items():
        folder = os.path.join(results, run)
        if not os.path.isdir(folder):
            continue
        ours = read_selfcal(folder)
        mean, largest = ours["mean_residual_px"], ours["max_residual_px"]
        shift = " / ".join(_signed(ours["points"][a]["mean"] - jigsaw["points"][a]["mean"]) for a in "XYZ")
        out.append(f"| `{run}`: {title} | {mean:.4f} ({mean / jigsaw['mean_residual_px']:.2f}\u00d7) | "
                   f"{largest:.4f} ({largest / jigsaw['max_residual_px']:.2f}\u00d7) | {shift} |")
    return out


def main(argv: list[str]) -> int:
    results = argv[1] if len(argv) > 1 else os.path.join(HERE, "results")
    jigsaw = read_jigsaw(argv[2] if len(argv) > 2 else EXPECTED)
    for run, title in RUNS.items():
        folder = os.path.join(results, run)
        if not os.path.isdir(folder):
            continue
        print(f"\n{run}: {title}\n\n| quantity | jigsaw | selfcal | ratio | difference |\n|---|---:|---:|---:|---:|")
        for name, theirs, ours in rows(folder, jigsaw):
            print(f"| {name} | {theirs:.6f} | {ours:.6f} | {ours / theirs:.4f} | {ours - theirs:.4f} |")
    print()
    print("\n".join(summary_rows(results, jigsaw)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
