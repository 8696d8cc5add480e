"""``selfcal export colmap-workspace``: a COLMAP dense workspace from a results folder and the block's images
(:mod:`selfcal.workflows.export_workspace` says what it holds)."""
from __future__ import annotations

import argparse
import os

from ...io.output import output_folder
from ...io.colmap_workspace import ORIGIN_FILE
from ...workflows.export_workspace import export_workspace
from ..calibrations import calibrations, maps_of
from ..options import force_option
from ..outcome import finish, say


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--images", required=True, metavar="DIR",
                        help="folder with the block's images; an image is found by its image id as the file name, "
                             "or as the file name without its extension")
    parser.add_argument("--out", required=True, metavar="WS",
                        help="workspace folder to write (replaced if selfcal wrote it; never inside RESULTS or DIR)")
    force_option(parser)


def run(args: argparse.Namespace) -> int:
    args.out = output_folder(args.out, (args.results, args.images), args.force)
    done = export_workspace(args.results, calibrations(args.results), args.images, args.out,
                            say=say, maps=maps_of)
    line = (f"wrote {args.out}: {done['images']} images, {done['points']} points, {done['observations']} "
            f"observations (mean error per point {done['mean_error_px']:.3f} px rms); model coordinates = object "
            f"coordinates - ({', '.join(f'{v:.0f}' for v in done['origin_m'])}) m (sparse/{ORIGIN_FILE})")
    return finish(args, line, {k: done[k] for k in ("images", "points", "observations", "mean_error_px")},
                  [os.path.abspath(args.out)])
