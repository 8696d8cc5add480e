"""One line per results folder of the COPR example: sigma0, reprojection RMS, rejections, APs, control fit.

Run: python examples/copr/summary.py OUT NAME...   (reads OUT/NAME/summary.json)
"""
from __future__ import annotations

import json
import os
import sys


def main() -> None:
    out, names = sys.argv[1], sys.argv[2:]
    print("| model | sigma0 [px] | reprojection RMS [px] | rejected | APs kept/initial | GCP RMS XY / Z [m] | "
          "iterations | seconds |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in names:
        path = os.path.join(out, name, "summary.json")
        if not os.path.isfile(path):
            print(f"| {name} | (no results: the adjustment failed, see its log) |||||||")
            continue
        with open(path, encoding="utf-8") as handle:
            s = json.load(handle)
        print(f"| {s['ap_model']} | {s['sigma0_px']:.3f} | {s['rms_image_residual_px']:.3f} | {s['n_obs_rejected']} | "
              f"{s['n_ap_significant']}/{s['n_ap_initial']} | {s['rms_gcp_residual_xy_m']:.2f} / "
              f"{s['rms_gcp_residual_z_m']:.2f} | {s['iterations']} | {s['seconds']:.0f} |")


if __name__ == "__main__":
    main()
