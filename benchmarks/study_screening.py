"""Screening against not screening at the check points (issue 44 item 2), Types 1-4 of seed 000's block.

For each lens field, seed and control scenario, the tested workflow (robust cleaning off: the blocks have no
blunders; data snooping on) with wavelet APs, three ways:

* unscreened;
* screened as before issue 44 (t-tests, correlations, joint F-guard only: ``--min-effect-px 0 --min-support 0
  --no-screen-cv``);
* screened without the interior orientation's guard (the practical significance of 0.1 px, the support of 20
  observations, and the cross-validation guard: ``--max-iop-move 0``);
* screened as now (plus the guard: no AP drop that moves c, x0 or y0 by more than 0.1 of its sigma).

The trajectory of Types 2 and 4 carries GNSS/IMU errors drawn independently of the adjustment's shift/drift model
(:class:`selfcal.simulate.trajectory.TrajectoryErrors`), as in the issue's measurement.

    python benchmarks/study_screening.py [--seeds 5] [--fields local+brown,ripple] [--ap wavelet:db4]
                                         [--density 1.0]

Prints one line per block and the mean over seeds per field and type of the check-point RMSD (XY, Z) of each
variant against the unscreened one: issue 44 asks for screened <= unscreened.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

VARIANTS = ("unscreened", "before", "unguarded", "now")


def _rmsd(tested) -> tuple[float, float]:
    from selfcal.stats.checks import intersected
    found = intersected(tested.result)
    return found.rmsd_xy_m(), found.rmsd_z_m()


def run(field: str, seed: int, ap: str, density: float, variants: tuple = VARIANTS) -> list[dict]:
    from selfcal.adjust import AdjustOptions, APOptions
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav
    from selfcal.simulate.trajectory import TrajectoryErrors
    from selfcal.stats.screening import ScreeningOptions
    from selfcal.workflows.tested import adjust_with_tests

    sim = simulate_uav(seed=seed, distortion=field, points_per_mm2=density, trajectory_errors=TrajectoryErrors(),
                       exposure_interval_s=2.0)
    screenings = {"unscreened": None,
                  "before": ScreeningOptions(min_effect_px=0.0, min_support=0, cross_validate=False,
                                             max_iop_move_sigma=0.0),
                  "unguarded": ScreeningOptions(max_iop_move_sigma=0.0),
                  "now": ScreeningOptions()}
    rows = []
    for scenario in ("type1", "type2", "type3", "type4"):
        block = prune(sim.blocks[scenario])
        row: dict = {"field": field, "seed": seed, "type": scenario}
        for name in variants:
            screening = screenings[name]
            t0 = time.perf_counter()
            tested = adjust_with_tests(block, AdjustOptions(ap=APOptions(ap)), screening=screening)
            row[name] = (*_rmsd(tested), tested.n_ap_significant, time.perf_counter() - t0)
        rows.append(row)
        runs = [row[v] for v in variants]
        print(f"{field:11s} seed {seed:3d} {scenario}: XY {' / '.join(f'{r[0]:.4f}' for r in runs)} m, Z "
              f"{' / '.join(f'{r[1]:.4f}' for r in runs)} m ({' / '.join(variants)}), APs "
              f"{' / '.join(str(r[2]) for r in runs)}, {' / '.join(f'{r[3]:.0f}' for r in runs)} s", flush=True)
    return rows


def summary(rows: list[dict], variants: tuple = VARIANTS) -> None:
    print("\nmean over seeds of the check-point RMSD against the unscreened one (ratio of the means)")
    for field in dict.fromkeys(r["field"] for r in rows):
        for scenario in ("type1", "type2", "type3", "type4"):
            sel = [r for r in rows if r["field"] == field and r["type"] == scenario]
            mean = {v: np.mean([r[v][:2] for r in sel], axis=0) for v in variants}
            ratios = "; ".join(f"{v} XY {mean[v][0] / mean['unscreened'][0]:.3f} Z {mean[v][1] / mean['unscreened'][1]:.3f}"
                               for v in variants if v != "unscreened")
            print(f"  {field:11s} {scenario}: {ratios} "
                  f"({len(sel)} seeds; unscreened XY {mean['unscreened'][0]:.4f} Z {mean['unscreened'][1]:.4f} m)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--fields", default="local+brown,ripple")
    parser.add_argument("--ap", default="wavelet:db4")
    parser.add_argument("--density", type=float, default=1.0, help="image points per mm^2 (seed 000: 3.5)")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"which of {', '.join(VARIANTS)} to run (unscreened always)")
    args = parser.parse_args(argv)
    variants = tuple(v for v in VARIANTS if v == "unscreened" or v in args.variants.split(","))
    rows = []
    for field in args.fields.split(","):
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rows += run(field, seed, args.ap, args.density, variants)
    summary(rows, variants)
    return 0


if __name__ == "__main__":
    sys.exit(main())
