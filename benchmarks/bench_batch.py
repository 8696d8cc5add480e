"""The demo's 24 cases (4 control scenarios x 6 AP models) serially and on a local Dask cluster.

The block is the one of ``selfcal demo``: the seed-000 UAV block, local +
Brown field of a wide-angle lens (distortion scale 4), 0.3 % blunders. Every
cell is an adjustment with data snooping and AP screening. Measured in the same
run, one after the other:

* serial: every cell in this process (the peer), with one BLAS thread as each Dask worker has (BLAS's own
  threads change the last digits, 1-2e-12 in summary.json; the passes over the chunks still take two threads
  and give the same bits as one);
* dask: a local cluster of ``--workers`` processes (default: the cores), one BLAS
  thread each, the wavelet cells submitted first.

Prints both wall times, their ratio, and the largest difference between the
two runs over every number of every summary.json (they must be identical).

Run: ``python benchmarks/bench_batch.py [--workers 2] [--seed 0]`` (about 7 minutes on 2 cores).
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args(argv)

    from selfcal.batch import PAPER_MODELS, CellSettings, available_models, run_matrix
    from selfcal.allocator import keep_freed_memory
    from selfcal.block import prune
    from selfcal.simulate import SCENARIOS, simulate_uav

    keep_freed_memory()
    sim = simulate_uav(seed=args.seed, distortion="local+brown", blunder_rate=0.003, distortion_scale=4.0)
    blocks = {name: prune(sim.blocks[name]) for name in SCENARIOS}
    models = available_models(PAPER_MODELS)
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):
        serial = run_matrix(blocks, models, CellSettings(), scheduler=None)
    t_serial = time.perf_counter() - t0
    t0 = time.perf_counter()
    parallel = run_matrix(blocks, models, CellSettings(), scheduler="local", n_workers=args.workers)
    t_dask = time.perf_counter() - t0

    worst = 0.0
    for a, b in zip(serial, parallel):
        assert (a.scenario, a.model) == (b.scenario, b.model) and a.error is None and b.error is None
        for key, value in a.files["summary.json"].items():
            if isinstance(value, float) and key != "seconds" and np.isfinite(value):
                worst = max(worst, abs(value - b.files["summary.json"][key]))
    print(f"{len(serial)} cases: serial {t_serial:.1f} s, dask {t_dask:.1f} s "
          f"(serial / dask = {t_serial / t_dask:.2f}); largest difference in summary.json: {worst:.3g}")
    return 0 if worst == 0.0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
