"""Honest precision on simulated truth (issue 44 item 5): does a calibration's sigma cover its error?

The block: selfcal.simulate.close_range, a free convergent network of 11 images of a 10 x 6 m wall with relief
(1500 points, 1 px of noise; the cameras at one height, turned by 0.7 degrees about the wall's middle) and
Strecha's camera (fx 2759.48, fy 2764.16: an affinity of 0.17 %, no distortion). In selfcal's model the camera is
c = fy with Brown's b1; its c trades with b1 at rho -0.9 and more (the vertical scale of the object is what the
cameras at one height cannot tell from fy).

1. Where the AP basis is evaluated (``--ap-at``): brown adjusted over SEEDS noise seeds with the basis at the
   measured image coordinates and at the adjusted ones; per parameter the mean and the scatter of z = (estimate -
   truth) / sigma (1 and 0 ... 1 where sigma is right and the estimate unbiased) and the share within 2 sigma;
   BIC's preference for brown over none (2 Delta cost - Delta k ln n, positive: brown).
2. The jackknife over the images (11 groups): how often it calls the calibration "not trusted" with the model
   right (false alarms, alpha 0.001 per parameter), and with the focus changed between images by 0.1, 0.2, 0.3 %
   (a model error no AP family represents): detections, the largest ratio sigma_J / sigma, and how often the
   honest sigma (the larger of the stated and the jackknife's) covers c's error within 2x. The brown model is
   adjusted, c against fy. And ``none`` on the same camera: its one c cannot be fx and fy at once; the arc's
   horizontal spread makes it fx's, and it is compared with fx.

Run: python benchmarks/study_honest_precision.py [--seeds 20]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from selfcal.adjust import AdjustOptions, APOptions, adjust
from selfcal.simulate.close_range import simulate_close_range
from selfcal.stats.calibration_precision import critical_ratio
from selfcal.workflows.jackknife import calibration_precision
from selfcal.workflows.tested import adjust_with_tests

BLOCK = dict(n_images=11, n_points=1500, image_sigma_px=1.0, turn_sd_deg=0.7)


def z_scores(result, truth) -> dict[str, float]:
    return truth.z_scores(result.state.cameras[0], result.camera_sigma()[0], result.problem.cameras[0].names)


def bic(result) -> float:
    return 2 * result.cost + result.n_unknowns * np.log(result.n_observations)


def where_evaluated(seeds: int) -> None:
    print(f"\n1. brown on {seeds} seeds: z = (estimate - truth) / sigma per parameter: mean, scatter, share |z| <= 2; "
          f"BIC(none) - BIC(brown) (positive: BIC takes brown)\n")
    print("| AP basis at | c: mean z, sd, within 2σ | x0 | y0 | b1 | BIC none − brown: median (share > 0) |")
    print("|---|---|---|---|---|---|")
    for at in ("measured", "adjusted"):
        z: dict[str, list[float]] = {}
        gain = []
        for seed in range(seeds):
            sim = simulate_close_range(seed, **BLOCK)
            brown = adjust(sim.block, AdjustOptions(ap=APOptions("brown", evaluated_at=at)))
            none = adjust(sim.block, AdjustOptions(ap=APOptions("none")))
            for k, v in z_scores(brown, sim.truth).items():
                z.setdefault(k, []).append(v)
            gain.append(bic(none) - bic(brown))
        cells = []
        for k in ("c", "x0", "y0", "b1"):
            v = np.array(z[k])
            cells.append(f"{v.mean():+.1f}, {v.std(ddof=1):.2f}, {np.mean(np.abs(v) <= 2):.0%}")
        g = np.array(gain)
        print(f"| {at} | " + " | ".join(cells) + f" | {np.median(g):+.0f} ({np.mean(g > 0):.0%}) |")


def jackknife_study(seeds: int) -> None:
    print(f"\n2. the jackknife over 11 groups (one image each), {seeds} seeds per row; critical ratio "
          f"{critical_ratio(11):.2f}; c against fy (none: against fx, which its one c meets)\n")
    print("| lens, model | not trusted | largest σ_J/σ of c, x0, y0 (median) | c: \\|e\\|/σ median | "
          "c: \\|e\\|/σ_honest median | c covered by 2 σ_honest | seconds per run |")
    print("|---|---|---|---|---|---|---|")
    for label, focal_sd, model in (("right, brown", 0.0, "brown"), ("focus 0.1 %, brown", 0.001, "brown"),
                                   ("focus 0.2 %, brown", 0.002, "brown"), ("focus 0.3 %, brown", 0.003, "brown"),
                                   ("right, none (fx != fy)", 0.0, "none")):
        flagged, largest, z, z_honest, covered, seconds = [], [], [], [], [], []
        for seed in range(seeds):
            sim = simulate_close_range(seed, **BLOCK, focal_sd=focal_sd)
            options = AdjustOptions(ap=APOptions(model))
            t0 = time.perf_counter()
            tested = adjust_with_tests(sim.block, options, snooping=None)
            summary, _ = calibration_precision(tested, options, groups=11)
            seconds.append(time.perf_counter() - t0)
            params = summary["cameras"]["cam"]
            c = next(p for p in params if p["name"] == "c")
            error = abs(c["value"] - (sim.truth.fy_px if model == "brown" else sim.truth.fx_px))
            honest = max(c["sigma"], c["sigma_jackknife"] or 0.0)
            flagged.append(summary["trusted"] is False)
            largest.append(max(p["ratio"] or 0.0 for p in params if p["core"]))
            z.append(error / c["sigma"])
            z_honest.append(error / honest)
            covered.append(error <= 2 * honest)
        print(f"| {label} | {np.mean(flagged):.0%} | {np.median(largest):.2f} | {np.median(z):.1f} | "
              f"{np.median(z_honest):.1f} | {np.mean(covered):.0%} | {np.median(seconds):.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    t0 = time.perf_counter()
    where_evaluated(args.seeds)
    jackknife_study(args.seeds)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
