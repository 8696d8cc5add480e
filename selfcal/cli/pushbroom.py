"""The pushbroom side of ``selfcal adjust`` and ``selfcal compare`` (seed 001): options and wiring."""
from __future__ import annotations

import argparse
import sys
import time

from ..adjust.pushbroom import SENSOR_MODELS, pushbroom_block, sensor_model
from ..ap.line import create_line_ap
from ..batch.pushbroom import ATTITUDE_FREE_SIGMA, calibrate_focal, choose_gcps, run_case, run_study, with_focal
from ..errors import UsageError
from ..io.atomic import atomic_folder
from ..io.dem import read_dem
from ..io.results import results_from_files, write_files, write_results
from ..report.pushbroom import pushbroom_files, render_pushbroom_report, study_csv, study_markdown
from ..stats.snooping import SnoopingOptions
from .options import screening_options

__all__ = ["adjust_arguments", "compare_arguments", "run_adjust", "run_compare"]


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dem", metavar="GEOTIFF",
                        help="pushbroom: terrain for mono restitution (EPSG:4326, ellipsoidal heights; default: "
                             "[terrain] of block.toml)")
    parser.add_argument("--no-attitude", action="store_true",
                        help="pushbroom: ignore attitude.csv; M6's corrections take the whole attitude "
                             "(seed 001, Table 5)")


def adjust_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("pushbroom blocks (seed 001)")
    group.add_argument("--sensor-model", default="M6", metavar="MODEL",
                       help="M1..M7 of seed 001, or parameter names separated by commas (default: M6)")
    group.add_argument("--images", metavar="ID,ID", help="images to adjust: one (mono) or more (stereo); default all")
    group.add_argument("--gcps", type=int, metavar="N",
                       help="use N (3, 4 or 5) of the block's gcp, spread over the scene; the others are checked")
    group.add_argument("--keep-focal", action="store_true",
                       help="use block.toml's focal_mm as it is; by default each camera's focal length is first "
                            "calibrated (M7 on all images, every gcp) and then held, as seed 001 does")
    group.add_argument("--ap-cameras", metavar="ID,ID",
                       help="pushbroom, --ap wavelet1d: the cameras whose detector lines get APs (required when "
                            "more than one camera is adjusted)")
    group.add_argument("--ap-sigma-px", type=float, metavar="S",
                       help="pushbroom, --ap wavelet1d: a-priori sigma of every line-AP coefficient (default: free)")
    _common(group)


def compare_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("pushbroom blocks (seed 001)")
    group.add_argument("--sensor-models", default=",".join(SENSOR_MODELS), metavar="MODELS",
                       help="sensor models to compare (default: M1..M7)")
    group.add_argument("--gcps", default="3,4,5", metavar="N,N", help="GCP counts (default 3,4,5)")
    _common(group)


def _terrain(block, args):
    if args.dem:
        return read_dem(args.dem)
    if block.dem_path:
        return read_dem(block.dem_path)
    return block.terrain_height_m


def _image_set(data, text: str | None) -> tuple[tuple[int, ...], list[str]]:
    ids = [img.image_id for img in data.images]
    if not text:
        return tuple(range(len(ids))), ids
    chosen = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [v for v in chosen if v not in ids]
    if unknown or len(set(chosen)) != len(chosen):
        raise UsageError(f"--images {text}: give distinct image ids of the block ({', '.join(ids)})")
    return tuple(ids.index(v) for v in chosen), chosen


def _line_aps(args, images) -> dict | None:
    """--ap wavelet1d:NAME --grid N: the line APs of every camera of the images adjusted."""
    if args.ap in ("none", ""):
        return None
    if not args.ap.startswith("wavelet1d:"):
        raise UsageError(f"--ap {args.ap}: a pushbroom block takes none or wavelet1d:NAME (NAME = dbN, symN, meyer, "
                         "blN), the 1-D wavelet APs along the detector line")
    cameras = {img.camera.camera_id: img.camera for img in images}
    if args.ap_cameras:
        chosen = [c.strip() for c in args.ap_cameras.split(",") if c.strip()]
        unknown = [c for c in chosen if c not in cameras]
        if unknown:
            raise UsageError(f"--ap-cameras: {', '.join(unknown)} not among the cameras adjusted "
                             f"({', '.join(cameras)})")
    elif len(cameras) > 1:
        raise UsageError("--ap wavelet1d with several cameras: name the cameras whose detector lines are calibrated "
                         "with --ap-cameras. Tie points cannot tell an error common to all the lines (one orbit "
                         "plane) from the ground: the other lines are the reference (their payload calibration), "
                         "unless many GCPs control the block")
    else:
        chosen = list(cameras)
    if args.ap_sigma_px is not None and args.ap_sigma_px <= 0:
        raise UsageError("--ap-sigma-px must be positive")
    try:
        return {c: create_line_ap(args.ap, cameras[c].columns, cameras[c].center_col, cameras[c].chip_starts,
                                  args.grid[0]) for c in chosen}
    except ValueError as exc:
        raise UsageError(f"--ap {args.ap}: {exc}") from None


