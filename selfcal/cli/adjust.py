"""Adjust a block folder and write a results folder."""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

from ..adjust import AdjustOptions
from ..ap import AP_FAMILIES, parse_ap_spec
from ..batch import ALL_MODELS
from ..errors import UsageError
from ..io import read_block
from ..io.results import results_from_files, write_results
from ..report import model_choice_table, render_report, result_files
from ..stats import SnoopingOptions, VarianceOptions
from ..workflows import adjust_with_tests, choose_ap_model, parse_candidate
from . import pushbroom
from .options import (ap_option, grid_option, progress_printer, round_printer, screening_options, test_options,
                      trajectory_options)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("block", metavar="BLOCK", help="block folder (DESIGN.md §3)")
    parser.add_argument("--out", required=True, metavar="RESULTS", help="results folder to write (replaced)")
    ap_option(parser)
    grid_option(parser)
    test_options(parser)
    trajectory_options(parser)
    parser.add_argument("--no-report", action="store_true",
                        help="do not render report.html and figures/ (selfcal report RESULTS does it later)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    pushbroom.adjust_arguments(parser)


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    block = read_block(args.block)
    if block.is_pushbroom:
        return pushbroom.run_adjust(block, args)
    for message in block.dropped.messages[:20]:
        print(f"warning: {message}", file=sys.stderr)
    if len(block.dropped.messages) > 20:
        print(f"warning: ... and {len(block.dropped.messages) - 20} more (see summary.json)", file=sys.stderr)
    if not args.quiet:
        print(f"{block.name}: {len(block.images)} images, {len(block.points)} points, "
              f"{len(block.observations)} image observations; AP model {args.ap}", file=sys.stderr)
    snooping = SnoopingOptions(critical=args.snoop, mode=args.snoop_mode)
    screening = screening_options(args) if args.screen else None
    options = AdjustOptions(ap=args.ap, grid=args.grid, gnss_drift=args.gnss_drift, imu_drift=args.imu_drift,
                            lever_arm=args.lever_arm, boresight=args.boresight)
    extra_files = {}
    if args.ap == "auto" or args.ap.startswith("auto:"):
        choice = _choose(block, args, options, snooping)
        options = replace(options, ap=choice.model, grid=choice.grid)
        extra_files["model_choice.csv"] = model_choice_table(choice)
    tested = adjust_with_tests(block, options, snooping, screening,
                               progress=None if args.quiet else progress_printer(block.image_sigma_px),
                               report=None if args.quiet else round_printer(),
                               variance=VarianceOptions() if args.variance_components else None)
    files = result_files(block, tested, {"seconds": time.perf_counter() - t0, "grid": list(args.grid)},
                         screening) | extra_files
    if not args.no_report:
        t_report = time.perf_counter()
        files |= render_report(results_from_files(files))
        if not args.quiet:
            print(f"report rendered in {time.perf_counter() - t_report:.1f} s", file=sys.stderr)
    write_results(args.out, files)
    s = files["summary.json"]
    print(f"sigma0 {s['sigma0_px']:.3f} px, check points RMSD XY {_m(s['rmsd_chk_xy_m'])} Z {_m(s['rmsd_chk_z_m'])}"
          f" ({s['n_chk_used']} CHK, {s['n_gcp_used']} GCP), {s['n_obs_rejected']} observations rejected, "
          f"{s['n_ap_significant']}/{s['n_ap_initial']} APs; results in {args.out}", file=sys.stderr)
    if not tested.result.converged:
        print(f"selfcal adjust: error: the adjustment did not converge: {tested.result.reason}", file=sys.stderr)
        return 1
    return 0


def _choose(block, args, options, snooping):
    """``--ap auto`` (the ten default models) or ``--ap auto:MODEL,MODEL@GxXGy,...``: choose by BIC."""
    listed = args.ap.partition(":")[2]
    names = [m for m in listed.split(",") if m.strip()] if listed else list(ALL_MODELS)
    candidates = []
    for name in names:
        try:
            model, grid_ = parse_candidate(name, args.grid)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if parse_ap_spec(model)[0] not in AP_FAMILIES:
            raise UsageError(f"unknown AP model '{model}' in --ap {args.ap} (known: {', '.join(AP_FAMILIES)})")
        candidates.append((model, grid_))
    if not args.quiet:
        print(f"choosing the AP model among {len(candidates)} candidates by BIC (blunders first, with the "
              f"richest candidate) ...", file=sys.stderr)

    def show(score):
        if args.quiet:
            return
        status = f"BIC {score.bic:.1f}, sigma0 {score.sigma0_px:.4f} px" if score.bic is not None else \
            f"failed: {(score.error or '').splitlines()[0]}"
        print(f"  {score.label}: {score.n_ap} camera parameters, {status}", file=sys.stderr, flush=True)
    choice = choose_ap_model(block, candidates, options, snooping, progress=show)
    label = choice.model + (f"@{choice.grid[0]}x{choice.grid[1]}" if choice.model.startswith("wavelet") else "")
    print(f"chosen AP model: {label} (smallest BIC; {choice.n_blunders} observations left out as blunders for "
          f"every candidate; scores in model_choice.csv)", file=sys.stderr)
    return choice


def _m(value) -> str:
    return "n/a" if value is None else f"{value:.3f} m"
