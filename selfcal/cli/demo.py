"""Simulate the seed-000 block and run the paper's 24 cases (4 control scenarios x 6 AP models)."""
from __future__ import annotations

import argparse
import os
import time

from .outcome import progress
from .options import count, force_option, number


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="demo-results", metavar="DIR",
                        help="folder for the simulated blocks, the results and the table (default: demo-results)")
    parser.add_argument("--seed", type=count(0, 2**32 - 1), default=0)
    force_option(parser)
    parser.add_argument("--blunder-rate", type=number(0.0, 0.5, high_open=True), default=0.003,
                        help="share of image observations with a 4-15 px blunder (default 0.003)")
    parser.add_argument("--distortion-scale", type=number(0.0, 100.0), default=4.0, metavar="S",
                        help="strength of the simulated local + Brown field (default 4: -44 px of radial distortion "
                             "in the corners, 1.2 %% of the half-diagonal, and local bumps of 5-10 px, an uncorrected "
                             "wide-angle lens as in seed 000, where no APs left several GSD at the check points)")
    parser.add_argument("--scheduler", default="local",
                        help="'local' Dask cluster (default), 'serial', or the address of a Dask scheduler")


def run(args: argparse.Namespace) -> int:
    from ..batch import PAPER_MODELS, CellSettings, available_models, run_matrix
    from ..block import prune
    from ..io.atomic import atomic_folder
    from ..io.block_folder import write_block
    from ..io.output import failed_run_folder, output_folder
    from ..io.results import write_files
    from ..report.compare import comparison_markdown, comparison_rows
    from ..simulate import SCENARIOS, simulate_uav, truth_files
    from .compare import finish_matrix, write_matrix
    t0 = time.perf_counter()
    args.out = output_folder(args.out, (), args.force)
    progress("simulating the seed-000 UAV block (28 images, local + Brown distortion, blunders) ...")
    sim = simulate_uav(seed=args.seed, distortion="local+brown", blunder_rate=args.blunder_rate,
                       distortion_scale=args.distortion_scale)
    blocks = {name: prune(sim.blocks[name]) for name in SCENARIOS}
    models = available_models(PAPER_MODELS)
    total = len(blocks) * len(models)
    count = []

    def done(cell):
        count.append(cell)
        status = "failed" if cell.error else f"{cell.seconds:.1f} s"
        progress(f"[{len(count)}/{total}] {cell.scenario} {cell.model}: {status}")

    cells = run_matrix(blocks, models, CellSettings(), None if args.scheduler == "serial" else args.scheduler,
                       None, done, say=progress)
    rows = comparison_rows(cells)
    failed = [c for c in cells if c.error]
    # a demo with a failed case never replaces earlier results: its files go beside them, or nowhere
    target, where = (args.out, f"results in {args.out}") if not failed else failed_run_folder(args.out)
    if target is not None:
        with atomic_folder(target) as tmp:
            progress(f"writing the simulated blocks into {target} ...")
            for name in SCENARIOS:
                write_block(sim.blocks[name], os.path.join(tmp, "blocks", name))
            os.makedirs(os.path.join(tmp, "blocks", "truth"))
            write_files(os.path.join(tmp, "blocks", "truth"), truth_files(sim.truth))
            write_matrix(tmp, cells, rows, "seed-000 block, 24 cases")
    progress(comparison_markdown(rows))
    progress(f"GSD {sim.truth.gsd_m * 100:.1f} cm; 'gruen' (Grün's 44 polynomials) stands for BINGO's AP set.")
    return finish_matrix(args, rows, failed, f"{total} adjustments, {time.perf_counter() - t0:.0f} s in all", where,
                         target)
