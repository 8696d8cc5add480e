"""Export a results folder to other programs: camera models (OpenCV, COLMAP, Metashape, OpenSfM, Kalibr), maps, RPCs."""
from __future__ import annotations

import argparse

from .exporters import EXPORTERS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    formats = parser.add_subparsers(dest="format", required=True, metavar="FORMAT",
                                    help=", ".join(EXPORTERS))
    for name, module in EXPORTERS.items():
        sub = formats.add_parser(name, help=module.HELP, description=module.HELP)
        sub.add_argument("results", metavar="RESULTS", help="results folder written by selfcal adjust")
        module.add_arguments(sub)


def run(args: argparse.Namespace) -> int:
    return EXPORTERS[args.format].run(args)
