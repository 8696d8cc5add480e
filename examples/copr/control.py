"""What the COPR ground control can and cannot fix: a 7-parameter similarity from the free network to the targets.

The block is adjusted as a free network (every target a check point, `selfcal import colmap --check ...`): its
frame is the one the import's similarity from the targets gave the start values, which minimum-norm steps do
not move. This script fits a 3-D similarity (3 shifts, 3 rotations, scale) from the free network's adjusted
target points to the surveyed ones, weighted by the surveyed sigmas (points.csv: the adjusted coordinates and
dX = adjusted - surveyed of each check point; the a-priori sigmas are given here, the hand-held GPS's), and
prints

* the targets' line: RMS distance from their best-fitting line against the block's extent;
* the a-priori sigma of each similarity parameter, the rotations about the line (roll), across it (pitch)
  and about the vertical (yaw): the roll is what the control cannot fix when the targets lie on a line;
* the residuals of the targets after the similarity and their chi-square against the GPS sigmas.

The adjusted points' own sigma (mm) is negligible against the GPS's metres and is left out.

Run: python examples/copr/control.py RESULTS [--sigma-xy 3] [--sigma-z 5]
"""
from __future__ import annotations

import argparse
import csv
import os

import numpy as np


def read_targets(results: str):
    ids, adjusted, surveyed = [], [], []
    with open(os.path.join(results, "points.csv"), newline="") as handle:
        for row in csv.DictReader(handle):
            if row["role"] != "chk" or not row["dX_m"]:
                continue
            xyz = np.array([float(row[k]) for k in ("X", "Y", "Z")])
            d = np.array([float(row[k]) for k in ("dX_m", "dY_m", "dZ_m")])
            ids.append(row["point_id"])
            adjusted.append(xyz)
            surveyed.append(xyz - d)
    return ids, np.array(adjusted), np.array(surveyed)


def block_extent(results: str) -> float:
    """Twice the median distance of the tie points from their median centre (selfcal.adjust.datum's extent)."""
    xyz = []
    with open(os.path.join(results, "points.csv"), newline="") as handle:
        for row in csv.DictReader(handle):
            xyz.append([float(row[k]) for k in ("X", "Y", "Z")])
    xyz = np.array(xyz)
    centre = np.median(xyz, axis=0)
    return 2.0 * float(np.median(np.linalg.norm(xyz - centre, axis=1)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results")
    parser.add_argument("--sigma-xy", type=float, default=3.0)
    parser.add_argument("--sigma-z", type=float, default=5.0)
    args = parser.parse_args()
    ids, adjusted, surveyed = read_targets(args.results)
    n = len(ids)
    # the targets' line (horizontal direction of the first principal axis) and the frame (along, across, up)
    centre = surveyed.mean(axis=0)
    _, _, vt = np.linalg.svd(surveyed - centre, full_matrices=False)
    along = vt[0] - vt[0][2] * np.array([0, 0, 1.0])
    along /= np.linalg.norm(along)
    up = np.array([0, 0, 1.0])
    across = np.cross(up, along)
    frame = np.vstack([along, across, up])                       # rows: the axes
    off = surveyed - centre - np.outer((surveyed - centre) @ vt[0], vt[0])
    rms_off = float(np.sqrt(np.mean(np.sum(off**2, axis=1))))
    extent = block_extent(args.results)
    print(f"{n} targets (check points of the free network), spanning {np.ptp((surveyed - centre) @ along):.1f} m "
          f"along their line and {np.ptp((surveyed - centre) @ across):.1f} m across it; RMS distance from the line "
          f"{rms_off:.2f} m, block extent {extent:.2f} m; GPS sigma {args.sigma_xy:g} m in plan, {args.sigma_z:g} m "
          f"in height")
    # linearised similarity in the (along, across, up) frame about the targets' centre:
    # surveyed = adjusted + t + w x a + s a, with a = adjusted - centre (the rotations are small)
    a = (adjusted - centre) @ frame.T
    y = ((surveyed - adjusted) @ frame.T).ravel()
    A = np.zeros((3 * n, 7))
    for k in range(n):
        A[3 * k:3 * k + 3, 0:3] = np.eye(3)
        ax, ay, az = a[k]
        A[3 * k:3 * k + 3, 3:6] = [[0, az, -ay], [-az, 0, ax], [ay, -ax, 0]]    # w x a
        A[3 * k:3 * k + 3, 6] = a[k]
    sigma = np.tile([args.sigma_xy, args.sigma_xy, args.sigma_z], n)
    Aw, yw = A / sigma[:, None], y / sigma
    N = Aw.T @ Aw
    Q = np.linalg.inv(N)
    x = Q @ Aw.T @ yw
    v = (yw - Aw @ x) * sigma
    chi2 = float(np.sum(((yw - Aw @ x)) ** 2))
    s = np.sqrt(np.diag(Q))
    names = ["shift along", "shift across", "shift up", "roll (about the line)", "pitch (across it)", "yaw (vertical)",
             "scale"]
    print("similarity from the free network to the targets (a-priori sigmas from the GPS):")
    for k, name in enumerate(names):
        if k < 3:
            print(f"  {name:<24} {x[k]:+8.3f} m   sigma {s[k]:.3f} m")
        elif k < 6:
            print(f"  {name:<24} {np.degrees(x[k]):+8.3f} deg sigma {np.degrees(s[k]):.3f} deg "
                  f"({s[k] * extent / 2:.2f} m at {extent / 2:.1f} m from the centre)")
        else:
            print(f"  {name:<24} {x[k] * 1e2:+8.3f} %   sigma {s[k] * 1e2:.3f} %")
    r = v.reshape(n, 3)
    dof = 3 * n - 7
    print(f"target residuals after the similarity: RMS {np.sqrt(np.mean(r[:, 0]**2 + r[:, 1]**2)):.2f} m in plan, "
          f"{np.sqrt(np.mean(r[:, 2]**2)):.2f} m in height; chi-square {chi2:.1f} on {dof} degrees of freedom")
    worst = int(np.argmax(np.hypot(r[:, 0], r[:, 1])))
    print(f"  largest: {ids[worst]} {np.hypot(r[worst, 0], r[worst, 1]):.2f} m in plan")


if __name__ == "__main__":
    main()
