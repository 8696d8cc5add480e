"""``selfcal import gnss``: camera positions from the images' EXIF GPS / DJI XMP tags or an ODM geo.txt, added to a
block as its GNSS observations (each image's own sigma where the images give one)."""
from __future__ import annotations

import argparse
import os
import sys

from ...errors import BlockError, UsageError
from ..options import number
from ..outcome import finish, progress
from . import rolling


def _three(text: str) -> tuple[float, float, float]:
    parse = number(0.0, low_open=True)
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"give three positive sigmas separated by commas, found '{text}'")
    x, y, z = (parse(p) for p in parts)
    return x, y, z


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--block", required=True, metavar="BLOCK",
                        help="the block the images belong to (read, never changed); its crs must be projected")
    parser.add_argument("--heights", choices=("ellipsoidal", "orthometric"), default="ellipsoidal",
                        help="what the heights in SRC are: ellipsoidal (WGS 84, as GNSS and DJI's RTK aircraft "
                             "write them; converted into the block's CRS, through its geoid where it has a vertical "
                             "datum) or orthometric (kept as given, only the plan position is converted)")
    parser.add_argument("--sigma-m", type=_three, metavar="SX,SY,SZ",
                        help="a-priori sigma of a GNSS position without its own (default: the block's [gnss] "
                             "sigma_m, else 3,3,5 m)")
    parser.add_argument("--imu-sigma-deg", type=_three, metavar="SO,SP,SK",
                        help="also import the camera attitudes (DJI XMP GimbalYaw/Pitch/RollDegree) as [imu] "
                             "observations with these sigmas of omega, phi, kappa (degrees)")
    parser.add_argument("--strip-turn-deg", type=number(0.0, 180.0, low_open=True), default=30.0, metavar="DEG",
                        help="a change of the direction of flight by more than this starts a strip (default 30)")
    parser.add_argument("--strip-gap", type=number(1.0, low_open=True), default=3.0, metavar="K",
                        help="a pause of more than K median intervals between exposures starts a strip (default 3)")
    rolling.add_arguments(parser, images=False)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ...convert.gnss import block_with_gnss, exif_cameras, positions_from_geo, positions_from_images
    from ...convert.rolling import with_rolling_shutter
    from ...io import read_block
    from ...io.block_folder import write_block
    from ...io.exif import image_files, read_image_gnss
    from ...io.odm import read_geo_txt
    from ...io.output import output_folder

    rolling.check(args)
    args.out = output_folder(args.out, (args.source, args.block), args.force)
    block = read_block(args.block)
    warnings = []
    records = []
    if os.path.isdir(args.source):
        files = image_files(args.source)
        if not files:
            raise BlockError(args.source, "no JPEG (.jpg, .jpeg) in the folder")
        records = [read_image_gnss(f) for f in files]
        positions, notes = positions_from_images(records)
        warnings += notes
        if not len(positions.names):
            raise BlockError(args.source, f"none of the {len(files)} JPEGs has a GPS position in its EXIF or XMP tags")
    elif os.path.isfile(args.source):
        positions = positions_from_geo(read_geo_txt(args.source), args.source)
    else:
        raise UsageError(f"{args.source} is neither a folder of JPEGs nor a geo.txt file")
    try:
        result = block_with_gnss(block, positions, args.sigma_m, args.heights, args.strip_turn_deg, args.strip_gap,
                                 args.imu_sigma_deg, points_path=os.path.join(args.block, "points.csv"),
                                 positions_path=args.source)
    except BlockError:
        raise
    except ValueError as exc:
        raise BlockError(args.source, str(exc)) from None
    if args.rolling_shutter:
        block, notes = with_rolling_shutter(result.block, exif_cameras(result.block, records), args.readout_ms)
        result = replace(result, block=block)
        for note in notes:
            progress(note)
    write_block(result.block, args.out, source=args.source, say=progress)
    warnings += result.warnings
    for note in warnings:
        print(f"warning: {note}", file=sys.stderr)
    import numpy as np
    images = result.block.images
    untimed = int((np.isfinite(images.position_m).all(axis=1) & np.isnan(images.time_s)).sum())
    if untimed:
        progress(f"{untimed} of the positions have no exposure time: adjust with --gnss-drift 0 (a shift per strip) "
                 f"or --gnss-drift none; the default drift per strip needs the times")
    line = (f"imported the GNSS positions of {result.n_with_gnss} of {len(result.block.images)} images "
            f"({result.n_own_sigma} with their own sigma) in {result.n_strips} strips"
            + (f", the attitudes of {result.n_with_attitude}" if args.imu_sigma_deg else "") + f" into {args.out} "
            f"({len(warnings)} warning{'s' if len(warnings) != 1 else ''})")
    return finish(args, line, {"n_images": len(result.block.images), "n_with_gnss": result.n_with_gnss,
                               "n_strips": result.n_strips, "n_warnings": len(warnings)}, [os.path.abspath(args.out)])
