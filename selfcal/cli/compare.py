"""Adjust blocks with several AP models and tabulate the comparison (seed 000's tables)."""
from __future__ import annotations

import argparse
import os
import time

from ..ap import ALL_MODELS
from ..errors import BlockError, UsageError
from .outcome import finish, progress, steps
from .options import ap_list, count, force_option, grid_option, screening_options, test_options, trajectory_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("blocks", nargs="+", metavar="BLOCK", help="block folders (one scenario each)")
    parser.add_argument("--ap", default=",".join(ALL_MODELS), metavar="MODELS", type=ap_list,
                        help="comma-separated AP models (default: all ten)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="folder for the results and the table (replaced if selfcal wrote it)")
    force_option(parser)
    grid_option(parser)
    test_options(parser)
    trajectory_options(parser)
    parser.add_argument("--no-screen", action="store_true", help="do not screen the APs (screening is on here)")
    parser.add_argument("--scheduler", default="local", metavar="ADDRESS",
                        help="Dask scheduler: 'local' (a cluster on this machine, default), 'serial' "
                             "(no Dask), or the address of a running scheduler (tcp://host:8786)")
    parser.add_argument("--workers", type=count(1), default=None, help="worker processes of the local cluster")
    parser.add_argument("--no-report", action="store_true",
                        help="no report.html (the comparison's, and each scenario's best model's)")
    group = parser.add_argument_group("pushbroom blocks (seed 001)")
    group.add_argument("--sensor-models", metavar="MODELS", help="sensor models to compare (default: M1..M7)")
    group.add_argument("--gcps", metavar="N,N", help="GCP counts (default 3,4,5)")
    group.add_argument("--dem", metavar="GEOTIFF",
                       help="terrain for mono restitution (EPSG:4326, ellipsoidal heights; default: [terrain] of "
                            "block.toml)")
    group.add_argument("--no-attitude", action="store_true",
                       help="ignore attitude.csv; M6's corrections take the whole attitude (seed 001, Table 5)")


def run(args: argparse.Namespace) -> int:
    progress(f"reading {', '.join(map(str, args.blocks))} ...")     # at once: the engine's import takes a second
    # the engine, Dask and the report load here, not for --help (issue 45)
    from ..ap import AP_FAMILIES, parse_ap_spec
    from ..batch import CellSettings, run_matrix
    from ..io import read_block
    from ..io.atomic import atomic_folder
    from ..io.output import check_inputs, failed_run_folder, output_folder
    from ..report.compare import comparison_markdown, comparison_rows
    from ..stats import SnoopingOptions, VarianceOptions
    from ..workflows.adjust import offers_sensor_models
    args.out = output_folder(args.out, (*args.blocks, args.dem), args.force)
    if len(args.blocks) == 1:
        block = read_block(args.blocks[0])
        check_inputs(args.out, [*(block.image_files or {}).values(), block.dem_path])
        if offers_sensor_models(block):
            return _run_study(block, args)
    for flag, dest in (("--sensor-models", "sensor_models"), ("--gcps", "gcps"), ("--dem", "dem"),
                       ("--no-attitude", "no_attitude")):
        if getattr(args, dest):
            raise UsageError(f"{flag} applies to pushbroom blocks only")
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
        check_inputs(args.out, (blocks[name].image_files or {}).values())
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
        progress(f"[{len(finished)}/{total}] {cell.scenario} {cell.model}: {status}")

    t0 = time.perf_counter()
    scheduler = None if args.scheduler == "serial" else args.scheduler
    cells = run_matrix(blocks, models, settings, scheduler, args.workers, done, say=progress)
    seconds = time.perf_counter() - t0
    rows = comparison_rows(cells)
    failed = [c for c in cells if c.error]
    # a comparison with a failed cell never replaces earlier results: its files go beside them, or nowhere
    target, where = (args.out, f"results in {args.out}") if not failed else failed_run_folder(args.out)
    if target is not None:
        with atomic_folder(target) as tmp:
            write_matrix(tmp, cells, rows, "selfcal compare", report=not args.no_report)
    progress(comparison_markdown(rows))
    return finish_matrix(args, rows, failed, f"{total} adjustments in {seconds:.1f} s ({args.scheduler})", where,
                         target)


def _run_study(block, args) -> int:
    """Seed 001's study on a pushbroom block: M1-M7 x GCP counts x image sets (no data snooping: the rows of
    M1-M4 are there to show the model error that snooping would reject)."""
    from ..adjust import AdjustOptions, SensorOptions
    from ..batch.seed001 import run_study
    from ..io.atomic import atomic_folder
    from ..io.dem import read_dem
    from ..io.results import write_files
    from ..report.compare import study_csv, study_markdown
    from ..sensors.pushbroom import SENSOR_MODELS
    from ..workflows.seed001 import ATTITUDE_FREE_SIGMA
    t0 = time.perf_counter()
    dem = read_dem(args.dem) if args.dem else read_dem(block.dem_path) if block.dem_path else block.terrain_height_m
    if dem is None:
        raise UsageError("the mono cases restitute the check points on the terrain: give --dem or [terrain] "
                         "in block.toml")
    models = [m.strip().upper() for m in (args.sensor_models or ",".join(SENSOR_MODELS)).split(",") if m.strip()]
    unknown = [m for m in models if m not in SENSOR_MODELS]
    if unknown:
        raise UsageError(f"unknown sensor model(s) {', '.join(unknown)} (known: {', '.join(SENSOR_MODELS)})")
    try:
        counts = sorted({int(v) for v in (args.gcps or "3,4,5").split(",") if v.strip()})
    except ValueError:
        raise UsageError(f"--gcps must be numbers separated by commas, found '{args.gcps}'") from None
    prior = ATTITUDE_FREE_SIGMA if args.no_attitude else None

    def show(case):
        status = case.failure.splitlines()[0] if case.rmse_m is None else \
            "RMSE " + " / ".join(f"{v:.2f}" for v in case.rmse_m) + " m"
        progress(f"{case.images} {case.model} {case.n_gcp} GCP: {status}")

    cases, focal, sigma = run_study(block, dem, models, counts, prior_sigma=prior, progress=show,
                                    options=AdjustOptions(sensor=SensorOptions(attitude_telemetry=not args.no_attitude)))
    table = study_markdown(cases, focal, sigma)
    with atomic_folder(args.out) as tmp:
        write_files(tmp, {"comparison.md": table, "comparison.csv": study_csv(cases)})
    progress(table)
    return finish(args, f"{len(cases)} adjustments in {time.perf_counter() - t0:.1f} s; results in {args.out}",
                  {"n_adjustments": len(cases)}, [os.path.abspath(args.out)])


def finish_matrix(args, rows: list[dict], failed: list, done: str, where: str, target: str | None) -> int:
    """The outcome of a comparison (compare, demo): the best model of each scenario, the cells' key figures for
    --json, and the error line when a cell failed."""
    from ..report import best_cells
    best = best_cells(rows)
    line = f"{done}; best " + ", ".join(f"{s} {r['ap_model']}" for s, r in best.items()) if best else done
    figures = {"best": {s: r["ap_model"] for s, r in best.items()},
               "cells": [{k: r.get(k) for k in ("scenario", "ap_model", "rmsd_xy_m", "rmsd_z_m", "sigma0_px",
                                                  "error")} for r in rows]}
    error = None
    if failed:
        error = (f"{len(failed)} of {len(rows)} {'cases' if args.command == 'demo' else 'adjustments'} failed "
                 f"({', '.join(f'{c.scenario} {c.model}' for c in failed[:5])}{', ...' if len(failed) > 5 else ''}); "
                 f"{where}")
    return finish(args, f"{line}; {where}", figures, [os.path.abspath(target)] if target else [],
                  exit_code=1 if failed else 0, error=error)


def cell_folder(scenario: str, model: str) -> str:
    """Results folder of one cell, relative to the comparison folder."""
    return f"{scenario}/{model.replace(':', '-')}"


def write_matrix(folder: str, cells, rows: list[dict], title: str, report: bool = True) -> None:
    """Write every cell's results, the comparison table and, with ``report``, the comparison report and
    the report of each scenario's best model (smallest check-point RMSD)."""
    from ..io.results import results_from_files, write_files
    from ..report import best_cells, render_comparison_report, render_report
    from ..report.compare import comparison_csv, comparison_markdown
    progress(f"writing the results of {sum(bool(c.files) for c in cells)} adjustments ...")
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
            say = steps(f"rendering the report of {scenario} {cell.model}")
            write_files(os.path.join(folder, name), render_report(results_from_files(cell.files), say=say))
            links[(scenario, cell.model)] = f"{name}/report.html"
        progress("rendering the comparison report ...")
        files |= render_comparison_report(rows, comparison_markdown(rows), links, title)
        progress(f"reports of the comparison and of {len(links)} best models rendered in "
                 f"{time.perf_counter() - t0:.1f} s")
    write_files(folder, files)
