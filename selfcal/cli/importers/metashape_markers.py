"""``selfcal import metashape-markers``: Metashape markers (XML) and their reference CSV, added to a block."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert.uav import block_with_markers
from ...errors import UsageError
from ...io import read_block
from ...io.block_folder import write_block
from ...io.metashape import read_markers_xml, read_reference_csv
from ...io.output import output_folder
from ..options import number
from .patb import checks, control_arguments
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--block", metavar="BLOCK", help="the block whose images the markers are measured in "
                                                         "(read, never modified)")
    parser.add_argument("--reference", metavar="CSV",
                        help="marker coordinates: label, X, Y, Z[, accuracies] (Metashape's reference CSV)")
    parser.add_argument("--marker-sigma-px", type=number(0.0, low_open=True), metavar="PX",
                        help="a-priori sigma of a marker projection (default: the block's image sigma)")
    control_arguments(parser, crs=False)


def run(args: argparse.Namespace) -> int:
    if not args.block:
        raise UsageError("selfcal import metashape-markers needs --block BLOCK (the images the markers are "
                         "measured in)")
    args.out = output_folder(args.out, (args.source, args.block, args.reference), args.force)
    block = read_block(args.block, min_gcp=0)
    markers = read_markers_xml(args.source)
    reference = read_reference_csv(args.reference) if args.reference else None
    new, notes = block_with_markers(block, markers, reference, marker_sigma_px=args.marker_sigma_px,
                                    control_sigma_m=(args.gcp_sigma_xy, args.gcp_sigma_z), check_points=checks(args))
    for note in notes:
        print(note, file=sys.stderr)
    write_block(new, args.out, source=args.source, say=progress)
    line = (f"wrote {args.out}: {len(new.images)} images, {len(new.points)} points, {len(new.observations)} "
            f"observations")
    return finish(args, line, {"n_images": len(new.images), "n_points": len(new.points),
                               "n_observations": len(new.observations)}, [os.path.abspath(args.out)])
