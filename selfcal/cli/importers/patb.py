"""``selfcal import patb``: PAT-B image coordinates (.im), control (.con) and orientations (.ori), as Metashape
exports them."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert.uav import block_from_patb
from ...errors import UsageError
from ...io.block_folder import write_block
from ...io.output import output_folder
from ...io.patb import find_patb, read_con, read_ori, read_photo_blocks
from ..options import number
from ..outcome import finish, progress


def image_size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        w, h = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels (e.g. 6000x4000), found '{text}'") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"the image size must be positive, found '{text}'")
    return w, h


def pair(text: str) -> tuple[float, float]:
    parse = number()
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected X,Y, found '{text}'")
    return parse(parts[0]), parse(parts[1])


def control_arguments(parser: argparse.ArgumentParser, crs: bool = True) -> None:
    """Options of the control of an import (shared by patb, pix4d and metashape-markers)."""
    parser.add_argument("--check", default="", metavar="NAMES",
                        help="comma-separated control points to use as check points")
    parser.add_argument("--gcp-sigma-xy", type=number(0.0, low_open=True), default=0.01, metavar="M",
                        help="a-priori sigma of the control coordinates in plan where the file gives none "
                             "(default 0.01 m)")
    parser.add_argument("--gcp-sigma-z", type=number(0.0, low_open=True), default=0.02, metavar="M",
                        help="a-priori sigma of the control heights where the file gives none (default 0.02 m)")
    if crs:
        parser.add_argument("--crs", default="local", help="CRS of the coordinates (e.g. EPSG:32632; default local)")


def checks(args) -> list[str]:
    return [c.strip() for c in args.check.split(",") if c.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--image-size", type=image_size, required=True, metavar="WxH",
                        help="image size in pixels (PAT-B does not carry it), e.g. 6000x4000")
    parser.add_argument("--pixel-size-mm", type=number(0.0, low_open=True), required=True,
                        help="physical pixel size (mm) of the camera")
    parser.add_argument("--focal-mm", type=number(0.0, low_open=True),
                        help="principal distance (default: the camera constant of the .im headers)")
    parser.add_argument("--principal-point-mm", type=pair, default=(0.0, 0.0), metavar="X0,Y0",
                        help="principal point from the image centre, mm, x right, y up (default 0,0)")
    parser.add_argument("--image-units", choices=("mm", "um"), default="mm",
                        help="unit of the .im coordinates, as the export's .pro states it (default mm)")
    parser.add_argument("--image-sigma-px", type=number(0.0, low_open=True), default=1.0,
                        help="a-priori sigma of an image measurement (default 1.0 px)")
    control_arguments(parser)


def run(args: argparse.Namespace) -> int:
    files = find_patb(args.source)
    args.out = output_folder(args.out, (args.source, *[f for f in files.values() if f]), args.force)
    if not args.crs.strip():
        raise UsageError("--crs is empty")
    measurements = read_photo_blocks(files["im"])
    control = read_con(files["con"]) if files["con"] else None
    orientations = read_ori(files["ori"]) if files["ori"] else None
    w, h = args.image_size
    block, notes = block_from_patb(measurements, control, orientations, width_px=w, height_px=h,
                                   pixel_size_mm=args.pixel_size_mm, focal_mm=args.focal_mm,
                                   principal_point_mm=args.principal_point_mm,
                                   image_unit_mm=0.001 if args.image_units == "um" else 1.0,
                                   image_sigma_px=args.image_sigma_px,
                                   control_sigma_m=(args.gcp_sigma_xy, args.gcp_sigma_z), check_points=checks(args),
                                   crs=args.crs, name=os.path.basename(os.path.normpath(args.out)))
    for note in notes:
        print(note, file=sys.stderr)
    write_block(block, args.out, source=files["im"], say=progress)
    roles = {r: int((block.points.role == r).sum()) for r in ("gcp", "chk", "tie")}
    line = (f"imported {len(block.images)} photos, {len(block.points)} points ({roles['gcp']} gcp, {roles['chk']} "
            f"chk, {roles['tie']} tie), {len(block.observations)} observations into {args.out}")
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
