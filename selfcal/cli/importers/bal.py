"""``selfcal import bal``: a Bundle Adjustment in the Large problem file."""
from __future__ import annotations

import argparse
import os
import sys

from ...convert import bal_behind_camera, block_from_bal
from ...io.bal import read_bal
from ...io.block_folder import write_block
from ...io.output import output_folder
from ..options import number
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--image-sigma-px", type=number(0.0, low_open=True), default=1.0,
                        help="a-priori sigma of an image measurement (default 1.0 px)")


def run(args: argparse.Namespace) -> int:
    args.out = output_folder(args.out, (args.source,), args.force)
    problem = read_bal(args.source)
    block = block_from_bal(problem, args.image_sigma_px, name=os.path.basename(os.path.normpath(args.out)))
    behind = bal_behind_camera(problem)
    if behind.any():
        print(f"warning: {int(behind.sum())} observations of {len(set(problem.obs_point[behind]))} points lie "
              f"behind their camera; BAL's formula still gives them a residual (COLMAP would ignore them)",
              file=sys.stderr)
    write_block(block, args.out, source=args.source, say=progress)
    line = (f"imported {len(block.images)} images (one BAL camera each), {len(block.points)} points, "
            f"{len(block.observations)} observations into {args.out}; BAL has no datum: adjust it with "
            f"ground control, or use it as a relative problem")
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
