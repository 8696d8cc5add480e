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


def main() -> None:
    out, names = sys.argv[1], sys.argv[2:]
    rms = {}
    print(f"{'run':<12} {'RMS |v| px':>10} {'sigma0 px':>9} {'rejected':>8} {'ties':>5}   heights min / median / max (m, WGS 84)")
    for name in names:
        folder = os.path.join(out, name)
        with open(os.path.join(folder, "summary.json")) as handle:
            s = json.load(handle)
        points = _rows(os.path.join(folder, "points.csv"))
        xyz = np.array([[float(p["X"]), float(p["Y"]), float(p["Z"])] for p in points])
        h = geodetic_from_ecef(xyz)[2]
        rms[name] = s["rms_image_residual_px"]
        print(f"{name:<12} {s['rms_image_residual_px']:>10.3f} {s['sigma0_px']:>9.3f} {s['n_obs_rejected']:>8d} "
              f"{s['n_tie_points']:>5d}   {h.min():.1f} / {np.median(h):.1f} / {h.max():.1f}")
        for p in _rows(os.path.join(folder, "parameters.csv")):
            if p["active"] == "1":
                print(f"{'':<14}{p['owner']:<6} {p['parameter']}: {float(p['value']):+.4g} +- {float(p['sigma']):.3g} "
                      f"{p['unit']}")
        print(f"{'':<14}datum: {s.get('datum')}: {s.get('datum_detail')}")
    if len(names) > 1:
        first = names[0]
        for name in names[1:]:
            print(f"{first} -> {name}: RMS falls {rms[first] / rms[name]:.1f}x")


if __name__ == "__main__":
    main()
