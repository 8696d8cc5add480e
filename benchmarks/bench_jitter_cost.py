"""What attitude jitter costs one adjustment (issue 42): a PRISM-like stereo pair (fore and aft views, seed 001's M5,
5 GCP) with N tie points, adjusted once with bias and drift alone and once with the jitter's scaling functions at a
given level (db4), both on the same observations (simulated with jitter).

    python benchmarks/bench_jitter_cost.py [--points 50000] [--level 7] [--repeat 2]

Prints the seconds of each (the best of ``--repeat``, warm: Numba's one-off set-up is measured on a small pair first
and printed beside), the ratio (issue 42 asks <= 2), the iterations and sigma0 (px) of each, and the image block's width.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from selfcal.adjust import AdjustOptions, SensorOptions, adjust
from selfcal.simulate.prism import JITTER, prism_block, simulate_prism
from selfcal.workflows import seed001

TRUE_FOCAL_MM = {"F": 1938.20, "N": 1937.45, "B": 1936.66}
STEREO = (0, 2)         # fore and aft
#: the coefficients' a-priori sigma (rad), of the order `--jitter auto` estimates on the triplet (a stereo pair
#: without it leaves roll and yaw jitter undetermined)
JITTER_SIGMA_RAD = 3e-6


def pair(n_points: int, seed: int = 1):
    sim = simulate_prism(seed=seed, n_points=n_points, jitter=JITTER)
    block = seed001.with_focal(prism_block(sim, seed=seed, dem_file=None), TRUE_FOCAL_MM)
    gcps = seed001.choose_gcps(block, None)
    return seed001.case_block(block, STEREO, gcps)


def timed(block, options, repeat: int):
    best, result = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        result = adjust(block, options)
        best = min(best, time.perf_counter() - t)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=50_000)
    parser.add_argument("--level", type=int, default=7)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    plain = AdjustOptions(sensor=SensorOptions(model="M5"))
    jitter = AdjustOptions(sensor=SensorOptions(model="M5", jitter=f"wavelet1d:db4:{args.level}",
                                                 jitter_sigma_rad=JITTER_SIGMA_RAD))

    t = time.perf_counter()
    small = pair(3000)
    adjust(small, plain)
    adjust(small, jitter)
    setup_s = time.perf_counter() - t

    block = pair(args.points)
    n_obs = len(block.observations.image_index)
    plain_s, plain_r = timed(block, plain, args.repeat)
    jitter_s, jitter_r = timed(block, jitter, args.repeat)
    print(f"stereo pair, {args.points} points, {n_obs} image observations; set-up (Numba, first small pair) "
          f"{setup_s:.1f} s")
    print(f"{'model':<22} {'width':>5} {'iter':>4} {'sigma0':>7} {'seconds':>8}")
    for name, s, r in (("bias + drift (M5)", plain_s, plain_r), (f"+ jitter db4 level {args.level}", jitter_s, jitter_r)):
        print(f"{name:<22} {r.problem.image_width:5d} {r.iterations:4d} {r.sigma0_px:7.3f} {s:8.2f}")
    print(f"ratio jitter / bias+drift: {jitter_s / plain_s:.2f} (issue 42 asks <= 2)")


if __name__ == "__main__":
    main()
