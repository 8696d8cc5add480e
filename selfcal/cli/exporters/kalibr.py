"""``selfcal export kalibr``: one camera as a Kalibr camchain.yaml (cam0), with the keys Kalibr's camchain
reader requires, its model (radtan or equidistant) chosen from the lens unless ``--model`` names one."""
from __future__ import annotations

import argparse
import os

from ...errors import UsageError
from ...io.calibration_files import KALIBR_ROSTOPIC, write_kalibr_camchain
from ...io.output import output_file
from ..calibrations import tool_calibration, tool_options
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="camchain.yaml to write (replaced; never inside RESULTS; missing folders are created)")
    parser.add_argument("--rostopic", default=KALIBR_ROSTOPIC, metavar="TOPIC",
                        help=f"the camera's image topic in the bag Kalibr reads (default {KALIBR_ROSTOPIC})")
    tool_options(parser, "kalibr")


def run(args: argparse.Namespace) -> int:
    if not args.rostopic or any(c.isspace() for c in args.rostopic):
        raise UsageError(f"--rostopic {args.rostopic!r}: a ROS topic name, not empty and without spaces "
                         f"(e.g. {KALIBR_ROSTOPIC})")
    args.out = output_file(args.out, (args.results,))
    write_kalibr_camchain(args.out, tool_calibration(args, "kalibr"), args.rostopic)
    line = f"wrote {args.out}"
    return finish(args, line, None, [os.path.abspath(args.out)])
