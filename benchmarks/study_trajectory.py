"""Do GNSS/IMU trajectory data ever make the block worse? A paired Monte-Carlo study (issue 25).

Seed 000 adds strip-wise GNSS/IMU observations with shift and drift (Eq. 12) to its
Types 1 and 3 and calls them Types 2 and 4. This study simulates the seed-000 block
(28 images in 4 strips of 12 s, mixed lens field local+brown, wavelet APs db4 on the
9x6 grid) with trajectory errors drawn *independently of the adjustment's
parametrisation* (selfcal.simulate.trajectory.TrajectoryErrors):

* GNSS shifts 0.1-0.45 m and drifts up to 0.02 m/s, IMU shifts up to 0.13 deg and drifts up
  to 0.005 deg/s, independent per strip and axis; half of the (sensor, strip) pairs drift
  at all (their drift terms are truly zero);
* noise GNSS 3/3/5 cm declared 5/5/10 cm, IMU 0.005/0.005/0.01 deg declared 0.01/0.01/0.02 deg;
* the seeds cycle through 8 variants: drift counted from the strip's first exposure or
  from its middle, IMU error added to omega-phi-kappa or applied as a small rotation of
  the body frame, GNSS antenna at the perspective centre or at a lever arm (declared in
  block.toml).

Every seed is adjusted as Types 1-4, with data snooping, without and with screening
(``--screen``). Printed: the tie-point RMS against the simulated truth in XY and Z
(mean over seeds), the paired change 1 -> 2 and 3 -> 4 (mean, worst seed, paired t), and
for the screened runs every dropped trajectory term against its truth in the
adjustment's own parametrisation (selfcal.simulate.trajectory.noise_free_terms): how
many dropped terms were really larger than 3 sigma of their estimate, and what share
of the truly zero terms was dropped.

Run: ``python benchmarks/study_trajectory.py [--seeds 32] [--processes 2] [--points 3.5] [--save JSON]``
(about 2 min per seed and process with 3.5 points/mm^2: 32 seeds took 34 min on 2 processes, each tested
adjustment peaking at about 2.5 GB).
"""
from __future__ import annotations

import argparse
import itertools
import json
import time
from multiprocessing import Pool

import numpy as np

TYPES = ("type1", "type2", "type3", "type4")
PAIRS = (("type1", "type2"), ("type3", "type4"))
VARIANTS = list(itertools.product(("first", "middle"), ("opk", "rotation"), (False, True)))
LEVER_ARM_M = (0.12, -0.08, 0.35)


def simulate(seed: int, points_per_mm2: float = 3.5, variant: int | None = None):
    """The simulation of a seed: the variant (drift origin, IMU composition, lever arm) cycles with it."""
    from selfcal.simulate import simulate_uav
    from selfcal.simulate.trajectory import TrajectoryErrors
    origin, composition, lever = VARIANTS[(seed if variant is None else variant) % len(VARIANTS)]
    errors = TrajectoryErrors(drift_origin=origin, imu_composition=composition)
    return simulate_uav(seed=seed, distortion="local+brown", points_per_mm2=points_per_mm2,
                        gnss_sigma_m=(0.05, 0.05, 0.10), imu_sigma_deg=(0.01, 0.01, 0.02),
                        trajectory_errors=errors, exposure_interval_s=2.0,
                        lever_arm_m=LEVER_ARM_M if lever else (0.0, 0.0, 0.0), declare_mounting=lever)


def tie_point_rms(sim, result) -> tuple[float, float]:
    """RMS of the tie-point errors against the truth, XY and Z (m)."""
    lookup = {p: i for i, p in enumerate(sim.truth.point_id)}
    points = result.block.points
    tie = np.flatnonzero(points.role == "tie")
    d = result.state.points[tie] - sim.truth.xyz[[lookup[p] for p in points.point_id[tie]]]
    return float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


def one_seed(args) -> dict:
    """Tie-point RMS of every Type without and with screening, and the screening's trajectory decisions
    against the truth: (scenario, name, true value, sigma in the unscreened adjustment, value and sigma at
    the drop, t at the drop)."""
    seed, points_per_mm2 = args
    from selfcal.adjust import AdjustOptions, APOptions, TrajectoryOptions
    from selfcal.block import prune
    from selfcal.stats.screening import ScreeningOptions
    from selfcal.simulate.trajectory import true_terms_by_name
    from selfcal.workflows.tested import adjust_with_tests
    sim = simulate(seed, points_per_mm2)
    options = AdjustOptions(ap=APOptions("wavelet:db4", grid=(9, 6)), trajectory=TrajectoryOptions(gnss_drift=1, imu_drift=1))
    out = {"seed": seed, "variant": VARIANTS[seed % len(VARIANTS)], "rms": {}, "dropped": [], "zero": [0, 0], "z": []}
    unscreened = {}
    for screen in (False, True):
        for scenario in TYPES:
            tested = adjust_with_tests(prune(sim.blocks[scenario]), options,
                                       screening=ScreeningOptions() if screen else None)
            out["rms"][(scenario, screen)] = tie_point_rms(sim, tested.result)
            if scenario not in ("type2", "type4"):
                del tested                  # one tested adjustment in memory at a time (~2.5 GB each)
                continue
            if not screen:
                r = tested.result
                unscreened[scenario] = (true_terms_by_name(sim.truth, r), dict(zip(r.theta_names, np.sqrt(
                    r.variance_factor * np.diag(r.Q_theta)))))
                estimate = dict(zip(r.theta_names, r.problem.pack(r.state)))
                truth, sigma = unscreened[scenario]
                out["z"] += [(scenario, name, (estimate[name] - value) / sigma[name])
                             for name, (value, _) in truth.items()]
                del tested, r
                continue
            truth, sigma = unscreened[scenario]
            dropped = {d.name: d for _, d in tested.screening_log if d.camera_id in ("GNSS", "IMU")}
            del tested
            for name, d in dropped.items():
                out["dropped"].append((scenario, name, truth[name][0], sigma[name], getattr(d, "value", np.nan),
                                       getattr(d, "sigma", np.nan), d.t))
            zero = [name for name, (_, is_zero) in truth.items() if is_zero]
            out["zero"][0] += len(zero)
            out["zero"][1] += sum(name in dropped for name in zero)
    return out


