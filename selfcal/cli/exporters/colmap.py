"""``selfcal export colmap``: the cameras as COLMAP's cameras.txt (OPENCV or FULL_OPENCV)."""
from __future__ import annotations

import argparse
import os

from ...calibration import COLMAP_MODELS, colmap_parameters, fit_opencv
from ...io.colmap import write_cameras_txt
from ...io.output import output_file
from ..calibrations import calibrations, camera_options, models, pick_camera, report_fit, warn_extrapolated
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="file to write (replaced; never inside RESULTS; missing folders are created)")
    camera_options(parser)


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cameras = calibrations(args.results)
    chosen = cameras if args.camera is None else {args.camera: pick_camera(cameras, args.camera)}
    rows, warnings = [], []
    for number, (camera_id, cal) in enumerate(chosen.items(), start=1):
        warnings += [w for w in [warn_extrapolated(cal)] if w]
        fitted = fit_opencv(cal, models(args.opencv_model, COLMAP_MODELS), args.tolerance_px)
        report_fit(camera_id, fitted, args.tolerance_px)
        model, params = colmap_parameters(fitted)
        rows.append((number, model, cal.width_px, cal.height_px, params))
        progress(f"camera {camera_id} is COLMAP camera {number} ({model})")
    write_cameras_txt(args.out, rows, warnings)
    line = f"wrote {args.out}"
    return finish(args, line, {"n_cameras": len(rows)}, [os.path.abspath(args.out)])
