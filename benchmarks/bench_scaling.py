"""How selfcal's cost grows with the block: synthetic frame blocks from 28 to 2000 images.

Blocks of the seed-000 simulator with more strips and longer strips (same overlaps, 0.5 tie
points per mm^2 of image, so points and observations grow with the images), Type 3 control,
no distortion, AP model none. Each block is adjusted in its own process (so that its peak
memory is its own) with the default solver, covariance of every unknown and every tie point
included. Printed per block: images, points, observations, iterations, median seconds per
iteration, total seconds of the adjustment, peak memory; then the growth exponent b of
seconds per iteration ~ observations^b (least squares in log-log).

Run: ``make bench`` or ``python benchmarks/bench_scaling.py [--largest 2000]``.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np

#: (strips, images per strip)
BLOCKS = [(4, 7), (6, 17), (10, 20), (14, 36), (20, 50), (40, 50)]


def _child(n_strips: int, per_strip: int) -> dict:
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=0.5, n_strips=n_strips,
                       images_per_strip=per_strip)
    block = prune(sim.blocks["type3"])
    stamps = []
    t0 = time.perf_counter()
    result = adjust(block, AdjustOptions(), progress=lambda record: stamps.append(time.perf_counter()))
    seconds = time.perf_counter() - t0
    per_iteration = float(np.median(np.diff(stamps))) if len(stamps) > 1 else float("nan")
    return {"images": len(block.images), "points": len(block.points), "observations": len(block.observations),
            "iterations": result.iterations, "per_iteration": per_iteration, "seconds": seconds,
            "converged": result.converged,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", nargs=2, type=int)
    parser.add_argument("--largest", type=int, default=2000, help="largest block in images (default 2000)")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(*args.child)))
        return
    rows = []
    print(f"{'images':>7}{'points':>9}{'observations':>14}{'iter.':>6}{'s/iter.':>9}{'total s':>9}{'peak MB':>9}")
    for strips, per_strip in BLOCKS:
        if strips * per_strip > args.largest:
            continue
        out = subprocess.run([sys.executable, __file__, "--child", str(strips), str(per_strip)],
                             capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(f"{r['images']:>7}{r['points']:>9}{r['observations']:>14}{r['iterations']:>6}{r['per_iteration']:>9.3f}"
              f"{r['seconds']:>9.1f}{r['peak_mb']:>9.0f}" + ("" if r["converged"] else "  (not converged)"),
              flush=True)
    big = [r for r in rows if r["images"] >= 200]
    if len(big) >= 2:
        x = np.log([r["observations"] for r in big])
        for key, label in (("per_iteration", "seconds per iteration"), ("seconds", "total seconds")):
            slope = np.polyfit(x, np.log([r[key] for r in big]), 1)[0]
            print(f"growth exponent of {label} vs observations (blocks of >= 200 images): {slope:.2f}")


if __name__ == "__main__":
    main()
