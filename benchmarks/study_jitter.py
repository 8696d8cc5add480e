"""Attitude jitter of line images (issue 42): a PRISM-like triplet with platform jitter that the telemetry does not
record, adjusted with bias and drift alone, with ``--jitter auto``, and the same triplet without jitter.

    python benchmarks/study_jitter.py [--seeds 1,2,3] [--points 1500] [--levels auto|N] [--ties]
                                      [--terrain-sigma-m 2]

The triplet of :func:`selfcal.simulate.prism.simulate_prism` (three views at +23.8, 0, -23.8 deg, 14,000 lines of
0.37 ms each, 2.5 m pixels, 5 GCP, 0.3 px noise) with :data:`~selfcal.simulate.prism.JITTER`: 5 urad in roll and in
pitch (3 urad at 1.3 / 2.2 Hz and 2 urad at 4.1 / 3.7 Hz, about 1.4 px), the focal lengths given (their step is seed
001's, not this study's). Seed 001's M5 (bias and drift of roll, pitch, yaw), snooping as ``selfcal adjust`` runs it.

Per row: sigma0 (px), the share of image observations rejected, check-point RMSE across / along / up (m) and the RMS
of the sigma the adjustment states for them (the precision these observations give: an error at it is the floor), the time
of the jitter's choice and of one adjustment at the chosen level against one without jitter (the cost), and the
error of the estimated jitter against the truth beyond each image's linear part (urad RMS, roll and pitch): in all,
and in what the tie points can see (roll beyond the part common to the three images; pitch along fore - 2 nadir +
aft: the common part moves the ground along the track, fore minus aft moves its heights; neither is in the tie
points, both need control or terrain).

``--ties``: every tenth point a check point, the others tie points without coordinates (the simulator makes every
non-control point a check point); with it, the rows ``+ terrain``: the same with the heights of a DEM of the
simulated terrain (50 m cells, each with ``--terrain-sigma-m`` of noise) observed at the tie points with that sigma
(issue 42 item 2), which fixes what fore minus aft pitch does to heights.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from dataclasses import replace

from selfcal.adjust import AdjustOptions, SensorOptions, adjust
from selfcal.block import TerrainObservations
from selfcal.geometry.terrain import GridDem
from selfcal.simulate.prism import JITTER, dem_grid, prism_block, simulate_prism
from selfcal.stats.snooping import SnoopingOptions
from selfcal.workflows import seed001
from selfcal.workflows.jitter import choose_jitter

TRUE_FOCAL_MM = {"F": 1938.20, "N": 1937.45, "B": 1936.66}


def tie_block(block, gcps):
    """Every tenth non-control point a check point, the others tie points without coordinates."""
    role = np.full(len(block.points), "tie", object)
    role[np.arange(len(role)) % 10 == 5] = "chk"
    role[gcps] = "gcp"
    xyz = np.where((role == "tie")[:, None], np.nan, block.points.xyz_m)
    return replace(block, points=replace(block.points, role=role, xyz_m=xyz))


def noisy_dem(sim, sigma_m: float, seed: int) -> GridDem:
    dem = dem_grid(sim)
    noise = np.random.default_rng(seed + 77).normal(0.0, sigma_m, dem.heights_m.shape)
    return GridDem(dem.heights_m + noise, dem.transform)


def case(block, gcps, options):
    c = seed001.run_case(block, "M5", gcps, (0, 1, 2), None, "F+N+B", options, SnoopingOptions())
    r = c.tested.result if c.tested is not None else None
    rejected = 0.0 if c.tested is None else len(c.tested.rejected_rows) / len(block.observations.image_index)
    return c, r, rejected


def check_sigma_m(c) -> np.ndarray:
    """RMS over the check points of their a-posteriori sigma across / along / up (m): the precision the adjustment
    states for them (the reference's own sigma not in it); NaN where the case failed."""
    if c.failure or c.checks is None or not len(c.checks):
        return np.full(3, np.nan)
    row = {pid: k for k, pid in enumerate(c.result.block.points.point_id)}
    covariance = c.result.point_covariance()[[row[pid] for pid in c.checks.point_id]]
    sigma = np.sqrt(np.einsum("ij,njk,ik->ni", c.track_axes, covariance, c.track_axes))
    return np.sqrt(np.mean(sigma ** 2, axis=0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--points", type=int, default=1500)
    parser.add_argument("--levels", default="auto")
    parser.add_argument("--ties", action="store_true")
    parser.add_argument("--terrain-sigma-m", type=float, default=2.0)
    args = parser.parse_args()
    spec = "auto" if args.levels == "auto" else f"wavelet1d:db4:{int(args.levels)}"
    print(f"{'seed':>4} {'case':<32} {'sigma0':>6} {'rej %':>6} {'across':>7} {'along':>7} {'up':>7}  "
          f"{'jitter err roll/pitch':>22} {'seen roll/pitch':>16} {'sigma roll/pitch':>14}  "
          f"{'check sigma across/along/up':>27}  time")
    for seed in (int(s) for s in args.seeds.split(",")):
        for jitter in (False, True):
            sim = simulate_prism(seed=seed, n_points=args.points, jitter=JITTER if jitter else None)
            block = seed001.with_focal(prism_block(sim, seed=seed), TRUE_FOCAL_MM)
            gcps = seed001.choose_gcps(block, None)
            if args.ties:
                block = tie_block(block, gcps)
            base = AdjustOptions(sensor=SensorOptions(model="M5"))
            blocks = [("", block)]
            if args.ties:
                terrain = TerrainObservations(noisy_dem(sim, args.terrain_sigma_m, seed), args.terrain_sigma_m)
                blocks.append((" + terrain", replace(block, terrain_observations=terrain)))
            rows = []
            for label, b in blocks:
                rows.append(("bias+drift" + label, b, base, 0.0))
                if jitter:
                    t = time.perf_counter()
                    choice = choose_jitter(seed001.case_block(b, (0, 1, 2), gcps),
                                           AdjustOptions(sensor=SensorOptions(model="M5", jitter=spec)))
                    rows.append((f"{choice.spec.replace('wavelet1d:', '')}" + label, b, choice.options(base),
                                 time.perf_counter() - t))
            for name, block, options, chosen_s in rows:
                c, r, rejected = case(block, gcps, options)
                rmse = c.rmse_m if c.rmse_m is not None else np.full(3, np.nan)
                stated = check_sigma_m(c)
                error = sim.truth.jitter_error_urad(r) if (r is not None and jitter) else (np.full(2, np.nan),) * 2
                floor = sim.truth.jitter_sigma_urad(r) if r is not None else np.full(2, np.nan)
                sub = seed001.case_block(replace(block, terrain_observations=None), (0, 1, 2), gcps)
                t = time.perf_counter()
                adjust(sub, options)
                one_s = time.perf_counter() - t
                status = "" if not c.failure else "  FAILS: " + c.failure.split(":")[0][:60]
                print(f"{seed:>4} {('jitter ' if jitter else 'no jitter ') + name:<32} {c.sigma0 * 0.3:6.3f} "
                      f"{100 * rejected:6.2f} {rmse[0]:7.2f} {rmse[1]:7.2f} {rmse[2]:7.2f}  "
                      f"{error[0][0]:10.2f} {error[0][1]:10.2f}  {error[1][0]:7.2f} {error[1][1]:7.2f}  "
                      f"{floor[0]:6.2f} {floor[1]:6.2f}  {stated[0]:6.2f} {stated[1]:6.2f} {stated[2]:6.2f}  "
                      f"choice {chosen_s:.1f} s, one adjustment {one_s:.2f} s{status}", flush=True)


if __name__ == "__main__":
    main()
