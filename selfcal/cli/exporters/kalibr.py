"""``selfcal export kalibr``: one camera as a Kalibr camchain.yaml (cam0)."""
from __future__ import annotations

import argparse
import os

from ...io.calibration_files import write_kalibr_camchain
from ...io.output import output_file
from ..calibrations import tool_calibration, tool_options
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="camchain.yaml to write (replaced; never inside RESULTS; missing folders are created)")
    tool_options(parser, "kalibr")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    write_kalibr_camchain(args.out, tool_calibration(args, "kalibr"))
    line = f"wrote {args.out}"
    return finish(args, line, None, [os.path.abspath(args.out)])
