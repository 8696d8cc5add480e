"""``selfcal import colmap``: a COLMAP sparse model, ground control from OpenDroneMap's gcp_list.txt."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert import block_from_colmap
from ...io.block_folder import write_block
from ...io.colmap import read_colmap
from ...io.odm import read_gcp_list
from ...io.output import output_folder
from ..options import number
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gcp", metavar="FILE", help="OpenDroneMap gcp_list.txt with the ground control")
    parser.add_argument("--check", default="", metavar="NAMES",
                        help="comma-separated control points to use as check points")
    parser.add_argument("--pixel-size-mm", type=number(0.0, low_open=True), default=0.005,
                        help="physical pixel size of the camera (default 0.005 mm)")
    parser.add_argument("--image-sigma-px", type=number(0.0, low_open=True), default=1.0,
                        help="a-priori sigma of an image measurement (default 1.0 px)")
    parser.add_argument("--gcp-sigma-xy", type=number(0.0, low_open=True), default=3.0,
                        help="a-priori sigma of the control coordinates in plan (default 3 m: hand-held GPS)")
    parser.add_argument("--gcp-sigma-z", type=number(0.0, low_open=True), default=5.0,
                        help="a-priori sigma of the control heights (default 5 m)")


def run(args: argparse.Namespace) -> int:
    args.out = output_folder(args.out, (args.source, args.gcp), args.force)
    model = read_colmap(args.source)
    control = read_gcp_list(args.gcp) if args.gcp else None
    checks = [c.strip() for c in args.check.split(",") if c.strip()]
    block, notes = block_from_colmap(model, control, args.pixel_size_mm, args.image_sigma_px,
                                     (args.gcp_sigma_xy, args.gcp_sigma_z), checks,
                                     name=os.path.basename(os.path.normpath(args.out)))
    for note in notes:
        print(note, file=sys.stderr)
    write_block(block, args.out, source=args.source)
    line = (f"imported {len(block.images)} images, {len(block.points)} points, {len(block.observations)} "
            f"observations into {args.out}")
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
