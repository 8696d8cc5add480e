"""Import another program's model, control, camera GNSS or calibration as a block folder.

COLMAP, BAL, ISIS, PAT-B, OpenSfM, Pix4D; Metashape markers, camera GNSS (EXIF, DJI XMP, ODM geo.txt) and a
camera calibration added to an existing block (--block)."""
from __future__ import annotations

import argparse

from .importers import IMPORTERS
from .options import force_option


def add_arguments(parser: argparse.ArgumentParser) -> None:
    formats = parser.add_subparsers(dest="format", required=True, metavar="FORMAT",
                                    help=", ".join(IMPORTERS))
    for name, module in IMPORTERS.items():
        sub = formats.add_parser(name, help=module.HELP, description=module.HELP)
        sub.add_argument("source", metavar="SRC", help="the model to import")
        sub.add_argument("--out", required=True, metavar="BLOCK",
                         help="block folder to write (replaced if selfcal wrote it; never the source)")
        force_option(sub)
        module.add_arguments(sub)


def run(args: argparse.Namespace) -> int:
    return IMPORTERS[args.format].run(args)
