"""Simulate a block with known truth (the UAV block of seed 000, the PRISM triplet of seed 001)."""
from __future__ import annotations

import argparse
import os

from ..errors import UsageError
from ..simulate.names import DISTORTIONS, FLIGHTS, SCENARIOS
from .outcome import finish
from .options import count, force_option, number


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("kind", choices=["uav", "prism"],
                        help="what to simulate (uav: the 28-image block of seed 000; prism: the ALOS/PRISM "
                             "forward/nadir/backward triplet of seed 001)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="folder to write: the block folders (uav: one per scenario; prism: triplet/) and truth/")
    force_option(parser)
    parser.add_argument("--seed", type=count(0, 2**32 - 1), default=0, help="random seed (default 0)")
    parser.add_argument("--scenario", choices=SCENARIOS, action="append",
                        help="control scenario to write (repeatable; default: all four)")
    parser.add_argument("--distortion", choices=DISTORTIONS, default="local+brown",
                        help="true distortion field of the camera (default: local+brown)")
    parser.add_argument("--distortion-scale", type=number(0.0, 100.0), default=1.0, metavar="S",
                        help="multiply the field (1: -11 px radial in the corners, bumps of 2-3 px; "
                             "selfcal demo uses 4)")
    parser.add_argument("--noise-px", type=number(0.0, 100.0, low_open=True), default=0.5, help="image measurement noise sigma (default 0.5)")
    parser.add_argument("--blunder-rate", type=number(0.0, 0.5, high_open=True), default=0.0,
                        help="share of image observations with a 4-15 px blunder (default 0)")
    parser.add_argument("--points", type=count(7, 100000), default=28, metavar="N",
                        help="prism: ground points measured in the triplet (default 28, as seed 001)")
    parser.add_argument("--flight", choices=FLIGHTS, default="seed000",
                        help="uav: seed000 (the camera turns at the strip ends), serpentine (the same strips with a "
                             "fixed heading) or corridor (2 long strips out and back, fixed heading); default seed000")
    parser.add_argument("--speed-mps", type=number(0.0, 100.0, low_open=True), default=8.0, metavar="V",
                        help="uav: ground speed along the strips (default 8 m/s)")
    parser.add_argument("--rolling-shutter-ms", type=number(0.0, 1000.0), default=0.0, metavar="MS",
                        help="uav: a rolling shutter read in MS from the first to the last row while the camera "
                             "moves (default 0: a global shutter); the blocks declare it with a wide prior")
    parser.add_argument("--line-error", action="store_true",
                        help="prism: give the nadir camera a chip-wise error of its detector line that the block "
                             "does not know (chips misaligned by up to 0.9 px, a 1 px bow; for --ap wavelet1d)")
    parser.add_argument("--jitter", action="store_true",
                        help="prism: the platform's attitude jitter that the telemetry does not record: 5 urad "
                             "(about 1.4 px) in roll and pitch at two frequencies of 1.3-4.1 Hz (for adjust --jitter)")


def run(args: argparse.Namespace) -> int:
    from ..simulate import simulate_uav, truth_files
    from ..io.atomic import atomic_folder
    from ..io.block_folder import write_block
    from ..io.output import output_folder
    from ..io.results import write_files
    args.out = output_folder(args.out, (), args.force)
    if args.kind == "prism":
        return _prism(args)
    if not 0.0 <= args.blunder_rate < 0.5:
        raise UsageError("--blunder-rate must be in [0, 0.5)")
    if args.noise_px <= 0:
        raise UsageError("--noise-px must be positive")
    if args.distortion_scale < 0:
        raise UsageError("--distortion-scale must not be negative")
    sim = simulate_uav(seed=args.seed, distortion=args.distortion, distortion_scale=args.distortion_scale,
                       image_sigma_px=args.noise_px, blunder_rate=args.blunder_rate, flight=args.flight,
                       speed_mps=args.speed_mps, rolling_shutter_ms=args.rolling_shutter_ms)
    scenarios = args.scenario or list(SCENARIOS)
    with atomic_folder(args.out) as tmp:
        for name in scenarios:
            write_block(sim.blocks[name], os.path.join(tmp, name))
        os.makedirs(os.path.join(tmp, "truth"))
        write_files(os.path.join(tmp, "truth"), truth_files(sim.truth))
    info = sim.info
    shutter = f", a rolling shutter of {args.rolling_shutter_ms:g} ms at {args.speed_mps:g} m/s" \
        if args.rolling_shutter_ms > 0 else ""
    flight = f" ({args.flight} flight)" if args.flight != "seed000" else ""
    return finish(args, f"simulated {info['n_images']} images{flight}, {info['n_points']} points, "
                        f"{info['n_observations']} image observations ({info['points_per_image']:.0f} per image), "
                        f"distortion {args.distortion}{shutter}; wrote {', '.join(scenarios)} and truth/ to {args.out}",
                  {k: info[k] for k in ("n_images", "n_points", "n_observations")},
                  [os.path.abspath(os.path.join(args.out, name)) for name in (*scenarios, "truth")])


def _prism(args: argparse.Namespace) -> int:
    from ..io.atomic import atomic_folder
    from ..io.block_folder import write_block
    from ..io.results import write_files
    from ..io.dem import write_dem
    from ..simulate.prism import JITTER, LINE_ERROR_PX, dem_grid, prism_block, prism_truth_files, simulate_prism

    for flag, given in (("--flight", args.flight != "seed000"), ("--speed-mps", args.speed_mps != 8.0),
                        ("--rolling-shutter-ms", args.rolling_shutter_ms != 0.0)):
        if given:
            raise UsageError(f"{flag} is an option of 'simulate uav' (a frame camera's flight), not of the PRISM "
                             f"triplet")
    noise = 0.3 if args.noise_px == 0.5 else args.noise_px       # seed 001's points: about 0.3 px
    if noise <= 0:
        raise UsageError("--noise-px must be positive")
    if args.points < 7:
        raise UsageError("--points must be at least 7")
    sim = simulate_prism(seed=args.seed, image_sigma_px=noise, n_points=args.points,
                         detector_error_px=LINE_ERROR_PX if args.line_error else None,
                         jitter=JITTER if args.jitter else None)
    block = prism_block(sim, seed=args.seed)
    with atomic_folder(args.out) as tmp:
        folder = os.path.join(tmp, "triplet")
        write_block(block, folder)
        write_dem(os.path.join(folder, "dem.tif"), dem_grid(sim))
        os.makedirs(os.path.join(tmp, "truth"))
        write_files(os.path.join(tmp, "truth"), prism_truth_files(sim))
    n_gcp = int((block.points.role == "gcp").sum())
    return finish(args, f"simulated the PRISM triplet F/N/B: {len(sim.point_ids)} points ({n_gcp} GCP), "
                        f"{len(sim.obs_row)} image points with {noise} px noise, telemetry at 1 Hz / 10 Hz; wrote "
                        f"triplet/ and truth/ to {args.out}",
                  {"n_points": len(sim.point_ids), "n_gcp": n_gcp, "n_observations": len(sim.obs_row)},
                  [os.path.abspath(os.path.join(args.out, name)) for name in ("triplet", "truth")])