def run_adjust(block, args) -> int:
    t0 = time.perf_counter()
    if getattr(args, "trajectory_significance", None) is not None:
        raise UsageError("--trajectory-significance screens GNSS/IMU shift/drift terms of frame blocks; a pushbroom "
                         "block has none")
    data = pushbroom_block(block, given_attitude=not args.no_attitude)
    image_set, labels = _image_set(data, args.images)
    dem = _terrain(block, args)
    if len(image_set) == 1 and dem is None:
        raise UsageError("a mono adjustment restitutes the check points on the terrain: give --dem or "
                         "[terrain] in block.toml")
    prior = ATTITUDE_FREE_SIGMA if args.no_attitude and args.sensor_model.upper() == "M6" else None
    model = sensor_model(args.sensor_model, prior)
    images, extra = data.images, {}
    if not args.keep_focal and "focal" not in model.free:
        focal, sigma = calibrate_focal(data, dem)
        images = with_focal(data.images, focal)
        extra["calibrated_focal_mm"] = {k: {"value": v, "sigma": sigma[k]} for k, v in focal.items()}
        print("focal lengths (M7 on all images): " + ", ".join(f"{k} {v:.3f} ± {sigma[k]:.3f} mm"
                                                                 for k, v in focal.items()), file=sys.stderr)
    gcps = choose_gcps(data, args.gcps)
    if not args.quiet:
        print(f"{block.name}: pushbroom images {', '.join(labels)}, {len(gcps)} GCP, sensor model {model.name} "
              f"({', '.join(model.free)})", file=sys.stderr)
    snooping = SnoopingOptions(critical=args.snoop)
    screening = screening_options(args) if args.screen else None
    line_aps = _line_aps(args, [data.images[i] for i in image_set])
    case = run_case(data, model, gcps, image_set, dem, "+".join(labels), images, snooping, screening,
                    line_aps=line_aps, line_ap_sigma_px=args.ap_sigma_px)
    if case.screening is not None:
        for d in case.screening.dropped:
            print(f"screening: dropped {d.camera_id}.{d.name} (t {d.t:.2f}, {d.reason})", file=sys.stderr)
    for k, w in case.rejected or []:
        print(f"rejected image point {data.point_ids[data.obs_point[k]]} in {data.images[data.obs_image[k]].image_id} "
              f"(|w| {w:.1f})", file=sys.stderr)
    extra["seconds"] = time.perf_counter() - t0
    extra["trajectory_fit_rms"] = {img.image_id: {k: v.tolist() for k, v in img.trajectory.fit_rms.items()}
                                   for img in data.images}
    files = pushbroom_files(data, case, args.sensor_model, labels, extra)
    if not args.no_report:
        files |= render_pushbroom_report(results_from_files(files))
    write_results(args.out, files)
    if case.rmse_m is None:
        print(f"selfcal adjust: error: the pushbroom adjustment failed: {case.failure}", file=sys.stderr)
        return 1
    x, y, z = case.rmse_m
    print(f"sigma0 {case.result.sigma0 * data.image_sigma_px:.3f} px, check points RMSE across {x:.2f} m, along "
          f"{y:.2f} m, up {z:.2f} m ({case.n_check} CHK, {len(gcps)} GCP); results in {args.out}", file=sys.stderr)
    return 0


def run_compare(block, args) -> int:
    t0 = time.perf_counter()
    data = pushbroom_block(block, given_attitude=not args.no_attitude)
    dem = _terrain(block, args)
    if dem is None:
        raise UsageError("the mono cases restitute the check points on the terrain: give --dem or [terrain] "
                         "in block.toml")
    models = [m.strip().upper() for m in args.sensor_models.split(",") if m.strip()]
    unknown = [m for m in models if m not in SENSOR_MODELS]
    if unknown:
        raise UsageError(f"unknown sensor model(s) {', '.join(unknown)} (known: {', '.join(SENSOR_MODELS)})")
    try:
        counts = sorted({int(v) for v in args.gcps.split(",") if v.strip()})
    except ValueError:
        raise UsageError(f"--gcps must be numbers separated by commas, found '{args.gcps}'") from None
    prior = ATTITUDE_FREE_SIGMA if args.no_attitude else None

    def show(case):
        status = case.failure.splitlines()[0] if case.rmse_m is None else \
            "RMSE " + " / ".join(f"{v:.2f}" for v in case.rmse_m) + " m"
        print(f"{case.images} {case.model} {case.n_gcp} GCP: {status}", file=sys.stderr, flush=True)

    # no data snooping here: the rows of M1-M4 are there to show the model error that snooping would reject
    cases, focal, sigma = run_study(data, dem, models, counts, prior_sigma=prior, progress=show)
    table = study_markdown(cases, focal, sigma)
    with atomic_folder(args.out) as tmp:
        write_files(tmp, {"comparison.md": table, "comparison.csv": study_csv(cases)})
    print(table)
    print(f"{len(cases)} adjustments in {time.perf_counter() - t0:.1f} s; results in {args.out}", file=sys.stderr)
    return 0
