"""One adjustment with its points on a local Dask cluster against the same adjustment in one process (issue 43 item 1).

The synthetic strip blocks of bench_scaling.py (seed-000 simulator, 0.5 tie points per mm^2, Type 3 control, AP model
none unless ``--ap``), each written once as a block folder. One child process adjusts it alone; another starts a
LocalCluster of ``--workers`` worker processes (one thread each) and adjusts it inside
:func:`selfcal.adjust.distributed.on_cluster`. Both compute the sigma of every unknown (Q_theta, every point's
covariance). Printed side by side: seconds per iteration, the whole adjustment's seconds, the peak resident memory of
the single process, of the client and of each worker (/proc's VmHWM, the peak since the exec), the largest
relative difference of the estimates (points, image and camera parameters) and of their sigmas, and what
``selfcal plan --scheduler local:WORKERS`` planned for the client and each worker.

Run: ``python benchmarks/bench_distributed.py [--blocks 20x50,50x100] [--workers 2] [--ap MODEL]``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import selfcal  # noqa: F401  (before NumPy, as on the command line: it sets OpenBLAS's thread timeout)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_plan import _write_child  # noqa: E402  (the same blocks, written the same way)


def _peak_mb() -> float:
    """This process's peak resident memory since its exec (VmHWM), MB."""
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _adjust_child(folder: str, workers: int, ap: str | None, out: str) -> dict:
    """Adjust the block folder (on a local cluster of ``workers`` processes when ``workers`` > 0) with the sigma of
    every unknown; the estimates and sigmas go to ``out`` (npz), the figures to stdout."""
    from selfcal.adjust import AdjustOptions, APOptions, adjust, distributed
    from selfcal.allocator import keep_freed_memory
    from selfcal.io import read_block

    keep_freed_memory()                 # as the CLI does
    block = read_block(folder)
    options = AdjustOptions() if ap is None else AdjustOptions(ap=APOptions(ap))
    stamps: list[float] = []
    worker_peaks: list[float] = []
    t0 = time.perf_counter()
    if workers:
        from selfcal.workflows.cluster import dask_client
        with dask_client(f"local:{workers}") as client:
            started = time.perf_counter() - t0
            t0 = time.perf_counter()
            with distributed.on_cluster(client):
                result = adjust(block, options, progress=lambda record: stamps.append(time.perf_counter()))
                result.Q_points
                sigma_points = np.sqrt(np.einsum("nii->ni", result.point_covariance()))
            worker_peaks = sorted(client.run(_peak_mb).values())
    else:
        started = 0.0
        result = adjust(block, options, progress=lambda record: stamps.append(time.perf_counter()))
        result.Q_points
        sigma_points = np.sqrt(np.einsum("nii->ni", result.point_covariance()))
    seconds = time.perf_counter() - t0
    np.savez(out, points=result.state.points, theta=result.problem.pack(result.state),
             sigma_theta=result.parameters().sigma, sigma_points=sigma_points)
    return {"images": len(block.images), "observations": len(block.observations), "iterations": result.iterations,
            "seconds": seconds, "cluster_start_s": started,
            "seconds_per_iteration": float(np.median(np.diff(stamps))) if len(stamps) > 1 else float("nan"),
            "peak_mb": _peak_mb(), "worker_peaks_mb": worker_peaks}


def _plan_child(folder: str, workers: int, ap: str | None) -> dict:
    """``selfcal plan --scheduler local:WORKERS`` of the block folder: the client's and each worker's planned peak."""
    from selfcal.io import read_block
    from selfcal.workflows.plan import plan_block

    plan = plan_block(read_block(folder), ap or "none", probe=False)
    return {"client_mb": plan.client_peak_mb(workers), "worker_mb": plan.worker_peak_mb(workers)}


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.max(np.abs(a[ok] - b[ok])) / np.max(np.abs(a[ok])))


def _run(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--adjust-child", nargs=3, metavar=("FOLDER", "WORKERS", "OUT"))
    parser.add_argument("--write-child", nargs=4)
    parser.add_argument("--plan-child", nargs=2, metavar=("FOLDER", "WORKERS"))
    parser.add_argument("--blocks", default="20x50,50x100",
                        help="strips x images per strip [@ points per mm^2] (default 20x50,50x100: 1000 and 5000 "
                             "images)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--ap", help="AP model (default none), e.g. wavelet:db4 (on 9x6)")
    args = parser.parse_args()
    model = [] if args.ap is None else ["--ap", args.ap]
    if args.write_child:
        strips, per_strip, density, folder = args.write_child
        print(json.dumps(_write_child(int(strips), int(per_strip), float(density), folder)))
        return
    if args.plan_child:
        print(json.dumps(_plan_child(args.plan_child[0], int(args.plan_child[1]), args.ap)))
        return
    if args.adjust_child:
        folder, workers, out = args.adjust_child
        print(json.dumps(_adjust_child(folder, int(workers), args.ap, out)))
        return
    print(f"load average at the start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'images':>7}{'obs.':>10}{'it.':>4}{'s/iter. 1 / cluster':>21}{'s 1 / cluster':>17}"
          f"{'peak MB 1':>11}{'client':>8}{'workers':>14}{'max rel. diff estimates / sigma':>33}"
          f"{'planned client / worker MB':>28}")
    work = tempfile.mkdtemp(prefix="bench-distributed-")
    for text in args.blocks.split(","):
        size, _, density = text.partition("@")
        strips, per_strip = (int(v) for v in size.split("x"))
        folder = os.path.join(work, f"block-{size}")
        _run(["--write-child", str(strips), str(per_strip), density or "0.5", folder])
        one_out, two_out = os.path.join(work, "one.npz"), os.path.join(work, "two.npz")
        one = _run(["--adjust-child", folder, "0", one_out, *model])
        two = _run(["--adjust-child", folder, str(args.workers), two_out, *model])
        planned = _run(["--plan-child", folder, str(args.workers), *model])
        a, b = np.load(one_out), np.load(two_out)
        estimates = max(_relative(a["points"], b["points"]), _relative(a["theta"], b["theta"]))
        sigmas = max(_relative(a["sigma_theta"], b["sigma_theta"]), _relative(a["sigma_points"], b["sigma_points"]))
        shutil.rmtree(folder)
        workers = "/".join(f"{p:.0f}" for p in two["worker_peaks_mb"])
        print(f"{one['images']:>7}{one['observations']:>10}{one['iterations']:>4}"
              f"{one['seconds_per_iteration']:>11.2f} / {two['seconds_per_iteration']:<7.2f}"
              f"{one['seconds']:>8.1f} / {two['seconds']:<6.1f}{one['peak_mb']:>11.0f}{two['peak_mb']:>8.0f}"
              f"{workers:>14}{estimates:>19.1e} / {sigmas:<8.1e}"
              f"{planned['client_mb']:>12.0f} / {planned['worker_mb']:<6.0f}", flush=True)
        print("  " + json.dumps({"single": one, "cluster": two, "planned": planned}), file=sys.stderr, flush=True)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
