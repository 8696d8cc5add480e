"""How much do GNSS/IMU trajectory data improve the check points? A Monte-Carlo study.

Seed 000 reports that adding GNSS/IMU with strip-wise shift and drift (Type 1 -> 2,
Type 3 -> 4) improves the check-point RMSD. On one simulated block the gain (a few
per cent) is smaller than the spread of an RMSD over 12 check points, so this study
adjusts all four Types of many simulated blocks (brown distortion, 1 tie point per
mm^2, GNSS shifts 0.2 m and drifts 5 mm/s per strip, IMU shifts 0.05 deg) and
compares the Types of each seed with each other (paired: same images, same noise).

Printed per Type: the RMSD pooled over seeds (3-D, metres, against the simulated
truth) and the RMS of the a-posteriori sigmas the adjustment predicts for the same
points; per pair: the mean paired change of the mean squared error, its standard
error and t.

Run: ``python benchmarks/study_trajectory.py [--seeds 96]`` (about 1 s per seed).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

TYPES = ("type1", "type2", "type3", "type4")


def one_seed(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean squared 3-D check-point error and mean predicted variance (m^2) of each Type."""
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    sim = simulate_uav(seed=seed, distortion="brown", points_per_mm2=1.0)
    lookup = {p: i for i, p in enumerate(sim.truth.point_id)}
    error, predicted = [], []
    for scenario in TYPES:
        result = adjust(prune(sim.blocks[scenario]), AdjustOptions(ap="brown", gnss_drift=1, imu_drift=0))
        chk = np.flatnonzero(result.block.points.role == "chk")
        d = result.state.points[chk] - sim.truth.xyz[[lookup[p] for p in result.block.points.point_id[chk]]]
        error.append(np.mean(np.sum(d * d, axis=1)))
        predicted.append(result.variance_factor * np.mean(np.einsum("nii->n", result.Q_points[chk])))
    return np.array(error), np.array(predicted)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=96, help="number of simulated blocks (default 96)")
    args = parser.parse_args()
    start = time.perf_counter()
    runs = [one_seed(seed) for seed in range(1, args.seeds + 1)]
    error = np.array([r[0] for r in runs])
    predicted = np.array([r[1] for r in runs])
    print(f"{args.seeds} simulated blocks, 12 check points each, {time.perf_counter() - start:.0f} s")
    print(f"{'type':<6} {'RMSD 3-D [mm]':>14} {'predicted [mm]':>15}")
    for k, name in enumerate(TYPES):
        print(f"{name:<6} {1000 * np.sqrt(error[:, k].mean()):>14.2f} {1000 * np.sqrt(predicted[:, k].mean()):>15.2f}")
    print(f"{'pair':<14} {'RMSD change':>12} {'paired MSE change [mm^2]':>26} {'t':>6}")
    for a, b in ((0, 1), (2, 3)):
        change = error[:, b] - error[:, a]
        se = change.std(ddof=1) / np.sqrt(len(change))
        ratio = np.sqrt(error[:, b].mean() / error[:, a].mean()) - 1
        print(f"{TYPES[a]} -> {TYPES[b]:<5} {100 * ratio:>11.1f}% {1e6 * change.mean():>16.1f} +- {1e6 * se:<6.1f}"
              f" {change.mean() / se:>6.1f}")


if __name__ == "__main__":
    main()
