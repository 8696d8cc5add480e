"""Does GNSS/IMU ever hurt? Types 1 -> 2 and 3 -> 4 paired over seeds, at the check and tie points (issue 44 item 6).

Issue 25's study (``study_trajectory.py``) pairs Type 1 -> 2 at the tie points on one lens field with one model.
This one asks it of fields the AP model does *not* represent (``local``: bumps, ``edge``: ripples along the
border, ``ripple``: finer than every grid) as well as of fields it does (``brown`` with ``--ap brown``, ``none``
with ``--ap none``), with a fixed model or the model chosen by cross-validation per block (``--ap auto`` or
``auto:MODEL,...``), unscreened and screened, and by ablation where a loss comes from:

* ``base``: the blocks as simulated (GNSS and IMU, strip-wise shift and drift);
* ``gnss`` / ``imu``: one sensor only;
* ``shift``: strip shifts without drift (``gnss_drift = imu_drift = 0``);
* ``truesigma``: the blocks declare the trajectory noise the simulation drew (not the default declared sigmas);
* ``vc``: variance components of every group (``VarianceOptions``) at the end of the tested adjustment;
* ``tw``: the GNSS and IMU groups' variance components against the images and control, before the tests
  (``adjust_with_tests(trajectory_weights=...)``);

the GNSS/IMU errors are drawn independently of the adjustment's model (``TrajectoryErrors``, as issue 25 and
``study_screening.py``); ``--eq12`` draws them the way Eq. (12) parametrises them instead. Each variant changes
only the trajectory Type (2 or 4); the GCP-only Type (1 or 3) is adjusted once per seed and screening.

    python benchmarks/study_gnss_imu.py [--seeds 3] [--fields local,ripple,edge] [--ap wavelet:db4]
        [--density 1.0] [--pairs 12,34] [--variants base] [--screen both|on|off] [--save JSON]

Prints one line per block and per field, pair, screening and variant the paired change of the mean RMSD
(Type 2 / Type 1 - 1, %) at the check points and the tie points in XY and Z, and the worst seed.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

import numpy as np

PAIRS = {"12": ("type1", "type2"), "34": ("type3", "type4")}
VARIANTS = ("base", "gnss", "imu", "shift", "truesigma", "vc", "tw")
METRICS = ("chk_xy", "chk_z", "tie_xy", "tie_z")


def _metrics(sim, result) -> tuple[float, float, float, float]:
    from selfcal.stats.checks import intersected
    found = intersected(result)
    lookup = {p: i for i, p in enumerate(sim.truth.point_id)}
    points = result.block.points
    tie = np.flatnonzero(points.role == "tie")
    d = result.state.points[tie] - sim.truth.xyz[[lookup[p] for p in points.point_id[tie]]]
    return (found.rmsd_xy_m(), found.rmsd_z_m(), float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))),
            float(np.sqrt(np.mean(d[:, 2] ** 2))))


def _variant_block(block, variant: str, errors):
    if variant == "gnss":
        return replace(block, imu_sigma_deg=None)
    if variant == "imu":
        return replace(block, gnss_sigma_m=None)
    if variant == "truesigma":
        return replace(block, gnss_sigma_m=tuple(errors.gnss_noise_m), imu_sigma_deg=tuple(errors.imu_noise_deg))
    return block


def _model(block, ap: str, options):
    """The AP model of a block: ``ap`` itself, or the one chosen by cross-validation (``auto...``)."""
    if not ap.startswith("auto"):
        return ap, options.ap.grid
    from selfcal.workflows.adjust import ap_candidates
    from selfcal.workflows.model_choice import choose_ap_model
    choice = choose_ap_model(block, ap_candidates(ap, options.ap.grid), options)
    return choice.model, choice.grid


def run(field: str, seed: int, ap: str, density: float, pairs, variants, screens, eq12: bool) -> list[dict]:
    from selfcal.adjust import AdjustOptions, APOptions, TrajectoryOptions
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav
    from selfcal.simulate.trajectory import TrajectoryErrors
    from selfcal.stats.screening import ScreeningOptions
    from selfcal.stats.variance import VarianceOptions
    from selfcal.workflows.tested import adjust_with_tests

    errors = TrajectoryErrors()
    sim = simulate_uav(seed=seed, distortion=field, points_per_mm2=density, exposure_interval_s=2.0,
                       trajectory_errors=None if eq12 else errors)
    base = AdjustOptions(ap=APOptions("none"))
    rows = []
    for key in pairs:
        for scenario in PAIRS[key]:
            block = prune(sim.blocks[scenario])
            model, grid = _model(block, ap, base)
            for screen in screens:
                for variant in (("base",) if scenario in ("type1", "type3") else variants):
                    b = _variant_block(block, variant, errors)
                    options = replace(base, ap=APOptions(model, grid=grid))
                    if variant == "shift":
                        options = replace(options, trajectory=TrajectoryOptions(gnss_drift=0, imu_drift=0))
                    t0 = time.perf_counter()
                    tested = adjust_with_tests(b, options, screening=ScreeningOptions() if screen else None,
                                               variance=VarianceOptions() if variant == "vc" else None,
                                               trajectory_weights=VarianceOptions() if variant == "tw" else None)
                    m = _metrics(sim, tested.result)
                    row = {"field": field, "seed": seed, "type": scenario, "screen": screen, "variant": variant,
                           "model": f"{model}@{grid[0]}x{grid[1]}" if model.startswith("wavelet") else model,
                           **dict(zip(METRICS, m)), "seconds": time.perf_counter() - t0}
                    for found in (tested.variance_components, tested.trajectory_weights):
                        if found:
                            row["scales"] = {c.group: round(c.scale, 3) for c in found if c.estimated}
                    rows.append(row)
                    print(f"{field:11s} seed {seed:3d} {scenario} {'scr' if screen else 'uns'} {variant:9s} "
                          f"{row['model']:>14s} chk {m[0]:.4f} {m[1]:.4f} tie {m[2]:.4f} {m[3]:.4f} m "
                          f"{row['seconds']:.0f} s {row.get('scales', '')}", flush=True)
    return rows


def summary(rows: list[dict]) -> None:
    print("\npaired change of the mean RMSD, GNSS/IMU type against GCP-only type (%), worst seed in brackets")
    print(f"{'field':11s} {'pair':7s} {'screen':6s} {'variant':9s} {'seeds':>5s}" + "".join(f"{m:>17s}" for m in METRICS))
    keys = dict.fromkeys((r["field"], r["type"], r["screen"], r["variant"]) for r in rows
                         if r["type"] in ("type2", "type4"))
    for field, scenario, screen, variant in keys:
        ref_type = "type1" if scenario == "type2" else "type3"
        mine = {r["seed"]: r for r in rows if (r["field"], r["type"], r["screen"], r["variant"])
                == (field, scenario, screen, variant)}
        ref = {r["seed"]: r for r in rows if (r["field"], r["type"], r["screen"]) == (field, ref_type, screen)}
        seeds = sorted(set(mine) & set(ref))
        cells = []
        for m in METRICS:
            a = np.array([ref[s][m] for s in seeds])
            b = np.array([mine[s][m] for s in seeds])
            cells.append(f"{100 * (b.mean() / a.mean() - 1):+7.2f} ({100 * (b / a - 1).max():+6.2f})")
        print(f"{field:11s} {ref_type[-1]}->{scenario[-1]:5s} {'on' if screen else 'off':6s} {variant:9s} "
              f"{len(seeds):5d}" + "".join(f"{c:>17s}" for c in cells))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--fields", default="local,ripple,edge")
    parser.add_argument("--ap", default="wavelet:db4", help="a model, or auto / auto:MODEL,... (chosen per block)")
    parser.add_argument("--density", type=float, default=1.0, help="image points per mm^2 (seed 000: 3.5)")
    parser.add_argument("--pairs", default="12,34")
    parser.add_argument("--variants", default="base", help=f"comma-separated of {', '.join(VARIANTS)}")
    parser.add_argument("--screen", choices=("both", "on", "off"), default="both")
    parser.add_argument("--eq12", action="store_true", help="trajectory errors as Eq. (12) parametrises them")
    parser.add_argument("--save", metavar="JSON")
    args = parser.parse_args(argv)
    screens = {"both": (False, True), "on": (True,), "off": (False,)}[args.screen]
    variants = tuple(args.variants.split(","))
    rows: list[dict] = []
    for field in args.fields.split(","):
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rows += run(field, seed, args.ap, args.density, args.pairs.split(","), variants, screens, args.eq12)
            if args.save:
                with open(args.save, "w", encoding="utf-8") as f:
                    json.dump(rows, f)
    summary(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
