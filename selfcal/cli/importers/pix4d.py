"""``selfcal import pix4d``: Pix4D's params folder (BINGO tie points, calibrated internal and external parameters)."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert.uav import block_from_pix4d
from ...errors import UsageError
from ...io.block_folder import write_block
from ...io.output import output_folder
from ...io.pix4d import params_folder, read_gcps_position, read_pix4d_params
from ..options import number
from .patb import checks, control_arguments, image_size
from ..outcome import finish, progress
from . import rolling


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gcp", metavar="FILE",
                        help="ground control: label, X, Y, Z[, accuracy XY, accuracy Z] (Pix4D's GCP import file), "
                             "or a *_measured_gcps_position.txt; default: the params folder's "
                             "*_measured_gcps_position.txt, where it has one")
    parser.add_argument("--image-size", type=image_size, metavar="WxH",
                        help="image size in pixels (default: from *_calibrated_camera_parameters.txt)")
    parser.add_argument("--image-sigma-px", type=number(0.0, low_open=True), default=1.0,
                        help="a-priori sigma of an image measurement (default 1.0 px)")
    control_arguments(parser)
    rolling.add_arguments(parser, images=True)


def run(args: argparse.Namespace) -> int:
    rolling.check(args, "Pix4D's params folder")
    args.out = output_folder(args.out, (args.source, args.gcp, args.images), args.force)
    if not args.crs.strip():
        raise UsageError("--crs is empty")
    params = read_pix4d_params(args.source, args.image_size)
    gcp_path = args.gcp or params.gcps_path
    control = read_gcps_position(gcp_path) if gcp_path else None
    if args.gcp and params.gcps_path:
        progress(f"control from {args.gcp} (--gcp), not from {params.gcps_path}")
    elif control is not None and not args.gcp:
        progress(f"control: {len(control.point_id)} point(s) of {control.path}")
    block, notes = block_from_pix4d(params, control, image_sigma_px=args.image_sigma_px,
                                    control_sigma_m=(args.gcp_sigma_xy, args.gcp_sigma_z), check_points=checks(args),
                                    crs=args.crs, name=os.path.basename(os.path.normpath(args.out)))
    for note in notes:
        print(note, file=sys.stderr)
    # the camera's name in the BINGO headers ("image camera": Pix4D's FC6310_8.8_5472x3648) names its model
    names = {photo: header[0] for photo, header in params.bingo.header.items() if header}
    block = rolling.rolling_block(args, block, names)
    write_block(block, args.out, source=params_folder(args.source), say=progress)
    roles = {r: int((block.points.role == r).sum()) for r in ("gcp", "chk", "tie")}
    line = (f"imported {len(block.images)} images, {len(block.points)} points ({roles['gcp']} gcp, {roles['chk']} "
            f"chk, {roles['tie']} tie), {len(block.observations)} observations into {args.out}")
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
