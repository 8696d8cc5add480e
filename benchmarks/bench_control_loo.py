"""The cost of the leave-one-out validation of the control (issue 40 item 3) against the adjustment it validates.

Seed 000's 28-image block, Type 3 control cut to 25 control points (the other two checked), ``--ap brown``; the
workflow of ``selfcal adjust`` (robust cleaning, data snooping, the tests) with and without the validation (25
re-adjustments from the converged estimate), medians of ``--repeat`` runs after a warm-up; and the largest
difference of the linear downdate from the re-adjusted errors.

    python benchmarks/bench_control_loo.py [--points-per-mm2 3.5] [--repeat 3]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from selfcal.adjust import AdjustOptions, APOptions, adjust
from selfcal.simulate import simulate_uav
from selfcal.workflows.adjust import AdjustRequest, adjust_block
from selfcal.workflows.tested import prune_for


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points-per-mm2", type=float, default=3.5)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    block = prune_for(simulate_uav(seed=1, points_per_mm2=args.points_per_mm2, distortion="brown").blocks["type3"])
    role = np.asarray(block.points.role).copy()
    role[np.flatnonzero(role == "gcp")[25:]] = "chk"
    block = replace(block, points=replace(block.points, role=role))
    options = AdjustOptions(ap=APOptions("brown"))
    print(f"{len(block.images)} images, {len(block.observations)} observations, {(role == 'gcp').sum()} GCP")
    adjust_block(block, AdjustRequest(options=options))                   # warm-up (Numba)
    plain, without, loo = [], [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        adjust(block, options)
        plain.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        adjust_block(block, AdjustRequest(options=options, control_loo=False))
        without.append(time.perf_counter() - t0)
        out = adjust_block(block, AdjustRequest(options=options))
        loo.append(out.tested.loo.seconds)
    p, w, v = np.median(plain), np.median(without), np.median(loo)
    s = out.summary_extra["control_loo"]
    print(f"one adjustment {p:.2f} s; the workflow without the validation {w:.2f} s; the validation {v:.2f} s "
          f"({v / w:.2f}x the workflow, {v / p:.1f}x one adjustment); linear downdate off by up to "
          f"{s['linear_downdate_gap_m']:.1e} m; worst {s['worst_point_id']} T {s['worst_t3']:.1f}, "
          f"{s['n_failing']} failing")


if __name__ == "__main__":
    main()
