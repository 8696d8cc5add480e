"""Adjust a block folder and write a results folder."""
from __future__ import annotations

import argparse
import sys
import time

from ..adjust import AdjustOptions
from ..io import read_block
from ..io.results import write_results
from ..report import result_files
from ..stats import SnoopingOptions, VarianceOptions, adjust_with_tests
from .options import (ap_option, grid_option, progress_printer, round_printer, screening_options, test_options,
                      trajectory_options)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("block", metavar="BLOCK", help="block folder (DESIGN.md §3)")
    parser.add_argument("--out", required=True, metavar="RESULTS", help="results folder to write (replaced)")
    ap_option(parser)
    grid_option(parser)
    test_options(parser)
    trajectory_options(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    block = read_block(args.block)
    for message in block.dropped.messages[:20]:
        print(f"warning: {message}", file=sys.stderr)
    if len(block.dropped.messages) > 20:
        print(f"warning: ... and {len(block.dropped.messages) - 20} more (see summary.json)", file=sys.stderr)
    if not args.quiet:
        print(f"{block.name}: {len(block.images)} images, {len(block.points)} points, "
              f"{len(block.observations)} image observations; AP model {args.ap}", file=sys.stderr)
    snooping = SnoopingOptions(critical=args.snoop, mode=args.snoop_mode)
    screening = screening_options(args) if args.screen else None
    tested = adjust_with_tests(block, AdjustOptions(ap=args.ap, grid=args.grid, gnss_drift=args.gnss_drift,
                                                    imu_drift=args.imu_drift), snooping, screening,
                               progress=None if args.quiet else progress_printer(block.image_sigma_px),
                               report=None if args.quiet else round_printer(),
                               variance=VarianceOptions() if args.variance_components else None)
    files = result_files(block, tested, {"seconds": time.perf_counter() - t0}, screening)
    write_results(args.out, files)
    s = files["summary.json"]
    print(f"sigma0 {s['sigma0_px']:.3f} px, check points RMSD XY {_m(s['rmsd_chk_xy_m'])} Z {_m(s['rmsd_chk_z_m'])}"
          f" ({s['n_chk_used']} CHK, {s['n_gcp_used']} GCP), {s['n_obs_rejected']} observations rejected, "
          f"{s['n_ap_significant']}/{s['n_ap_initial']} APs; results in {args.out}", file=sys.stderr)
    if not tested.result.converged:
        print(f"selfcal adjust: error: the adjustment did not converge: {tested.result.reason}", file=sys.stderr)
        return 1
    return 0


def _m(value) -> str:
    return "n/a" if value is None else f"{value:.3f} m"
