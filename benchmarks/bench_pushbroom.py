"""A pushbroom triplet with many tie points on the one engine: time per iteration against the number of points.

The simulated PRISM triplet (seed 001) with 1,000 to 50,000 tie points seen in all three images (plus the
block's GCPs), adjusted with M6 as ``selfcal adjust`` does it: data snooping, the covariance of every point,
the check points. Printed per size: observations, iterations, seconds per Gauss-Newton iteration (the mean
time between the solver's progress records), the whole tested run, and the growth exponent of the time per
iteration (least squares on log time against log points). Before the one engine the pushbroom adjustment
had dense normal equations: 50,000 points (150,000 coordinates) could not be adjusted at all.

Run: ``python benchmarks/bench_pushbroom.py [--points 1000,2000,5000,10000,20000,50000]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def one_run(n_points: int) -> dict:
    from selfcal.simulate.prism import TRUE_FOCAL_MM, prism_block, simulate_prism
    from selfcal.stats import SnoopingOptions
    from selfcal.workflows.seed001 import choose_gcps, run_case, with_focal

    sim = simulate_prism(seed=7, n_points=n_points)
    block = with_focal(prism_block(sim, seed=7), TRUE_FOCAL_MM)
    stamps = []
    t0 = time.perf_counter()
    case = run_case(block, "M6", choose_gcps(block, 5), (0, 1, 2), sim.dem, "F+N+B", snooping=SnoopingOptions(),
                    progress=lambda record: stamps.append(time.perf_counter()))
    seconds = time.perf_counter() - t0
    result = case.result
    steps = np.diff(stamps)
    # the first record of each adjustment follows its set-up (initial values): time the iterations after it
    per_iteration = float(np.median(steps)) if steps.size else float("nan")
    return {"points": n_points, "observations": int(2 * result.problem.n_image_observations),
            "iterations": len(stamps), "per_iteration_s": per_iteration, "seconds": seconds,
            "rejected": len(case.tested.rejected_rows), "rmse_m": case.rmse_m}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", default="1000,2000,5000,10000,20000,50000")
    args = parser.parse_args()
    sizes = [int(v) for v in args.points.split(",")]
    one_run(500)                                  # compile the kernels once
    rows = [one_run(n) for n in sizes]
    print(f"{'points':>7} {'coordinates':>12} {'iterations':>10} {'s/iteration':>12} {'tested run s':>13} "
          f"{'rejected':>9}  RMSE across/along/up [m]")
    for r in rows:
        rmse = " / ".join(f"{v:.2f}" for v in r["rmse_m"]) if r["rmse_m"] is not None else "n/a"
        print(f"{r['points']:>7} {r['observations']:>12} {r['iterations']:>10} {r['per_iteration_s']:>12.3f} "
              f"{r['seconds']:>13.2f} {r['rejected']:>9}  {rmse}")
    if len(rows) >= 2:
        x = np.log([r["points"] for r in rows])
        y = np.log([r["per_iteration_s"] for r in rows])
        exponent = np.polyfit(x, y, 1)[0]
        print(f"growth exponent of the time per iteration ({rows[0]['points']} -> {rows[-1]['points']} points): "
              f"{exponent:.2f}")


if __name__ == "__main__":
    main()
