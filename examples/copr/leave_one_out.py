"""Leave-one-out check of the ground control of a block: each control point in turn becomes a check point.

The block is adjusted once with all control and data snooping; the observations snooping kept are then
re-adjusted once per control point seen in at least two images, with that point free (a check point),
each from the block's own initial values. (Starting from the full adjustment is not faster on COPR: a
single strip along a beach, whose weakly controlled bending lets some runs creep along a flat valley.) Printed: the point's error (adjusted - surveyed) with its a-posteriori
sigma, and the plan and height RMSD over all points left out.

Run: python examples/copr/leave_one_out.py BLOCK [--ap brown]
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from selfcal.adjust import AdjustOptions, adjust
from selfcal.block import prune
from selfcal.io import read_block
from selfcal.workflows.tested import adjust_with_tests


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("block")
    parser.add_argument("--ap", default="brown")
    args = parser.parse_args()
    options = AdjustOptions(ap=args.ap)
    full = adjust_with_tests(prune(read_block(args.block)), options)
    kept = full.result.block                                   # the observations snooping kept
    points = kept.points
    seen = np.bincount(kept.observations.point_index, minlength=len(points))
    targets = [k for k in np.flatnonzero(points.role == "gcp") if seen[k] >= 2]
    skipped = [str(points.point_id[k]) for k in np.flatnonzero(points.role == "gcp") if seen[k] < 2]
    print(f"{args.block}: {args.ap}, {len(targets)} control points left out in turn"
          + (f" ({', '.join(skipped)} seen in fewer than two images: cannot be checked)" if skipped else ""))
    print(f"{'point':<8} {'images':>6} {'dX [m]':>8} {'dY [m]':>8} {'dZ [m]':>8} {'dXY [m]':>8} {'sigma XY':>9}")
    errors = []
    for k in targets:
        role = points.role.copy()
        role[k] = "chk"
        block = replace(kept, points=replace(points, role=role))
        result = adjust(block, options)
        if not result.converged:
            print(f"{points.point_id[k]}: did not converge ({result.reason})", file=sys.stderr)
            continue
        d = result.state.points[k] - points.xyz_m[k]
        sigma_xy = np.sqrt(result.variance_factor * np.trace(result.Q_points[k][:2, :2]))
        errors.append(d)
        print(f"{points.point_id[k]:<8} {seen[k]:>6} {d[0]:>8.3f} {d[1]:>8.3f} {d[2]:>8.3f} "
              f"{np.hypot(d[0], d[1]):>8.3f} {sigma_xy:>9.3f}")
    e = np.array(errors)
    print(f"RMSD plan {np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)):.3f} m, height {np.sqrt(np.mean(e[:, 2] ** 2)):.3f} m "
          f"over {len(e)} points left out")


if __name__ == "__main__":
    main()
