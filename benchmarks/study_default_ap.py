"""The evidence for ``selfcal adjust``'s default AP model (issue 45 item 4): check-point RMSD of the tested workflow
(robust cleaning, data snooping, defaults otherwise) with ``--ap none`` and ``--ap brown``, on simulated blocks
whose lens has no distortion, Brown's distortion, or a local field no AP family represents plus Brown's
(seed 000's block, Type 1: 15 GCP / 24 CHK and Type 3: full control), over several seeds; then the same choice
by BIC between the two (``auto:none,brown``, the default) on each block. The real COPR block's none / brown rows
are examples/copr's (tests/test_readme.py runs its brown adjustment).

    python benchmarks/study_default_ap.py [--seeds 2]

Prints one row per block and model; the ratio brown / none of the check-point RMSD is the evidence: a default
must never cost accuracy on a camera without distortion and must calibrate the cameras that have it.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from selfcal import bundle_adjust
from selfcal.simulate import simulate_uav

MODELS = ("none", "brown", None)        # None: the default (auto:none,brown for these cameras)


def _row(label: str, model: str, summary: dict, seconds: float) -> dict:
    row = {"block": label, "ap": model or "default", "converged": summary.get("converged"),
           "sigma0_px": summary.get("sigma0_px"), "chk_xy_m": summary.get("rmsd_chk_xy_m"),
           "chk_z_m": summary.get("rmsd_chk_z_m"), "gcp_used": summary.get("n_gcp_used"),
           "rejected": summary.get("n_obs_rejected"), "seconds": seconds}
    print(f"{label:28s} {model or 'default':7s} sigma0 {row['sigma0_px'] or float('nan'):7.3f} px  "
          f"CHK XY {row['chk_xy_m'] or float('nan'):7.4f} m  Z {row['chk_z_m'] or float('nan'):7.4f} m  "
          f"GCP used {row['gcp_used']}  rejected {row['rejected']}  ({seconds:.1f} s)", flush=True)
    return row


def simulated(seeds: int) -> list[dict]:
    rows = []
    for distortion in ("none", "brown", "local+brown"):
        for seed in range(seeds):
            sim = simulate_uav(seed=100 + seed, distortion=distortion)
            for scenario in ("type1", "type3"):
                for model in MODELS:
                    t0 = time.perf_counter()
                    outcome = bundle_adjust(sim.blocks[scenario], ap=model)
                    rows.append(_row(f"{distortion} {scenario} seed {100 + seed}", model, outcome.summary,
                                     time.perf_counter() - t0))
    return rows


def ratios(rows: list[dict]) -> None:
    print("\nbrown / none and default / the better of the two, check-point RMSD (median over seeds; max)")
    by = {}
    for r in rows:
        key = " ".join(r["block"].split()[:2])
        by.setdefault(key, {}).setdefault(r["ap"], []).append(r)
    for key, models in by.items():
        for axis in ("chk_xy_m", "chk_z_m"):
            q = np.array([b[axis] / n[axis] for n, b in zip(models["none"], models["brown"])])
            d = np.array([d[axis] / min(n[axis], b[axis])
                          for n, b, d in zip(models["none"], models["brown"], models["default"])])
            print(f"  {key:20s} {axis:9s} brown/none median {np.median(q):6.3f} max {q.max():6.3f}   "
                  f"default/better median {np.median(d):6.3f} max {d.max():6.3f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args(argv)
    rows = simulated(args.seeds)
    ratios(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
