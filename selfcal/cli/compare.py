"""Adjust blocks with several AP models and tabulate the comparison (seed 000's tables)."""
from __future__ import annotations

import argparse
import os
import sys
import time

from ..ap import parse_ap_spec, AP_FAMILIES
from ..batch import ALL_MODELS, CellSettings, run_matrix
from ..errors import BlockError, UsageError
from ..io import read_block
from ..io.atomic import atomic_folder
from ..io.results import results_from_files, write_files
from ..report import best_cells, render_comparison_report, render_report
from ..report.compare import comparison_csv, comparison_markdown, comparison_rows
from ..stats import SnoopingOptions, VarianceOptions
from . import pushbroom
from .options import grid_option, screening_options, test_options, trajectory_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("blocks", nargs="+", metavar="BLOCK", help="block folders (one scenario each)")
    parser.add_argument("--ap", default=",".join(ALL_MODELS), metavar="MODELS",
                        help="comma-separated AP models (default: all ten)")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results and the table")
    grid_option(parser)
    test_options(parser)
    trajectory_options(parser)
    parser.add_argument("--no-screen", action="store_true", help="do not screen the APs (screening is on here)")
    parser.add_argument("--scheduler", default="local", metavar="ADDRESS",
                        help="Dask scheduler: 'local' (a cluster on this machine, default), 'serial' "
                             "(no Dask), or the address of a running scheduler (tcp://host:8786)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes of the local cluster")
    parser.add_argument("--no-report", action="store_true",
                        help="no report.html (the comparison's, and each scenario's best model's)")
    pushbroom.compare_arguments(parser)


def run(args: argparse.Namespace) -> int:
    if len(args.blocks) == 1:
        block = read_block(args.blocks[0])
        if block.is_pushbroom:
            return pushbroom.run_compare(block, args)
    models = [m.strip() for m in args.ap.split(",") if m.strip()]
    for m in models:
        if parse_ap_spec(m)[0] not in AP_FAMILIES:
            raise UsageError(f"unknown AP model '{m}' (known: {', '.join(AP_FAMILIES)})")
    blocks = {}
    for folder in args.blocks:
        name = os.path.basename(os.path.normpath(folder))
        if name in blocks:
            raise BlockError(folder, f"two blocks are named '{name}'; give each scenario its own folder name")
        blocks[name] = read_block(folder)
    settings = CellSettings(
        grid=args.grid, gnss_drift=args.gnss_drift, imu_drift=args.imu_drift, lever_arm=args.lever_arm,
        boresight=args.boresight,
        snooping=SnoopingOptions(critical=args.snoop, mode=args.snoop_mode),
        screening=None if args.no_screen else screening_options(args),
        variance=VarianceOptions() if args.variance_components else None)
    total = len(blocks) * len(models)
    finished = []

    def done(cell):
        finished.append(cell)
        status = "failed: " + cell.error.splitlines()[0] if cell.error else f"{cell.seconds:.1f} s"
        print(f"[{len(finished)}/{total}] {cell.scenario} {cell.model}: {status}", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    scheduler = None if args.scheduler == "serial" else args.scheduler
    cells = run_matrix(blocks, models, settings, scheduler, args.workers, done)
    seconds = time.perf_counter() - t0
    rows = comparison_rows(cells)
    with atomic_folder(args.out) as tmp:
        write_matrix(tmp, cells, rows, "selfcal compare", report=not args.no_report)
    print(comparison_markdown(rows))
    print(f"{total} adjustments in {seconds:.1f} s ({args.scheduler}); results in {args.out}", file=sys.stderr)
    return 1 if any(c.error for c in cells) else 0


def cell_folder(scenario: str, model: str) -> str:
    """Results folder of one cell, relative to the comparison folder."""
    return f"{scenario}/{model.replace(':', '-')}"


def write_matrix(folder: str, cells, rows: list[dict], title: str, report: bool = True) -> None:
    """Write every cell's results, the comparison table and, with ``report``, the comparison report and
    the report of each scenario's best model (smallest check-point RMSD)."""
    for cell in cells:
        if cell.files:
            write_files(os.path.join(folder, cell_folder(cell.scenario, cell.model)), cell.files)
    files = {"comparison.csv": comparison_csv(rows), "comparison.md": comparison_markdown(rows, title)}
    if report:
        t0 = time.perf_counter()
        by_key = {(c.scenario, c.model): c for c in cells}
        links = {}
        for scenario, row in best_cells(rows).items():
            cell = by_key[(scenario, row["ap_model"])]
            name = cell_folder(scenario, cell.model)
            write_files(os.path.join(folder, name), render_report(results_from_files(cell.files)))
            links[(scenario, cell.model)] = f"{name}/report.html"
        files |= render_comparison_report(rows, comparison_markdown(rows), links, title)
        print(f"reports of the comparison and of {len(links)} best models rendered in "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
    write_files(folder, files)
