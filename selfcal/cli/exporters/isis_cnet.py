"""``selfcal export isis-cnet``: the ISIS control network that was imported, with the adjusted points and the
measures' residuals in it (jigsaw's onet), as PVL or (``--binary``) an ISIS binary network."""
from __future__ import annotations

import argparse
import os

from ...io.atomic import atomic_write
from ...io.output import output_file
from ..outcome import finish


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--network", required=True, metavar="NET",
                        help="the ISIS control network 'selfcal import isis' read (PVL or binary)")
    parser.add_argument("--images", required=True, metavar="DIR",
                        help="its --images folder (the cube labels give the serial numbers of the image ids)")
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="control network to write (replaced; never inside RESULTS)")
    parser.add_argument("--binary", action="store_true",
                        help="write an ISIS binary (protobuf, version 5) network instead of PVL")


def run(args: argparse.Namespace) -> int:
    from ...convert import adjusted_network
    from ...io.isis import read_control_network, read_image_folder
    from ...io.isis_cnet import network_bytes, network_pvl
    from ...io.results import read_results_table
    args.out = output_file(args.out, (args.results, args.network))
    points = read_results_table(args.results, "points.csv")
    residuals = read_results_table(args.results, "residuals.csv")
    network = read_control_network(args.network)
    images = read_image_folder(args.images)
    image_of_serial = {s: os.path.splitext(os.path.basename(sensor))[0] for s, (_, sensor) in images.items()}
    scale = {s: ((a.alpha_ending_sample - a.alpha_starting_sample) / a.beta_samples,
                 (a.alpha_ending_line - a.alpha_starting_line) / a.beta_lines)
             for s, (label, _) in images.items() for a in [label.alpha_cube]}
    adjusted, counts = adjusted_network(network, image_of_serial, points, residuals, scale)
    if args.binary:
        with atomic_write(args.out, "wb", None) as handle:
            handle.write(network_bytes(adjusted))
    else:
        with atomic_write(args.out) as handle:
            handle.write(network_pvl(adjusted))
    line = (f"wrote {args.out} ({'binary' if args.binary else 'PVL'}): {counts['points_adjusted']} of "
            f"{len(network.points)} points adjusted, {counts['measures_with_residuals']} measures with residuals "
            f"({counts['measures_rejected']} JigsawRejected)")
    return finish(args, line, {"n_points": len(network.points), **counts}, [os.path.abspath(args.out)])
