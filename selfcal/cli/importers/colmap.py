"""``selfcal import colmap``: a COLMAP sparse model, ground control from OpenDroneMap's gcp_list.txt."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert import DEFAULT_GCP_LIST_SIGMA_M, block_from_colmap
from ...io.block_folder import write_block
from ...io.colmap import read_colmap
from ...io.odm import read_gcp_list
from ...io.output import output_folder
from ..options import number
from ..outcome import finish, progress
from . import rolling


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gcp", metavar="FILE", help="OpenDroneMap gcp_list.txt with the ground control")
    parser.add_argument("--check", default="", metavar="NAMES",
                        help="comma-separated control points to use as check points")
    parser.add_argument("--pixel-size-mm", type=number(0.0, low_open=True), default=None,
                        help="physical pixel size of the camera (default 0.005 mm, with a warning)")
    parser.add_argument("--image-sigma-px", type=number(0.0, low_open=True), default=1.0,
                        help="a-priori sigma of an image measurement (default 1.0 px)")
    parser.add_argument("--gcp-sigma-xy", type=number(0.0, low_open=True), default=None,
                        help="a-priori sigma of the control coordinates in plan (default 3 m, as a hand-held GPS, "
                             "with a warning: gcp_list.txt carries no accuracy; surveyed targets: e.g. 0.01)")
    parser.add_argument("--gcp-sigma-z", type=number(0.0, low_open=True), default=None,
                        help="a-priori sigma of the control heights (default 5 m, with a warning; surveyed: e.g. 0.02)")
    rolling.add_arguments(parser, images=True)


def run(args: argparse.Namespace) -> int:
    rolling.check(args, "COLMAP")
    args.out = output_folder(args.out, (args.source, args.gcp, args.images), args.force)
    progress(f"reading {args.source} ...")
    model = read_colmap(args.source)
    control = read_gcp_list(args.gcp) if args.gcp else None
    checks = [c.strip() for c in args.check.split(",") if c.strip()]
    sigma = None
    if args.gcp_sigma_xy is not None or args.gcp_sigma_z is not None:   # one given: the other's default, said
        xy, z = DEFAULT_GCP_LIST_SIGMA_M
        if args.gcp_sigma_xy is None or args.gcp_sigma_z is None:
            print(f"warning: --gcp-sigma-{'xy' if args.gcp_sigma_xy is None else 'z'} not given: "
                  f"{xy if args.gcp_sigma_xy is None else z:g} m assumed", file=sys.stderr)
        sigma = (args.gcp_sigma_xy if args.gcp_sigma_xy is not None else xy,
                 args.gcp_sigma_z if args.gcp_sigma_z is not None else z)
    block, notes = block_from_colmap(model, control, args.pixel_size_mm, args.image_sigma_px, sigma, checks,
                                     name=os.path.basename(os.path.normpath(args.out)))
    for note in notes:
        print(note, file=sys.stderr)
    block = rolling.rolling_block(args, block)
    progress(f"writing {args.out} ({len(block.observations)} observations) ...")
    write_block(block, args.out, source=args.source, say=progress)
    line = (f"imported {len(block.images)} images, {len(block.points)} points, {len(block.observations)} "
            f"observations into {args.out}")
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
