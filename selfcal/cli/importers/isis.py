"""``selfcal import isis``: an ISIS PVL control network with its images' usgscsm/ALE ISDs (jigsaw's settings)."""
from __future__ import annotations

import argparse
import os
import sys

from ...errors import BlockError, UsageError
from ...io.block_folder import write_block
from ...io.output import output_folder
from ..options import count, number
from ..outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--images", metavar="DIR", help="folder of the ISIS cube labels (*.pvl) and their ISDs")
    parser.add_argument("--sigma-position-m", type=number(0.0, low_open=True), metavar="M",
                        help="a-priori sigma of each image's position (jigsaw's spacecraft_position_sigma)")
    parser.add_argument("--sigma-attitude-deg", type=number(0.0, low_open=True), metavar="DEG",
                        help="a-priori sigma of each image's attitude angles (jigsaw's camera_angles_sigma)")
    parser.add_argument("--attitude-degree", type=count(0, 3), metavar="N",
                        help="line scanners: degree 0..3 of the attitude corrections (jigsaw's cksolvedegree)")
    parser.add_argument("--no-twist", action="store_true",
                        help="line scanners: no correction of the rotation about the line of sight (jigsaw twist=no)")
    parser.add_argument("--solve-position", action="store_true",
                        help="line scanners: a constant J2000 offset of each image's trajectory, weighted by "
                             "--sigma-position-m (jigsaw spsolve=position; frame images always have theirs)")
    parser.add_argument("--hold-radii", type=number(0.0, low_open=True), metavar="M",
                        help="Free points keep their a-priori radius within this sigma (m), latitude and longitude "
                             "free: jigsaw's radius=no, which holds them on the DEM the a-priori points came from")
    parser.add_argument("--strict", action="store_true",
                        help="a *.pvl in --images that cannot be read as a cube label is an error (by default it "
                             "is left out with a warning naming it)")
    parser.add_argument("--measure-sigma-px", type=number(0.0, low_open=True), default=None, metavar="PX",
                        help="a-priori sigma of a measure in cube pixels (default: jigsaw's 1.4 detector pixels)")


def run(args: argparse.Namespace) -> int:
    args.out = output_folder(args.out, (args.source, args.images), args.force)
    from ...convert import block_from_isis
    from ...io.isis import read_control_network, read_image_folder
    from ...io.sensor_files import read_usgscsm
    if not args.images:
        raise UsageError("selfcal import isis needs --images DIR (the cube labels and their ISDs)")
    for flag, value in (("--sigma-position-m", args.sigma_position_m), ("--sigma-attitude-deg", args.sigma_attitude_deg),
                        ("--measure-sigma-px", args.measure_sigma_px)):
        if value is not None and not value > 0:
            raise UsageError(f"{flag} must be positive, found {value}")
    network = read_control_network(args.source)
    left_out: list[tuple[str, str]] = []
    images = read_image_folder(args.images, left_out=left_out)
    for path, why in left_out:
        if args.strict:
            raise BlockError(path, f"{why}; with --strict every *.pvl in --images must be a cube label")
        print(f"warning: {path}: left out of the images: {why}", file=sys.stderr)
    if not images:
        raise BlockError(args.images, "no ISIS cube label (*.pvl with 'Object = IsisCube') in the folder")
    first = read_usgscsm(next(iter(images.values()))[1])
    line_only = [flag for flag, given in (("--attitude-degree", args.attitude_degree is not None),
                                          ("--no-twist", args.no_twist), ("--solve-position", args.solve_position))
                 if given]
    if line_only and hasattr(first, "trans_x"):
        raise UsageError(f"{', '.join(line_only)} {'applies' if len(line_only) == 1 else 'apply'} to line-scan ISDs "
                         f"only; the images in {args.images} are frame ISDs (their positions and RA/DEC/TWIST are "
                         f"always estimated)")
    sigma_px = args.measure_sigma_px
    if sigma_px is None:                  # jigsaw: 1.4 detector pixels, in the pixels of the cubes
        detector_px = getattr(first, "alpha_cube", None)
        scale = 1.0 if detector_px is None else (detector_px.alpha_ending_sample - detector_px.alpha_starting_sample) \
            / detector_px.beta_samples
        sigma_px = 1.4 / scale
    settings = {k: v for k, v in (("sigma_position_m", args.sigma_position_m),
                                  ("sigma_attitude_deg", args.sigma_attitude_deg),
                                  ("attitude_degree", args.attitude_degree)) if v is not None}
    if args.no_twist:
        settings["twist"] = False
    if args.solve_position:
        settings["position_offsets"] = True
    if args.attitude_degree is not None and not 0 <= args.attitude_degree <= 3:
        raise UsageError(f"--attitude-degree must be 0..3, found {args.attitude_degree}")
    if args.hold_radii is not None and not args.hold_radii > 0:
        raise UsageError(f"--hold-radii must be positive, found {args.hold_radii}")
    block, counts = block_from_isis(network, images, sigma_px, os.path.basename(os.path.normpath(args.out)), settings,
                                    hold_radii_m=args.hold_radii)
    write_block(block, args.out, source=args.source, say=progress)
    if args.hold_radii is not None and (block.points.role == "tie").any():
        from ...io import read_block
        from ...workflows.isis import hold_radii
        block = hold_radii(read_block(args.out), args.hold_radii)
        write_block(block, args.out)
    roles = {r: int((block.points.role == r).sum()) for r in ("gcp", "tie")}
    missing = sorted({m.serial_number for m in network.measures if not m.ignored and m.serial_number not in images})
    line = (f"imported {len(block.images)} images, {len(block.points)} points ({roles['gcp']} gcp, {roles['tie']} "
            f"tie), "
            f"{len(block.observations)} measures (sigma {sigma_px:.3g} px) into {args.out}; left out: "
            f"{counts['ignored_points']} ignored points, {counts['ignored_measures']} ignored measures, "
            f"{counts['measures_without_image']} measures of images not in {args.images}"
            + (f" (serial numbers {', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''}"
               + (f"; left out: {', '.join(os.path.basename(p) for p, _ in left_out)})" if left_out else ")")
               if missing else ""))
    return finish(args, line, {"n_images": len(block.images), "n_points": len(block.points),
                               "n_observations": len(block.observations)}, [os.path.abspath(args.out)])
