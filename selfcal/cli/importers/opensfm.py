"""``selfcal import opensfm``: an OpenSfM/OpenDroneMap reconstruction.json with its tracks.csv."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert.uav import block_from_opensfm
from ...errors import BlockError
from ...io.block_folder import write_block
from ...io.opensfm import read_reconstruction, read_tracks
from ...io.output import output_folder
from ..options import number
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tracks", metavar="FILE",
                        help="OpenSfM tracks.csv (default: tracks.csv beside reconstruction.json)")
    parser.add_argument("--pixel-size-mm", type=number(0.0, low_open=True), default=None,
                        help="physical pixel size of the camera (default 0.005 mm, with a warning; OpenSfM works in "
                             "pixels only)")
    parser.add_argument("--image-sigma-px", type=number(0.0, low_open=True), default=1.0,
                        help="a-priori sigma of an image measurement (default 1.0 px)")


def run(args: argparse.Namespace) -> int:
    source = args.source
    if os.path.isdir(source):
        source = os.path.join(source, "reconstruction.json")
    tracks = args.tracks or os.path.join(os.path.dirname(os.path.abspath(source)), "tracks.csv")
    args.out = output_folder(args.out, (args.source, tracks), args.force)
    if not os.path.isfile(tracks):
        raise BlockError(tracks, "file not found: the image measurements of OpenSfM are in tracks.csv (--tracks)")
    block, notes = block_from_opensfm(read_reconstruction(source), read_tracks(tracks), args.pixel_size_mm,
                                      args.image_sigma_px, name=os.path.basename(os.path.normpath(args.out)))
    for note in notes:
        print(note, file=sys.stderr)
    write_block(block, args.out, source=source, say=progress)
    line = (f"imported {len(block.images)} shots, {len(block.points)} points, {len(block.observations)} "
            f"observations into {args.out}")
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