def paired(before: np.ndarray, after: np.ndarray) -> tuple[float, float, float]:
    """Mean relative change (%), worst seed (%), paired t of after - before."""
    change = after - before
    t = change.mean() / (change.std(ddof=1) / np.sqrt(len(change)))
    relative = 100 * (after / before - 1)
    return float(100 * (after.mean() / before.mean() - 1)), float(relative.max()), float(t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=32, help="number of simulated blocks (default 32)")
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--processes", type=int, default=1)
    parser.add_argument("--points", type=float, default=3.5, help="image points per mm^2 (default 3.5)")
    parser.add_argument("--save", metavar="JSON", help="also write every seed's numbers to this file")
    args = parser.parse_args()
    start = time.perf_counter()
    seeds = [(s, args.points) for s in range(args.first_seed, args.first_seed + args.seeds)]
    if args.processes > 1:
        with Pool(args.processes, maxtasksperchild=1) as pool:    # a fresh process per seed: memory back
            runs = pool.map(one_seed, seeds, chunksize=1)
    else:
        runs = [one_seed(s) for s in seeds]
    if args.save:
        with open(args.save, "w", encoding="utf-8") as f:
            json.dump([{**r, "rms": {f"{s}{' screened' if sc else ''}": v for (s, sc), v in r["rms"].items()}}
                       for r in runs], f)
    print(f"{args.seeds} simulated blocks (seeds {args.first_seed}-{args.first_seed + args.seeds - 1}), "
          f"{args.points:g} points/mm^2, wavelet:db4 9x6, snooping on; {time.perf_counter() - start:.0f} s")
    print("tie-point RMS against the truth, mean over seeds [mm]")
    print(f"{'':10}" + "".join(f"{s + (' screened' if sc else ''):>17}" for sc in (False, True) for s in TYPES))
    rms = {key: np.array([r["rms"][key] for r in runs]) for key in runs[0]["rms"]}
    for j, axis in enumerate(("XY", "Z")):
        print(f"{axis:10}" + "".join(f"{1000 * rms[(s, sc)][:, j].mean():>17.2f}" for sc in (False, True) for s in TYPES))
    print(f"{'pair':<22}{'axis':>5}{'mean change':>13}{'worst seed':>12}{'paired t':>10}")
    for screen in (False, True):
        for a, b in PAIRS:
            for j, axis in enumerate(("XY", "Z")):
                mean, worst, t = paired(rms[(a, screen)][:, j], rms[(b, screen)][:, j])
                label = f"{a} -> {b}" + (" screened" if screen else "")
                print(f"{label:<22}{axis:>5}{mean:>12.2f}%{worst:>11.2f}%{t:>10.2f}")
    print("unscreened shift/drift terms against their truth, z = (estimate - true) / sigma, all seeds")
    z = [(name.split()[0], name.split()[2], value) for r in runs for _, name, value in r["z"]]
    for sensor in ("GNSS", "IMU"):
        for term in ("D0", "D1"):
            zs = np.array([v for s, t, v in z if s == sensor and t == term])
            if zs.size:
                print(f"  {sensor} {term}: {zs.size} terms, mean z {zs.mean():+.2f}, rms z {np.sqrt(np.mean(zs ** 2)):.2f}, "
                      f"max |z| {np.abs(zs).max():.2f}")
    dropped = [d for r in runs for d in r["dropped"]]
    large = [(r["seed"],) + d for r in runs for d in r["dropped"] if abs(d[2]) > 3 * d[3]]
    large_at_drop = [(r["seed"],) + d for r in runs for d in r["dropped"] if abs(d[2]) > 3 * d[5]]
    zero = np.sum([r["zero"] for r in runs], axis=0)
    print(f"screening: {len(dropped)} trajectory terms dropped; with |true| > 3 sigma of the unscreened estimate: "
          f"{len(large)}, > 3 sigma at the drop: {len(large_at_drop)}; truly zero terms dropped: {zero[1]} of "
          f"{zero[0]} ({100 * zero[1] / max(zero[0], 1):.0f} %)")
    for seed, scenario, name, true, sigma, value, sigma_drop, t in sorted(set(large) | set(large_at_drop)):
        print(f"  seed {seed} {scenario} {name}: true {true:.4g}, sigma {sigma:.3g} (at the drop {sigma_drop:.3g}, "
              f"estimate {value:.4g}, t {t:.2f})")
    ratio = np.array([abs(d[2]) / d[3] for d in dropped])
    if ratio.size:
        print(f"  |true| / sigma of the dropped terms: median {np.median(ratio):.2f}, 95th percentile "
              f"{np.percentile(ratio, 95):.2f}, largest {ratio.max():.2f}")
    print("per variant (drift origin, IMU error, lever arm): worst XY change 1 -> 2, 3 -> 4 screened")
    for v in VARIANTS:
        mine = [r for r in runs if tuple(r["variant"]) == v]
        if mine:
            worst = [max(100 * (r["rms"][(b, True)][0] / r["rms"][(a, True)][0] - 1) for r in mine) for a, b in PAIRS]
            print(f"  {str(v):<32} seeds {len(mine):>3}  {worst[0]:+6.2f}%  {worst[1]:+6.2f}%")


if __name__ == "__main__":
    main()
