"""Adjust a block folder and write a results folder, whatever the block's sensors."""
from __future__ import annotations

import argparse
import os
import sys
import time

from ..adjust import SolverOptions
from ..errors import UsageError
from .outcome import finish, progress, say, steps
from .options import (ap_at_option, ap_option, count, force_option, grid_option, number, progress_printer,
                      robust_options, round_printer, screening_options, test_options, trajectory_options)

#: options that only blocks whose sensors offer seed 001's sensor models take (dest -> flag)
_SEED001_OPTIONS = {"sensor_model": "--sensor-model", "images": "--images", "gcps": "--gcps",
                    "keep_focal": "--keep-focal", "dem": "--dem", "no_attitude": "--no-attitude"}
def _jitter_option(text: str) -> str:
    """``--jitter``: checked as it is read (a wrong name is exit 2 before any work)."""
    import argparse
    from ..sensors.pushbroom.jitter import parse_jitter
    try:
        parse_jitter(text)
    except UsageError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


#: options that only frame blocks take
_FRAME_OPTIONS = {"lever_arm": "--lever-arm", "boresight": "--boresight"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("block", metavar="BLOCK", help="block folder (DESIGN.md §3)")
    parser.add_argument("--out", required=True, metavar="RESULTS",
                        help="results folder to write (replaced if selfcal wrote it; never the block or a folder "
                             "that holds it)")
    force_option(parser)
    ap_option(parser)
    ap_at_option(parser)
    grid_option(parser)
    test_options(parser)
    trajectory_options(parser)
    parser.add_argument("--no-report", action="store_true",
                        help="do not render report.html and figures/ (selfcal report RESULTS does it later)")
    parser.add_argument("--no-control-loo", action="store_true",
                        help="leave out the leave-one-out check of the control (control_loo.csv: each GCP's error "
                             "when the others alone hold the datum; one short re-adjustment per GCP)")
    parser.add_argument("--jackknife", type=count(0), default=0, metavar="G",
                        help="check the calibration's sigma: G groups of consecutive images (at most one per image) "
                             "each left out in turn and the block adjusted again; a camera parameter that scatters "
                             "over them beyond its sigma is named in summary.json calibration_precision and the "
                             "report (G more adjustments; default 0: not checked)")
    parser.add_argument("--no-half-block", action="store_true",
                        help="leave out the half-block check of the calibration (each half of the block, by strips, "
                             "adjusted on its own and the two APs compared: two more adjustments)")
    parser.add_argument("--scheduler", metavar="SPEC",
                        help="put each adjustment's object points and their observations on a Dask cluster, one "
                             "share per worker: 'local' (a worker process per core), 'local:N', or a running "
                             "scheduler's address (tcp://host:8786); the results equal one process's (sensors "
                             "other than frame cameras stay in this process). Default: one process")
    parser.add_argument("--max-iterations", type=count(1), default=SolverOptions.max_iterations, metavar="N",
                        help=f"Gauss-Newton / Levenberg-Marquardt iterations at most (default "
                             f"{SolverOptions.max_iterations}); a weakly determined block may need more")
    group = parser.add_argument_group("pushbroom blocks (seed 001)")
    group.add_argument("--sensor-model", metavar="MODEL",
                       help="M1..M7 of seed 001, or parameter names separated by commas (default: M6)")
    group.add_argument("--images", metavar="ID,ID", help="images to adjust: one (mono) or more (stereo); default all")
    group.add_argument("--gcps", type=count(1), metavar="N",
                       help="use N (3, 4 or 5) of the block's gcp, spread over the scene; the others are checked")
    group.add_argument("--keep-focal", action="store_true",
                       help="use block.toml's focal_mm as it is; by default each camera's focal length is first "
                            "calibrated (M7 on all images, every gcp) and then held, as seed 001 does")
    group.add_argument("--dem", metavar="GEOTIFF",
                       help="terrain for mono restitution (EPSG:4326, ellipsoidal heights; default: [terrain] of "
                            "block.toml)")
    group.add_argument("--no-attitude", action="store_true",
                       help="ignore attitude.csv; M6's corrections take the whole attitude (seed 001, Table 5)")
    parser.add_argument("--jitter", type=_jitter_option, default="none", metavar="SPEC",
                        help="line images (pushbroom, usgscsm-line, dimap, dg): attitude jitter as 1-D wavelet scaling "
                             "functions in time: auto (db4, the level and the power per axis chosen by the data), "
                             "wavelet1d:NAME (level chosen), wavelet1d:NAME:LEVEL (2^LEVEL cells per image), or none "
                             "(default); +details after any but none: the same space as the scaling functions and "
                             "wavelets of LEVEL - 1, its terms by scale")
    parser.add_argument("--jitter-sigma-urad", type=number(0.0, low_open=True), metavar="S",
                        help="a-priori sigma of every jitter coefficient (urad); default: estimated (variance "
                             "components)")
    group = parser.add_argument_group("terrain as observations (issue 42; satellite and pushbroom blocks in ECEF)")
    group.add_argument("--terrain-observations", nargs="?", const="", default=None, metavar="GEOTIFF",
                       help="observe every tie point's height on this DEM (EPSG:4326; default: [terrain] dem of "
                            "block.toml), with --terrain-sigma-m; control and check points get none. The heights "
                            "are tested with the rays (data snooping rejects a changed or vegetated area) and "
                            "--variance-components estimates their sigma (group terrain). Not --dem, which is the "
                            "terrain of mono restitution")
    group.add_argument("--terrain-cloud", metavar="CSV",
                       help="observe every tie point's height on a ground point cloud instead of a DEM (CSV with "
                            "lat_deg,lon_deg,h_m: WGS 84, ellipsoidal, or X,Y,Z: ECEF m): a plane through the 8 "
                            "nearest cloud points at the tie point; with --terrain-sigma-m, tested and weighted as "
                            "--terrain-observations")
    group.add_argument("--terrain-sigma-m", type=number(0.0, low_open=True), metavar="S",
                       help="a-priori sigma of a DEM height at a tie point, m (required with --terrain-observations)")
    group.add_argument("--terrain-datum", choices=("ellipsoid", "egm96", "egm2008"), default="ellipsoid",
                       help="what the DEM's heights are over (default: the WGS 84 ellipsoid); egm96/egm2008 are "
                            "converted with PROJ's geoid grid, and refused where PROJ does not have it")
    parser.add_argument("--ap-cameras", metavar="ID,ID",
                        help="the cameras that get the APs (default all; required for wavelet1d when more than one "
                             "pushbroom camera is adjusted)")
    parser.add_argument("--ap-sigma-px", type=number(0.0, low_open=True), metavar="S",
                        help="a-priori sigma of every AP coefficient in px (default: free)")
    parser.add_argument("--orthonormal", action="store_true",
                        help="add to summary.json the correlation figures of Table 4 in an AP basis orthonormal over "
                             "the block's observations (max_abs_corr_orthonormal: the same fit, intra-AP 0), the "
                             "canonical correlations no AP basis can change (canonical_corr) and the design "
                             "cosines (design_cosine); see selfcal.stats.correlation")


def _given(args, dest: str) -> bool:
    value = getattr(args, dest)
    return value not in (None, False)


def _check_options(block, args) -> None:
    """An option that does not apply to the block's sensors is an error naming it."""
    from ..workflows.adjust import offers_sensor_models
    seed001 = offers_sensor_models(block)
    sensors = ", ".join(sorted({c.model for c in block.cameras.values()}))
    foreign = _FRAME_OPTIONS if seed001 else _SEED001_OPTIONS
    for dest, flag in foreign.items():
        if _given(args, dest):
            raise UsageError(f"{flag} does not apply to this block ({sensors} cameras)")
    if seed001 and (args.gnss_drift != 1 or args.imu_drift != 1) and not block.has_trajectory:
        raise UsageError(f"--gnss-drift / --imu-drift do not apply to this block ({sensors} cameras without "
                         "[gnss] or [imu])")
    _check_drift_times(block, args)
    if getattr(args, "trajectory_significance", None) is not None and not block.has_trajectory:
        raise UsageError(f"--trajectory-significance screens GNSS/IMU shift/drift terms; this block has no [gnss] "
                         f"or [imu] ({sensors} cameras)")
    if args.ap_sigma_px is not None and args.ap_sigma_px <= 0:
        raise UsageError("--ap-sigma-px must be positive")
    for flag, drift in (("--lever-arm", "--gnss-drift"), ("--boresight", "--imu-drift")):
        if getattr(args, flag[2:].replace("-", "_")) and getattr(args, drift[2:].replace("-", "_")) != -1:
            raise UsageError(f"{flag} cannot be separated from strip-wise shifts (the attitude hardly changes along "
                             f"a strip): give {drift} none with it")


def _check_drift_times(block, args) -> None:
    """A drift per strip needs the exposure times: GNSS positions without them (an ODM geo.txt, a CSV of
    positions) and the default --gnss-drift 1 are an error saying what to give instead."""
    import numpy as np

    images = block.images
    for flag, sensor, sigma, observed in (("--gnss-drift", "GNSS positions", block.gnss_sigma_m, images.position_m),
                                          ("--imu-drift", "IMU attitudes", block.imu_sigma_deg, images.attitude_rad)):
        order = getattr(args, flag[2:].replace("-", "_"))
        if sigma is None or order is None or order < 1:
            continue
        seen = np.isfinite(observed).all(axis=1)
        untimed = seen & np.isnan(images.time_s)
        if untimed.any():
            names = ", ".join(images.image_id[untimed][:3]) + (" ..." if untimed.sum() > 3 else "")
            raise UsageError(
                f"{flag} {order} (the default: a shift and a drift per strip) needs the exposure time of every "
                f"image, and {int(untimed.sum())} of the {int(seen.sum())} images with {sensor} have "
                f"none ({names}; an ODM geo.txt carries no times): give {flag} 0 (a shift per strip) or "
                f"{flag} none, or give the times (time_s in images.csv; `selfcal import gnss` of the JPEGs reads "
                f"their GPS time stamps)")


def _ap_cameras(block, args) -> tuple[str, ...] | None:
    """--ap-cameras, checked; wavelet1d on several pushbroom cameras needs it (DESIGN-NOTES)."""
    from ..ap import AP_FAMILIES, parse_ap_spec
    adjusted = args.images.split(",") if args.images else list(block.images.image_id)
    cameras = list(dict.fromkeys(block.images.camera_id[list(block.images.image_id).index(i)] for i in adjusted
                                 if i in list(block.images.image_id)))
    if args.ap_cameras:
        chosen = tuple(c.strip() for c in args.ap_cameras.split(",") if c.strip())
        unknown = [c for c in chosen if c not in cameras]
        if unknown:
            raise UsageError(f"--ap-cameras: {', '.join(unknown)} not among the cameras adjusted ({', '.join(cameras)})")
        return chosen
    if AP_FAMILIES.get(parse_ap_spec(args.ap)[0], AP_FAMILIES["none"]).domain == "line" and len(cameras) > 1:
        raise UsageError("--ap wavelet1d with several cameras: name the cameras whose detector lines are calibrated "
                         "with --ap-cameras. Tie points cannot tell an error common to all the lines (one orbit "
                         "plane) from the ground: the other lines are the reference (their payload calibration), "
                         "unless many GCPs control the block")
    return None


def _terrain(block, args):
    from ..io.dem import read_dem
    if args.dem:
        return read_dem(args.dem)
    if block.dem_path:
        return read_dem(block.dem_path)
    return block.terrain_height_m


def _terrain_observations(block, args):
    """``block`` with the terrain observations of --terrain-observations (unchanged without it); UsageError or
    BlockError (exit 2) for a missing sigma, a DEM that cannot be read or converted, a block that cannot take
    them."""
    from dataclasses import replace

    from ..block import TerrainObservations
    from ..errors import BlockError
    from ..geometry.terrain import ellipsoidal_dem
    from ..io.dem import read_dem
    from ..workflows.terrain import check_terrain_block
    if args.terrain_cloud is not None:
        return _terrain_cloud(block, args)
    if args.terrain_observations is None:
        for flag, given in (("--terrain-sigma-m", args.terrain_sigma_m is not None),
                            ("--terrain-datum", args.terrain_datum != "ellipsoid")):
            if given:
                raise UsageError(f"{flag} applies to --terrain-observations, which is not given")
        return block
    path = args.terrain_observations or block.dem_path
    if not path:
        raise UsageError("--terrain-observations without a DEM: give a GeoTIFF after it, or [terrain] dem in "
                         "block.toml")
    if args.terrain_sigma_m is None:
        raise UsageError("--terrain-observations needs --terrain-sigma-m S: the a-priori sigma of a DEM height at a "
                         "tie point (m; --variance-components estimates it from the block)")
    check_terrain_block(block)
    dem = read_dem(path)
    try:
        dem = ellipsoidal_dem(dem, args.terrain_datum)
    except ValueError as exc:
        raise BlockError(path, f"--terrain-datum {args.terrain_datum}: {exc}") from None
    return replace(block, terrain_observations=TerrainObservations(dem, float(args.terrain_sigma_m),
                                                                   source=str(path)))


def _terrain_cloud(block, args):
    """``block`` with the terrain observations of --terrain-cloud (see :func:`_terrain_observations`)."""
    from dataclasses import replace

    from ..block import TerrainObservations
    from ..errors import BlockError
    from ..geometry.cloud import CloudSurface
    from ..io.cloud import read_point_cloud
    from ..workflows.terrain import check_terrain_block
    if args.terrain_observations is not None:
        raise UsageError("--terrain-cloud and --terrain-observations: one terrain at a time (a DEM and a cloud "
                         "together are not built)")
    if args.terrain_datum != "ellipsoid":
        raise UsageError("--terrain-datum applies to a DEM; a cloud's heights are ellipsoidal (or ECEF)")
    if args.terrain_sigma_m is None:
        raise UsageError("--terrain-cloud needs --terrain-sigma-m S: the a-priori sigma of the cloud's height at a "
                         "tie point (m; --variance-components estimates it from the block)")
    check_terrain_block(block)
    kind, values = read_point_cloud(args.terrain_cloud)
    try:
        surface = CloudSurface.from_ecef(values) if kind == "ECEF" else CloudSurface(*values.T)
    except ValueError as exc:
        raise BlockError(args.terrain_cloud, str(exc)) from None
    return replace(block, terrain_observations=TerrainObservations(surface, float(args.terrain_sigma_m),
                                                                   source=str(args.terrain_cloud)))


def run(args: argparse.Namespace) -> int:
    if not args.scheduler:
        return _run(args)
    # the cluster first: a scheduler that cannot be reached is an error before any work
    from ..adjust.distributed import on_cluster
    from ..workflows.cluster import dask_client, parse_scheduler
    parse_scheduler(args.scheduler)
    with dask_client(args.scheduler, say=progress) as client, on_cluster(client):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    progress(f"reading {args.block} ...")       # at once: the engine's import takes a second of its own
    # the engine, the readers and the report load here, not for --help (issue 45: help answers at once)
    from ..adjust import AdjustOptions, APOptions, SensorOptions, TrajectoryOptions
    from ..io import read_block
    from ..io.output import check_inputs, failed_run_folder, output_folder
    from ..io.results import results_from_files, write_results
    from ..stats import SnoopingOptions, VarianceOptions
    from ..workflows.adjust import AdjustRequest, adjust_block, ap_candidates, default_ap_model, is_auto, \
        offers_sensor_models
    from ..workflows.seed001 import ATTITUDE_FREE_SIGMA
    t0 = time.perf_counter()
    if args.max_iterations < 1:
        raise UsageError(f"--max-iterations must be at least 1, found {args.max_iterations}")
    out = output_folder(args.out, (args.block, args.dem, args.terrain_observations or None, args.terrain_cloud),
                        args.force)
    block = read_block(args.block)
    defaulted = args.ap is None
    if defaulted:
        args.ap = default_ap_model(block)
    check_inputs(out, [*(block.image_files or {}).values(), block.dem_path])
    _check_options(block, args)
    block = _terrain_observations(block, args)
    for message in block.dropped.messages[:20]:
        print(f"warning: {message}", file=sys.stderr)
    if len(block.dropped.messages) > 20:
        print(f"warning: ... and {len(block.dropped.messages) - 20} more (see summary.json)", file=sys.stderr)
    if not args.quiet:
        print(f"{block.name}: {len(block.images)} images, {len(block.points)} points, "
              f"{len(block.observations)} image observations; AP model {args.ap}"
              + (" (the default for these cameras: see --ap in --help)" if defaulted else ""), file=sys.stderr)
    auto = is_auto(args.ap)
    seed001 = offers_sensor_models(block)
    height = _terrain(block, args) if seed001 else None
    if seed001 and args.images and len(args.images.split(",")) == 1 and height is None:
        raise UsageError("a mono adjustment restitutes the check points on the terrain: give --dem or "
                         "[terrain] in block.toml")
    sensor_model = args.sensor_model or ("M6" if seed001 else None)
    options = AdjustOptions(ap=APOptions("none" if auto else args.ap, grid=args.grid, cameras=_ap_cameras(block, args), sigma_px=args.ap_sigma_px, evaluated_at=args.ap_at), trajectory=TrajectoryOptions(gnss_drift=args.gnss_drift, imu_drift=args.imu_drift, lever_arm=args.lever_arm, boresight=args.boresight), sensor=SensorOptions(model=sensor_model, parameter_sigma=ATTITUDE_FREE_SIGMA if args.no_attitude and
                            (sensor_model or "").upper() == "M6" else None, attitude_telemetry=not args.no_attitude, jitter=args.jitter, jitter_sigma_rad=None if args.jitter_sigma_urad is None else args.jitter_sigma_urad * 1e-6), solver=SolverOptions(max_iterations=args.max_iterations))
    screening = screening_options(args) if args.screen else None
    image_ids = tuple(v.strip() for v in args.images.split(",") if v.strip()) if args.images else None
    # by keyword, so that a field added to AdjustRequest does not shift the others
    request = AdjustRequest(options=options, snooping=SnoopingOptions(critical=args.snoop, mode=args.snoop_mode),
                            screening=screening, variance=VarianceOptions() if args.variance_components else None,
                            candidates=ap_candidates(args.ap, args.grid) if auto else None, image_ids=image_ids, n_gcp=args.gcps,
                            keep_focal=args.keep_focal, height=height,
                            robust=robust_options(args), control_loo=not args.no_control_loo,
                            orthonormal=args.orthonormal, jackknife=args.jackknife,
                            half_block=not args.no_half_block, min_effect_px=args.min_effect_px)
    if request.candidates is not None and not args.quiet:         # --ap auto
        print(f"choosing the AP model among {len(request.candidates)} candidates by their cross-validated "
              f"prediction error (blunders first, with a reference candidate) ...", file=sys.stderr)
    adjusted = adjust_block(block, request, progress=None if args.quiet else progress_printer(block.image_sigma_px),
                            report=None if args.quiet else round_printer(),
                            say=say,
                            scores=None if args.quiet else _show_score)
    tested = adjusted.tested
    if seed001 and not args.quiet:
        for _, d in tested.screening_log:
            print(f"screening: dropped {d.camera_id}.{d.name} (t {d.t:.2f}, {d.reason})", file=sys.stderr)
    extra = {"seconds": time.perf_counter() - t0, "grid": list(args.grid)} | adjusted.summary_extra
    from ..report import model_choice_table, render_report, result_files     # the report's code after the work
    files = result_files(adjusted.block, tested, extra, screening, adjusted.checks, adjusted.track,
                         adjusted.plane)
    if adjusted.choice is not None:
        files["model_choice.csv"] = model_choice_table(adjusted.choice)
    if not args.no_report:
        t_report = time.perf_counter()
        files |= render_report(results_from_files(files), say=steps("rendering the report"))
        if not args.quiet:
            print(f"report rendered in {time.perf_counter() - t_report:.1f} s", file=sys.stderr)
    s = files["summary.json"]
    failure = s.get("failure") or (None if tested.result.converged else
                                   f"the adjustment did not converge: {tested.result.reason}")
    # a failed run never replaces earlier results: its files go beside them, or nowhere (and the line says so)
    target, where = (out, f"results in {args.out}") if not failure else failed_run_folder(out)
    if target is not None:
        write_results(target, files)
    line = (f"sigma0 {s['sigma0_px']:.3f} px, check points RMSD XY {_m(s['rmsd_chk_xy_m'])} Z {_m(s['rmsd_chk_z_m'])}"
            f" ({s['n_chk_used']} CHK, {s['n_gcp_used']} GCP), {s['n_obs_rejected']} observations rejected")
    if seed001 and s.get("rmse_chk_across_m") is not None:
        line += (f"; across {s['rmse_chk_across_m']:.2f} m, along {s['rmse_chk_along_m']:.2f} m, up "
                 f"{s['rmse_chk_up_m']:.2f} m")
    if not seed001:
        line += f", {s['n_ap_significant']}/{s['n_ap_initial']} APs"
    # what a free network's adjustments left out (observations behind their camera, undetermined points)
    for message in tested.result.block.dropped.messages[len(block.dropped.messages):]:
        if message.startswith("left out"):
            print(f"warning: {message}", file=sys.stderr)
    for note in s.get("notes", []):
        if note.startswith(("weakly determined", "object points not determined")) and note != failure:
            print(f"warning: {note}", file=sys.stderr)
    # what the robust cleaning and the control group's test found (images and control left out, the diagnosis)
    messages = (tested.cleaning.messages if tested.cleaning is not None else []) + \
        [n for n in tested.result.notes if n.startswith(("control point", "check point", "leave-one-out"))
         and ("fails the" in n or "left without rays" in n or n.startswith("leave-one-out"))]
    for message in dict.fromkeys(messages):
        print(f"warning: {message}", file=sys.stderr)
    robust = s.get("robust")
    if robust and not args.quiet:
        print(f"robust cleaning ({robust['loss']}): {robust['n_rejected']} gross errors rejected "
              f"({100 * robust['share_rejected']:.1f} %), {robust.get('n_readmitted', 0)} taken back; diagnosis "
              f"{robust['diagnosis']}", file=sys.stderr)
    figures = {key: s.get(key) for key in _FIGURES if key in s}
    written = [os.path.abspath(target)] if target is not None else []
    return finish(args, f"{line}; {where}", figures, written, exit_code=1 if failure else 0,
                  error=f"{failure}; {where}" if failure else None)


#: the summary's key figures in ``--json``'s document (summary.json holds them all)
_FIGURES = ("converged", "sigma0_px", "rmsd_chk_xy_m", "rmsd_chk_z_m", "rmse_chk_across_m", "rmse_chk_along_m",
            "rmse_chk_up_m", "n_chk_used", "n_gcp_used", "n_obs_rejected", "n_ap_significant", "n_ap_initial",
            "ap_model", "failure")


def _show_score(score) -> None:
    if score.prediction is not None:
        status = (f"{score.n_ap} camera parameters, prediction error {score.prediction.rmse_px:.4f} ± "
                  f"{score.prediction.se_px:.4f} px, BIC {score.bic:.1f}, sigma0 {score.sigma0_px:.4f} px")
    elif score.error:
        status = f"failed: {score.error.splitlines()[0]}"
    else:
        status = f"image-space BIC {score.field_bic:.1f} ({score.field_k} coefficients): not short-listed"
    print(f"  {score.label}: {status}", file=sys.stderr, flush=True)


def _m(value) -> str:
    return "n/a" if value is None else f"{value:.3f} m"
