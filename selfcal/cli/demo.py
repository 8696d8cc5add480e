"""Simulate the seed-000 block, adjust it with the paper's AP models and print the comparison."""
from __future__ import annotations

import argparse
import os
import sys

from ..batch import PAPER_MODELS, available_models, run_cell
from ..block import prune
from ..io.atomic import atomic_folder
from ..io.block_folder import write_block
from ..io.results import write_files
from ..simulate import simulate_uav, truth_files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="demo-results", metavar="DIR",
                        help="folder for the simulated blocks and the results (default: demo-results)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenario", default="type3", choices=["type1", "type2", "type3", "type4"])


def _fmt(value, digits=2):
    return "n/a" if value is None else f"{value:.{digits}f}"


def run(args: argparse.Namespace) -> int:
    print("simulating the seed-000 UAV block (28 images, local + Brown distortion) ...", file=sys.stderr)
    sim = simulate_uav(seed=args.seed, distortion="local+brown")
    block = prune(sim.blocks[args.scenario])
    models = available_models(PAPER_MODELS)
    rows = []
    with atomic_folder(args.out) as tmp:
        write_block(sim.blocks[args.scenario], os.path.join(tmp, "blocks", args.scenario))
        os.makedirs(os.path.join(tmp, "blocks", "truth"))
        write_files(os.path.join(tmp, "blocks", "truth"), truth_files(sim.truth))
        for model in models:
            print(f"adjusting {args.scenario} with --ap {model} ...", file=sys.stderr, flush=True)
            cell = run_cell(args.scenario, block, model)
            if cell.error:
                rows.append((model, None, cell.error))
                continue
            folder = os.path.join(tmp, f"{args.scenario}-{model.replace(':', '-')}")
            os.makedirs(folder)
            write_files(folder, cell.files)
            rows.append((model, cell.files["summary.json"], None))
    print(f"\nseed-000 block, {args.scenario}, GSD {sim.truth.gsd_m * 100:.1f} cm; results in {args.out}")
    print(f"{'AP model':<16}{'sigma0 px':>10}{'RMSD XY':>9}{'RMSD Z':>8}{'RMS sXY':>9}{'RMS sZ':>8}{'APs':>6}"
          "   (RMSD and RMS sigma in GSD)")
    for model, s, error in rows:
        if error:
            print(f"{model:<16} failed: {error.splitlines()[0]}")
            continue
        print(f"{model:<16}{_fmt(s['sigma0_px'], 3):>10}{_fmt(s['rmsd_chk_xy_gsd']):>9}{_fmt(s['rmsd_chk_z_gsd']):>8}"
              f"{_fmt(s['rms_sigma_tie_xy_gsd']):>9}{_fmt(s['rms_sigma_tie_z_gsd']):>8}{s['n_ap_initial']:>6}")
    return 0
