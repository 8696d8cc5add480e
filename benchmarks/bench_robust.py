"""Robust adjustment of matcher data on the paper-scale block, side by side with pycolmap (Ceres) (issue 39).

Seed 000's 28-image block (80,000 observations, a lens field of Brown terms and local bumps that no AP family
represents exactly), Type 3 control, ``--ap wavelet:db4 --screen``, made wrong as matchers make it
(:mod:`selfcal.simulate.outliers`: at each rate half the wrong observations are small blunders of 4-15 px, half
wrong matches anywhere in the frame, and a patch of 60 consistently wrong matches in one image). Printed per rate:

* selfcal's tested workflow, robust (the default, ``danish``) and least squares (``--robust none``): check-point
  RMSD XY and Z against the surveyed coordinates and as a ratio to the clean block's, tie points none of whose
  observations was made wrong against the truth (ratio to the clean block's tie points), recall (the wrong observations larger than 4 sigma of determinable points that are out of the final
  adjustment), false rejections (good observations of determinable points that the clean block's workflow kept and
  this one has not), the WAPs kept, seconds;
* "ideal": a perfect cleaning, the least-squares workflow on the block without the wrong observations (what the
  remaining data can give at best);
* pycolmap's bundle adjuster with its Cauchy loss (OPENCV camera: a Brown field, same start values, the GCPs held:
  ``robust_peer.pycolmap_adjust_block``) on the same observations: check-point RMSD;
* the cost: the robust tested workflow on the clean block against today's least-squares one, medians of
  ``--repeat`` runs in this process (after one warm-up run: Numba's one-off set-up is printed beside).

    python benchmarks/bench_robust.py [--seed 1] [--repeat 3] [--rates 0.05,0.1,0.2,0.3] [--no-peer]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from selfcal.allocator import keep_freed_memory  # noqa: E402
from selfcal.adjust import AdjustOptions, APOptions, RobustOptions  # noqa: E402
from selfcal.simulate import simulate_uav  # noqa: E402
from selfcal.simulate.outliers import contaminate  # noqa: E402
from selfcal.stats import ScreeningOptions, SnoopingOptions  # noqa: E402
from selfcal.stats.checks import intersected  # noqa: E402
from selfcal.workflows.tested import adjust_with_tests, prune_for  # noqa: E402


def tested(block, robust):
    t0 = time.perf_counter()
    out = adjust_with_tests(block, AdjustOptions(ap=APOptions("wavelet:db4")), SnoopingOptions(), ScreeningOptions(),
                            robust=robust)
    return out, time.perf_counter() - t0


def tie_rms(result, truth, only: set | None = None) -> tuple[float, float]:
    """RMS of the tie points' errors against the truth, XY and Z (of the points ``only`` if given)."""
    where = {p: k for k, p in enumerate(truth.point_id)}
    points = result.block.points
    tie = np.flatnonzero((points.role == "tie") & (np.isin(points.point_id, list(only)) if only is not None else True))
    d = result.state.points[tie] - truth.xyz[[where[p] for p in points.point_id[tie]]]
    return float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


