"""Export a results folder to other programs: camera models (OpenCV, COLMAP, Metashape, OpenSfM, Kalibr), maps, RPCs."""
from __future__ import annotations

import argparse
from typing import Callable

from .exporters import EXPORTERS, module


#: the formats of this verb (the command line imports only the one it names)
FORMATS = EXPORTERS


def add_arguments(parser: argparse.ArgumentParser, chosen: str | None = None,
                  common: Callable[[argparse.ArgumentParser], None] | None = None) -> None:
    """The formats' sub-commands; the arguments of the format ``chosen`` only (the one the command line names),
    and ``common``'s (the options every verb has) after them."""
    formats = parser.add_subparsers(dest="format", required=True, metavar="FORMAT",
                                    help=", ".join(EXPORTERS))
    for name, (_, text) in EXPORTERS.items():
        sub = formats.add_parser(name, help=text, description=text)
        if name != chosen:
            continue
        sub.add_argument("results", metavar="RESULTS", help="results folder written by selfcal adjust")
        module(name).add_arguments(sub)
        if common is not None:
            common(sub)


def run(args: argparse.Namespace) -> int:
    return module(args.format).run(args)
