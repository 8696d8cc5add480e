"""``selfcal export opencv``: one camera as an OpenCV cv::FileStorage YAML."""
from __future__ import annotations

import argparse
import sys

from ...calibration import OPENCV_MODELS, fit_opencv
from ...io.opencv import write_opencv_yaml
from ...io.output import output_file
from ..calibrations import calibrations, camera_options, models, pick_camera, report_fit

HELP = "cv::FileStorage YAML of one camera (camera matrix, distortion coefficients)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="file to write (replaced; never inside RESULTS; missing folders are created)")
    camera_options(parser)


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cal = pick_camera(calibrations(args.results), args.camera)
    fitted = fit_opencv(cal, models(args.opencv_model, OPENCV_MODELS), args.tolerance_px)
    report_fit(cal.camera_id, fitted, args.tolerance_px)
    write_opencv_yaml(fitted, args.out, source=f"selfcal {cal.ap.spec} calibration of camera {cal.camera_id}")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0
