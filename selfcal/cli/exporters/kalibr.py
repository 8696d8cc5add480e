"""``selfcal export kalibr``: one camera as a Kalibr camchain.yaml (cam0)."""
from __future__ import annotations

import argparse
import sys

from ...io.calibration_files import ToolCalibration, write_kalibr_camchain
from ...io.output import output_file
from ..calibrations import calibrations, fit_tool, pick_camera, tool_options

HELP = "Kalibr camchain.yaml of one camera (pinhole, radtan or equidistant)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="camchain.yaml to write (replaced; never inside RESULTS; missing folders are created)")
    tool_options(parser, "kalibr")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    cal = pick_camera(calibrations(args.results), args.camera)
    fitted = fit_tool(cal, "kalibr", args.tool_model, args.tolerance_px,
                      args.tool_model_option)
    write_kalibr_camchain(args.out, ToolCalibration("kalibr", fitted.model.name, fitted.as_dict(), cal.width_px,
                                                    cal.height_px, camera_id=cal.camera_id))
    print(f"wrote {args.out}", file=sys.stderr)
    return 0
