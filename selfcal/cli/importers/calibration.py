"""``selfcal import calibration``: another tool's calibration of one camera as that camera's initial (or fixed)
interior orientation and additional parameters, in a copy of a block."""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

from ...convert import camera_from_calibration
from ...errors import BlockError, UsageError
from ...io.block_folder import read_block, write_block
from ...io.calibration_files import read_calibration_file
from ...io.output import output_folder
from ..options import number
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--block", required=True, metavar="BLOCK", help="block folder to add it to (read only)")
    parser.add_argument("--camera", metavar="ID", help="the block's camera it calibrates (needed when it has several)")
    parser.add_argument("--fixed", action="store_true",
                        help="hold the calibration in the adjustment (c, x0, y0 and the APs, whatever model "
                             "'selfcal adjust --ap' asks for) instead of starting from it")
    parser.add_argument("--ap", default="brown", metavar="MODEL",
                        help="AP model whose initial values take up the distortion (default brown)")
    parser.add_argument("--tolerance-px", type=number(0.0, low_open=True), default=0.05,
                        help="largest misfit of the AP fit over the image without a warning (default 0.05 px)")


def run(args: argparse.Namespace) -> int:
    args.out = output_folder(args.out, (args.source, args.block), args.force)
    tool_cal = read_calibration_file(args.source)
    block = read_block(args.block)
    frames = {cid: cam for cid, cam in block.cameras.items() if cam.model == "frame"}
    if args.camera is None:
        if len(frames) != 1:
            raise UsageError(f"the block has {len(frames)} frame cameras ({', '.join(frames)}): choose one with "
                             f"--camera")
        args.camera = next(iter(frames))
    if args.camera not in frames:
        raise UsageError(f"--camera {args.camera}: no such frame camera in {args.block} (it has: "
                         f"{', '.join(frames)})")
    camera = frames[args.camera]
    if (tool_cal.width_px, tool_cal.height_px) != (camera.width_px, camera.height_px):
        raise BlockError(args.source, f"calibrates a {tool_cal.width_px} x {tool_cal.height_px} px image; camera "
                                      f"{args.camera} of {args.block} is {camera.width_px} x {camera.height_px} px")
    try:
        new_camera, misfit_px = camera_from_calibration(tool_cal, camera, args.ap, args.fixed)
    except ValueError as exc:
        raise UsageError(f"--ap {args.ap}: {exc}") from None
    except ArithmeticError as exc:
        raise BlockError(args.source, str(exc)) from None
    progress(f"{args.source}: {tool_cal.tool} {tool_cal.model} calibration of {tool_cal.width_px} x "
             f"{tool_cal.height_px} px")
    progress(f"camera {args.camera}: c = {new_camera.focal_mm:.5f} mm, x0 = {new_camera.x0_mm:.5f} mm, y0 = "
             f"{new_camera.y0_mm:.5f} mm, {args.ap} APs reproduce its distortion within {misfit_px:.4f} px over the "
             f"image; {'held fixed' if args.fixed else 'initial values'}")
    if misfit_px > args.tolerance_px:
        print(f"warning: camera {args.camera}: the {args.ap} APs reproduce the {tool_cal.tool} calibration only within "
              f"{misfit_px:.3f} px (selfcal's terms are centred on the frame, the tool's on its principal point)"
              + ("; held with --fixed, that error stays in the adjustment" if args.fixed else
                 "; the adjustment refines them"), file=sys.stderr)
    cameras = dict(block.cameras)
    cameras[args.camera] = new_camera
    write_block(replace(block, cameras=cameras), args.out, source=args.source, say=progress)
    line = f"wrote {args.out}"
    return finish(args, line, {"camera_id": args.camera, "focal_mm": new_camera.focal_mm, "misfit_px": misfit_px},
                  [os.path.abspath(args.out)])
