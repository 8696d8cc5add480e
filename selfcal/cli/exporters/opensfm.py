"""``selfcal export opensfm``: one camera as an OpenSfM / OpenDroneMap cameras.json."""
from __future__ import annotations

import argparse
import os

from ...io.calibration_files import write_opensfm_cameras
from ...io.output import output_file
from ..calibrations import tool_calibration, tool_options
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="cameras.json to write (replaced; never inside RESULTS; missing folders are created)")
    parser.add_argument("--key", metavar="KEY",
                        help="the camera's key in cameras.json (default: 'v2 selfcal ID W H MODEL FOCAL'); give "
                             "the key of the camera in your OpenSfM project to replace its calibration")
    tool_options(parser, "opensfm")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    write_opensfm_cameras(args.out, tool_calibration(args, "opensfm"), args.key)
    line = f"wrote {args.out}"
    return finish(args, line, None, [os.path.abspath(args.out)])
