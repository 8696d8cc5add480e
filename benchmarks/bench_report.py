"""Rendering the report of the 28-image seed-000 block, against the adjustment it reports on.

The block is one cell of ``selfcal demo``: Type 1 control, local + Brown field of
a wide-angle lens (distortion scale 4), 0.3 % blunders, wavelet:db4 APs with
data snooping and screening (about 80,000 image observations, 14,500 tie
points, 254 WAPs). Measured in the same run:

* adjust: ``adjust_with_tests`` and the results files (the peer);
* render (memory): ``render_report`` of those files, as ``selfcal adjust`` does it;
* render (folder): ``read_results`` + ``render_report``, as ``selfcal report RESULTS`` does it.

Prints the times and the ratio render / adjust. The issue's bar: a report of this
block renders in at most 10 s.

Run: ``python benchmarks/bench_report.py [--model wavelet:db4] [--repeat 3]``.
"""
from __future__ import annotations

import argparse
import tempfile
import time


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="wavelet:db4")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)

    from selfcal.adjust import AdjustOptions, APOptions
    from selfcal.allocator import keep_freed_memory
    from selfcal.block import prune
    from selfcal.io.results import read_results, results_from_files, write_results
    from selfcal.report import render_report, result_files
    from selfcal.stats import ScreeningOptions, SnoopingOptions
    from selfcal.workflows import adjust_with_tests
    from selfcal.simulate import simulate_uav

    keep_freed_memory()
    sim = simulate_uav(seed=args.seed, distortion="local+brown", blunder_rate=0.003, distortion_scale=4.0)
    block = prune(sim.blocks["type1"])
    t0 = time.perf_counter()
    tested = adjust_with_tests(block, AdjustOptions(ap=APOptions(args.model)), SnoopingOptions(), ScreeningOptions())
    files = result_files(block, tested, {"seconds": 0.0})
    t_adjust = time.perf_counter() - t0

    memory, folder = [], []
    with tempfile.TemporaryDirectory() as tmp:
        write_results(f"{tmp}/results", files)
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            report = render_report(results_from_files(files))
            memory.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            render_report(read_results(f"{tmp}/results"))
            folder.append(time.perf_counter() - t0)
    size = sum(len(v) for v in report.values()) / 1e6
    print(f"block: {len(block.images)} images, {len(block.observations)} image observations, "
          f"{int((block.points.role == 'tie').sum())} tie points; {args.model}, "
          f"{tested.n_ap_significant}/{tested.n_ap_initial} APs kept")
    print(f"adjust (peer)        {t_adjust:7.2f} s")
    print(f"render from memory   {min(memory):7.2f} s  (best of {args.repeat}; ratio to adjust {min(memory) / t_adjust:.3f})")
    print(f"render from folder   {min(folder):7.2f} s  (best of {args.repeat}; ratio to adjust {min(folder) / t_adjust:.3f})")
    print(f"report: {sum(n.endswith('.png') for n in report)} figures, {size:.1f} MB with the SVGs")
    worst = max(max(memory), max(folder))
    print(f"bar (<= 10 s): {'met' if worst <= 10.0 else 'NOT met'} (slowest rendering {worst:.2f} s)")
    return 0 if worst <= 10.0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
