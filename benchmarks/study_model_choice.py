"""The AP model chosen by prediction against the best of all candidates at the check points (issue 44 item 1).

On seed 000's simulated block (Type 1: 15 GCP, 24 check points; or another scenario) with lens fields of three
spatial scales and none -- ``brown`` (the whole frame), ``local`` (bumps of a few hundred pixels), ``ripple``
(waves finer than a 9 x 6 grid's cells), optionally ``edge`` (ripples along the border) -- over several seeds:

* every candidate of ``--ap auto`` (the ten families, the wavelets on grids 3x2 ... 15x10) is adjusted on its own
  (no tests: the blocks have no blunders) and its check-point RMSD measured: the oracle is the smallest;
* ``--ap auto`` chooses (:func:`selfcal.workflows.choose_ap_model`, no snooping), and the chosen candidate's own
  adjustment gives its RMSD: the ratio chosen / oracle is the evidence (issue 44: within 1.1);
* for comparison, the smallest BIC of the candidates' own adjustments (the rule before issue 44), the one-SE
  rule with the best one's own standard error instead of the paired one (Breiman's, "breiman"), and the paired rule
  without the practical bound of 0.1 px ("paired").

    python benchmarks/study_model_choice.py [--seeds 10] [--fields none,brown,local,ripple] [--scenario type1]
                                            [--density 3.5]

Prints one line per block (the choices, the ratios) and a summary per field: the mean and the largest ratio, how
often ``none`` was chosen.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np


def _rmsd(result) -> tuple[float, float, float]:
    from selfcal.stats.checks import intersected
    found = intersected(result)
    xy, z = found.rmsd_xy_m(), found.rmsd_z_m()
    return xy, z, float(np.hypot(xy, z))


def block_study(field: str, seed: int, scenario: str, density: float, candidates) -> dict:
    from selfcal.adjust import AdjustOptions, APOptions, adjust
    from selfcal.block import prune
    from selfcal.errors import AdjustmentError
    from selfcal.simulate import simulate_uav
    from selfcal.stats.prediction import simplest_within_one_se
    from selfcal.workflows.model_choice import choose_ap_model

    block = prune(simulate_uav(seed=seed, distortion=field, points_per_mm2=density).blocks[scenario])
    t0 = time.perf_counter()
    choice = choose_ap_model(block, candidates, snooping=None)
    seconds = time.perf_counter() - t0
    own = {}
    for model, grid in candidates:
        label = f"{model}@{grid[0]}x{grid[1]}" if model.startswith("wavelet") else model
        try:
            result = adjust(block, AdjustOptions(ap=APOptions(model, grid=grid)))
        except AdjustmentError as exc:
            print(f"    {label}: {exc}", flush=True)
            continue
        n, k = result.n_observations, result.n_unknowns
        omega = result.variance_factor * (n - k)
        own[label] = (*_rmsd(result), float(n * np.log(omega / n) + k * np.log(n)))
    label_of = {(s.model, s.grid): s.label for s in choice.candidates}
    chosen = label_of[(choice.model, choice.grid)]
    errors, sizes = [s.prediction for s in choice.candidates], [s.n_ap for s in choice.candidates]
    breiman_pick = simplest_within_one_se(errors, sizes, paired=False)
    breiman = choice.candidates[breiman_pick].label if breiman_pick is not None else chosen
    paired_pick = simplest_within_one_se(errors, sizes, min_effect_px=0.0)
    paired = choice.candidates[paired_pick].label if paired_pick is not None else chosen
    by_bic = min(own, key=lambda k: own[k][3])
    oracle = {axis: min(v[axis] for v in own.values()) for axis in range(3)}
    best = min(own, key=lambda k: own[k][2])
    row = {"field": field, "seed": seed, "chosen": chosen, "oracle": best, "bic": by_bic, "breiman": breiman,
           "paired": paired,
           "seconds": seconds, "shortlist": [s.label for s in choice.candidates if s.prediction is not None]}
    for name, label in (("chosen", chosen), ("bic", by_bic), ("breiman", breiman), ("paired", paired)):
        row[f"{name}_ratio"] = own[label][2] / oracle[2]
        row[f"{name}_ratio_xy"] = own[label][0] / oracle[0]
        row[f"{name}_ratio_z"] = own[label][1] / oracle[1]
    print(f"{field:7s} seed {seed:3d}: chosen {chosen:18s} ({row['chosen_ratio']:.3f} of the oracle {best}, XY "
          f"{row['chosen_ratio_xy']:.3f} Z {row['chosen_ratio_z']:.3f}); BIC {by_bic} {row['bic_ratio']:.3f}; "
          f"own-SE rule {breiman} {row['breiman_ratio']:.3f}; paired SE alone {paired} {row['paired_ratio']:.3f}; "
          f"short list {', '.join(row['shortlist'])}; "
          f"choice {seconds:.1f} s", flush=True)
    return row


def summary(rows: list[dict]) -> None:
    print("\nper field: chosen / oracle check-point RMSD (3-D; XY; Z), mean and largest over the seeds")
    for field in dict.fromkeys(r["field"] for r in rows):
        sel = [r for r in rows if r["field"] == field]
        parts = []
        for name in ("chosen", "bic", "breiman", "paired"):
            q = np.array([r[f"{name}_ratio"] for r in sel])
            parts.append(f"{name} {q.mean():.3f} (max {q.max():.3f}, <= 1.1 in {int(np.sum(q <= 1.1))}/{len(q)})")
        none = sum(r["chosen"] == "none" for r in sel)
        xy = np.mean([r["chosen_ratio_xy"] for r in sel])
        z = np.mean([r["chosen_ratio_z"] for r in sel])
        print(f"  {field:7s} {'; '.join(parts)}; chosen XY {xy:.3f} Z {z:.3f}; none chosen {none}/{len(sel)}; "
              f"choice {np.mean([r['seconds'] for r in sel]):.1f} s")


def main(argv: list[str] | None = None) -> int:
    from selfcal.workflows.adjust import ap_candidates
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--fields", default="none,brown,local,ripple")
    parser.add_argument("--scenario", default="type1")
    parser.add_argument("--density", type=float, default=3.5, help="image points per mm^2 (seed 000: 3.5)")
    parser.add_argument("--candidates", default="auto", help="--ap auto[:...] list (default: auto)")
    args = parser.parse_args(argv)
    candidates = ap_candidates(args.candidates, (9, 6))
    rows = []
    for field in args.fields.split(","):
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rows.append(block_study(field, seed, args.scenario, args.density, candidates))
    summary(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
