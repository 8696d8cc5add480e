"""``selfcal export metashape``: one camera as a Metashape calibration XML, with its covariance."""
from __future__ import annotations

import argparse
import os

from ...io.calibration_files import write_metashape_xml
from ...io.output import output_file
from ..calibrations import tool_calibration, tool_options
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="XML file to write (replaced; never inside RESULTS; missing folders are created)")
    tool_options(parser, "metashape")


def run(args: argparse.Namespace) -> int:
    args.out = output_file(args.out, (args.results,))
    write_metashape_xml(args.out, tool_calibration(args, "metashape", with_covariance=True))
    line = f"wrote {args.out}"
    return finish(args, line, None, [os.path.abspath(args.out)])
