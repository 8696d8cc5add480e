"""One line per results folder of the COPR example: sigma0, reprojection RMS, rejections, APs, check points.

The block is a free network whose frame is the import's similarity from the targets, all of them check
points: their RMSD measures that similarity and the hand-held GPS, not the photogrammetry (control.py).

Run: python examples/copr/summary.py OUT NAME...   (reads OUT/NAME/summary.json)
"""
from __future__ import annotations

import json
import os
import sys


def main() -> None:
    out, names = sys.argv[1], sys.argv[2:]
    print("| model | sigma0 [px] | reprojection RMS [px] | rejected | APs kept/initial | check RMSD XY / Z [m] | "
          "points left out | iterations | seconds |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in names:
        path = os.path.join(out, name, "summary.json")
        if not os.path.isfile(path):
            print(f"| {name} | (no results: the adjustment failed, see its log) ||||||||")
            continue
        with open(path, encoding="utf-8") as handle:
            s = json.load(handle)
        print(f"| {s['ap_model']} | {s['sigma0_px']:.3f} | {s['rms_image_residual_px']:.3f} | {s['n_obs_rejected']} | "
              f"{s['n_ap_significant']}/{s['n_ap_initial']} | {_m(s['rmsd_chk_xy_m'])} / {_m(s['rmsd_chk_z_m'])} | "
              f"{s['dropped'].get('points_undetermined', 0)} | {s['iterations']} | {s['seconds']:.0f} |")


def _m(value) -> str:
    return "n/a" if value is None else f"{value:.2f}"


if __name__ == "__main__":
    main()
