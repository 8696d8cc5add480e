"""``selfcal export opensfm``: one camera as an OpenSfM / OpenDroneMap cameras.json."""
from __future__ import annotations

import argparse
import sys

from ...io.calibration_files import ToolCalibration, write_opensfm_cameras
from ...io.output import output_file
from ..calibrations import calibrations, fit_tool, pick_camera, tool_options

HELP = "OpenSfM / OpenDroneMap cameras.json of one camera (perspective, brown or fisheye)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="cameras.json to write (replaced; never inside RESULTS; missing folders are created)")
    parser.add_argument("--key", metavar="KEY",
                        help="the camera's key in cameras.json (default: 'v2 selfcal ID W H MODEL FOCAL'); give "
                             "the key of the camera in your OpenSfM project to replace its calibration")
    tool_options(parser, "opensfm")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cal = pick_camera(calibrations(args.results), args.camera)
    fitted = fit_tool(cal, "opensfm", args.tool_model, args.tolerance_px,
                      args.tool_model_option)
    write_opensfm_cameras(args.out, ToolCalibration("opensfm", fitted.model.name, fitted.as_dict(), cal.width_px,
                                                    cal.height_px, camera_id=cal.camera_id), args.key)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0