def detection(block, contamination, out, clean) -> tuple[float, float]:
    """(recall, false) as in the module docstring."""
    obs = block.observations
    wrong = contamination.mask(len(obs))
    final = np.isin(obs.row, out.result.block.observations.row)
    kept_clean = np.isin(obs.row, clean.result.block.observations.row)
    large = np.zeros(len(obs), bool)
    large[contamination.index] = np.hypot(*contamination.displacement_px.T) > 4.0 * obs.sigma_px[contamination.index]
    rays = np.bincount(obs.point_index, minlength=len(block.points))
    bad = np.bincount(obs.point_index, wrong, minlength=len(block.points))
    determinable = ((rays >= 3) & (2 * bad < rays))[obs.point_index]
    return float(np.mean(~final[large & determinable])), float(np.mean(~final[~wrong & determinable & kept_clean]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--rates", default="0.05,0.1,0.2,0.3")
    parser.add_argument("--no-peer", action="store_true", help="leave pycolmap out")
    args = parser.parse_args()
    keep_freed_memory()
    sim = simulate_uav(seed=args.seed)
    block = prune_for(sim.blocks["type3"])
    t0 = time.perf_counter()
    warm, _ = tested(block, RobustOptions())                    # Numba's kernels, the WAP tables: once per process
    print(f"first (cold) robust tested workflow {time.perf_counter() - t0:.2f} s (Numba's one-off set-up included)")
    del warm
    times: dict[str, list[float]] = {"robust": [], "ls": []}
    for _ in range(args.repeat):
        for name, robust in (("ls", None), ("robust", RobustOptions())):
            out, seconds = tested(block, robust)
            times[name].append(seconds)
            if name == "robust":
                clean = out
            else:
                clean_ls = out
            del out
    ratio = np.median(times["robust"]) / np.median(times["ls"])
    print(f"clean block, {len(block.observations)} observations: robust tested workflow {np.median(times['robust']):.2f} s "
          f"({', '.join(f'{t:.2f}' for t in times['robust'])}), least squares {np.median(times['ls']):.2f} s "
          f"({', '.join(f'{t:.2f}' for t in times['ls'])}): ratio {ratio:.2f} (accepted: <= 1.5)")
    checks = intersected(clean.result)
    xy0, z0 = checks.rmsd_xy_m(), checks.rmsd_z_m()
    ls_checks = intersected(clean_ls.result)
    header = (f"{'outliers':>8} {'run':>7} {'chk XY m':>9} {'x clean':>7} {'chk Z m':>8} {'x clean':>7} {'tie XY':>7} "
              f"{'tie Z':>7} {'recall':>7} {'false':>6} {'WAPs':>5} {'s':>6}")
    print(header)
    print(f"{'0 %':>8} {'robust':>7} {xy0:9.4f} {1:7.2f} {z0:8.4f} {1:7.2f} {1:7.2f} {1:7.2f} {'':>7} {'':>6} "
          f"{clean.n_ap_significant:5d} {np.median(times['robust']):6.1f}")
    print(f"{'0 %':>8} {'ls':>7} {ls_checks.rmsd_xy_m():9.4f} {ls_checks.rmsd_xy_m() / xy0:7.2f} "
          f"{ls_checks.rmsd_z_m():8.4f} {ls_checks.rmsd_z_m() / z0:7.2f} {'':>7} {'':>7} {'':>7} {'':>6} "
          f"{clean_ls.n_ap_significant:5d} {np.median(times['ls']):6.1f}")
    peers = []
    for rate in (float(r) for r in args.rates.split(",")):
        wrong_block, contamination = contaminate(block, rate, anywhere_share=0.5, patch=60, seed=args.seed + 6)
        # "ideal": a perfect cleaning, the least-squares workflow on the block without the wrong observations
        keep = np.setdiff1d(np.arange(len(block.observations)), contamination.index)
        ideal = prune_for(replace(block, observations=block.observations.take(keep)))
        # tie points against the truth: those none of whose observations was made wrong (a wrong ray of a two-ray
        # point along its epipolar line is invisible to any adjustment: such points keep its error)
        untouched = set(block.points.point_id.tolist()) - set(
            block.points.point_id[block.observations.point_index[contamination.index]].tolist())
        txy0, tz0 = tie_rms(clean.result, sim.truth, untouched)
        for name, robust, data in (("robust", RobustOptions(), wrong_block), ("ls", None, wrong_block),
                                   ("ideal", None, ideal)):
            try:
                out, seconds = tested(data, robust)
            except Exception as exc:                 # least squares on matcher data: it may not get through
                print(f"{rate:8.0%} {name:>7} failed: {str(exc).splitlines()[0][:90]}")
                continue
            c = intersected(out.result)
            txy, tz = tie_rms(out.result, sim.truth, untouched)
            recall, false = detection(wrong_block, contamination, out, clean) if name != "ideal" else (np.nan, np.nan)
            flag = " FAILED: " + out.failure[:60] if out.failure else ""
            print(f"{rate:8.0%} {name:>7} {c.rmsd_xy_m():9.4f} {c.rmsd_xy_m() / xy0:7.2f} {c.rmsd_z_m():8.4f} "
                  f"{c.rmsd_z_m() / z0:7.2f} {txy / txy0:7.2f} {tz / tz0:7.2f} {recall:7.4f} {false:6.4f} "
                  f"{out.n_ap_significant:5d} {seconds:6.1f}{flag}", flush=True)
            del out
        if not args.no_peer:
            from robust_peer import check_point_rmsd, pycolmap_adjust_block
            peer = pycolmap_adjust_block(prune_for(wrong_block), loss="cauchy")
            peers.append((rate, *check_point_rmsd(wrong_block, peer.chk_xyz), peer.seconds))
    if peers:
        print("pycolmap (Ceres), Cauchy loss, OPENCV camera, GCPs held, same observations and start:")
        for rate, pxy, pz, seconds in peers:
            print(f"{rate:8.0%} {'pycolmap':>8} {pxy:9.4f} {'':>7} {pz:8.4f} {'':>7} {seconds:6.1f} s")


if __name__ == "__main__":
    main()
