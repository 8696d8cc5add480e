"""Import another program's model, control, camera GNSS or calibration as a block folder.

COLMAP, BAL, ISIS, PAT-B, OpenSfM, Pix4D; Metashape markers, camera GNSS (EXIF, DJI XMP, ODM geo.txt) and a
camera calibration added to an existing block (--block)."""
from __future__ import annotations

import argparse
from typing import Callable

from .importers import IMPORTERS, module
from .options import force_option


#: the formats of this verb (the command line imports only the one it names)
FORMATS = IMPORTERS


def add_arguments(parser: argparse.ArgumentParser, chosen: str | None = None,
                  common: Callable[[argparse.ArgumentParser], None] | None = None) -> None:
    """The formats' sub-commands; the arguments of the format ``chosen`` only (the one the command line names),
    and ``common``'s (the options every verb has) after them."""
    formats = parser.add_subparsers(dest="format", required=True, metavar="FORMAT",
                                    help=", ".join(IMPORTERS))
    for name, (_, text) in IMPORTERS.items():
        sub = formats.add_parser(name, help=text, description=text)
        if name != chosen:
            continue
        sub.add_argument("source", metavar="SRC", help="the model to import")
        sub.add_argument("--out", required=True, metavar="BLOCK",
                         help="block folder to write (replaced if selfcal wrote it; never the source)")
        force_option(sub)
        module(name).add_arguments(sub)
        if common is not None:
            common(sub)


def run(args: argparse.Namespace) -> int:
    return module(args.format).run(args)
