"""Seed 000's Table 4 on the simulated seed-000 block (issue 44 item 7): the correlation figures of the tested
adjustment (data snooping k = 3, AP screening) for Types 1-4 with ``wavelet:db4`` (9x6) and ``brown``.

Per block and model, four rows (selfcal.stats.correlation): ``max |rho|`` as summary.json's ``max_abs_corr`` gives
it (the APs as estimated); the same in the AP basis orthonormal over the block's observations (the same fit:
tests/test_correlation_figures.py checks it to 1e-9); the canonical correlation of the APs' span with each group
(no AP basis can go below it); and the largest cosine between AP and group columns of the design matrix (an angle
between basis functions at the observations, not a correlation of the estimates). Seed 000 reports < 0.01 for
every WAP group pair (0.03 for the EOPs of ADB4 in Types 1 and 3) and 0.67-0.77 for BINGO's IOP and intra-AP.

    python benchmarks/study_table4.py [--seed 0] [--types type1,type2,type3,type4]
"""
from __future__ import annotations

import argparse
import time

from selfcal import bundle_adjust
from selfcal.simulate import simulate_uav
from selfcal.stats.correlation import GROUPS, correlation_figures

ROWS = (("max_abs_corr", "max |rho| as estimated"), ("max_abs_corr_orthonormal", "max |rho| orthonormal APs"),
        ("canonical_corr", "canonical correlation"), ("design_cosine", "design-column cosine"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--types", default="type1,type2,type3,type4")
    parser.add_argument("--models", default="wavelet:db4,brown")
    args = parser.parse_args()
    sim = simulate_uav(seed=args.seed)
    print(f"{'block':6s} {'model':12s} {'figure':28s} " + " ".join(f"{g:>8s}" for g in GROUPS) + "   APs kept")
    for scenario in args.types.split(","):
        for model in args.models.split(","):
            t0 = time.perf_counter()
            out = bundle_adjust(sim.blocks[scenario], model, screen=True, control_loo=False)
            figures = {"max_abs_corr": out.summary["max_abs_corr"]} | correlation_figures(out.result)
            kept = f"{out.summary['n_ap_significant']}/{out.summary['n_ap_initial']}"
            for key, label in ROWS:
                values = figures[key]
                cells = " ".join(f"{'-':>8s}" if values.get(g) is None else f"{values[g]:8.4f}" for g in GROUPS)
                print(f"{scenario:6s} {model:12s} {label:28s} {cells}   {kept} ({time.perf_counter() - t0:.0f} s)",
                      flush=True)


if __name__ == "__main__":
    main()
