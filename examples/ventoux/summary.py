"""The Ventoux results side by side: residual RMS, sigma0, tie point heights and the bias of each image.

Run: python examples/ventoux/summary.py OUT NAME...   (reads OUT/NAME/{summary.json,points.csv,parameters.csv})
"""
from __future__ import annotations

import csv
import json
import os
import sys

import numpy as np

from selfcal.geometry.earth import geodetic_from_ecef


def _rows(path: str) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


LABELS = {"uncorrected": "uncorrected RPCs", "shift": "shift bias", "affine": "affine bias"}


def _signed(value: float, digits: int) -> str:
    return f"{value:+.{digits}f}".replace("-", "\u2212")


def main() -> None:
    out, names = sys.argv[1], sys.argv[2:]
    rms, bias = {}, {}
    print("| run | RMS of \\|v\\| (px) | \u03c3\u03020 (px) | rejected | tie points | heights min / median / max (m) |\n"
          "| --- | ---: | ---: | ---: | ---: | --- |")
    for name in names:
        folder = os.path.join(out, name)
        with open(os.path.join(folder, "summary.json"), encoding="utf-8") as handle:
            s = json.load(handle)
        points = _rows(os.path.join(folder, "points.csv"))
        xyz = np.array([[float(p["X"]), float(p["Y"]), float(p["Z"])] for p in points])
        h = geodetic_from_ecef(xyz)[2]
        rms[name] = s["rms_image_residual_px"]
        sigma0 = f"{s['sigma0_px']:.3g}" if s["sigma0_px"] >= 1 else f"{s['sigma0_px']:.3f}"
        print(f"| {LABELS.get(name, name)} | {s['rms_image_residual_px']:.3f} | {sigma0} | {s['n_obs_rejected']} | "
              f"{s['n_tie_points']} | {h.min():.1f} / {np.median(h):.1f} / {h.max():.1f} |")
        bias[name] = {(p["owner"], p["parameter"]): (float(p["value"]), float(p["sigma"]))
                      for p in _rows(os.path.join(folder, "parameters.csv")) if p["active"] == "1"}
        print(f"datum of {name}: {s.get('datum')}: {s.get('datum_detail')}", file=sys.stderr)
    if "shift" in bias:
        print("\n| image | a0 (rows) | b0 (columns) |\n| --- | --- | --- |")
        for image in sorted({owner for owner, _ in bias["shift"]}):
            cells = [f"{_signed(v, 2)} \u00b1 {sd:.2f} px" for v, sd in
                     (bias["shift"][image, name] for name in ("a0", "b0"))]
            print(f"| {image} | " + " | ".join(cells) + " |")
    if len(names) > 1:
        print()
        for name in names[1:]:
            print(f"{names[0]} -> {name}: RMS falls {rms[names[0]] / rms[name]:.1f}x")


if __name__ == "__main__":
    main()
