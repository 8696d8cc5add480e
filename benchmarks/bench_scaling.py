"""How selfcal's cost grows with the block: synthetic frame blocks from 28 to 2000 (5000) images.

Blocks of the seed-000 simulator with more strips and longer strips (same overlaps, 0.5 tie
points per mm^2 of image, so points and observations grow with the images), Type 3 control,
no distortion, AP model none. Each block is adjusted in its own process (so that its peak
memory is its own) with the default solver, covariance of every unknown and every tie point
included. Printed per block: images, points, observations, iterations, median seconds per
iteration, total seconds of the adjustment, seconds of the covariance (Q_theta: the dense
inverse or the selected inverse, and the point cofactors), the factorisation path taken, peak
memory; then the growth exponent b of seconds per iteration ~ observations^b and ~ images^b
(least squares in log-log over the blocks of >= 200 images).

``--largest 5000`` adds the 5000-image block (about 8 GB of peak memory was the 2000-image
block's with the dense inverse; the selected inverse needs far less, but the block takes
minutes). ``--dense-covariance`` takes Q_theta from the dense inverse as before the selected
inverse (for the before/after comparison). ``--linalg`` instead times the factorisation and a
solve of the reduced matrix by each path (banded, CHOLMOD, SuperLU) on the strip blocks of
>= 1000 images and on random image graphs (no band) of 1000 and 2000 images.

Run: ``make bench`` or ``python benchmarks/bench_scaling.py [--largest 5000] [--dense-covariance]``.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import selfcal  # noqa: F401  (before NumPy, as on the command line: it sets OpenBLAS's thread timeout)
import numpy as np

#: (strips, images per strip)
BLOCKS = [(4, 7), (6, 17), (10, 20), (14, 36), (20, 50), (40, 50), (50, 100)]


def _block(n_strips: int, per_strip: int):
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=0.5, n_strips=n_strips,
                       images_per_strip=per_strip)
    return prune(sim.blocks["type3"])


def _child(n_strips: int, per_strip: int, dense_covariance: bool) -> dict:
    import selfcal.adjust.result as result_module           # where the adjustment's result makes the points' cofactors
    from selfcal.adjust import AdjustOptions, adjust, linalg

    block = _block(n_strips, per_strip)
    covariance, methods = [0.0], set()

    def timed(function):
        def run(*args, **kwargs):
            t = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                covariance[0] += time.perf_counter() - t
        return run

    # the stage that makes Q_theta (an older selfcal, e.g. PYTHONPATH=<main> for a "before" run, has only inverse)
    stage = "cofactor" if hasattr(linalg.Factor, "cofactor") else "inverse"
    cofactor = linalg.Factor.inverse if dense_covariance else getattr(linalg.Factor, stage)

    def cofactor_noted(self):
        methods.add(getattr(self, "method", "?"))
        return cofactor(self)

    setattr(linalg.Factor, stage, timed(cofactor_noted))
    result_module.point_cofactors = timed(result_module.point_cofactors)
    stamps = []
    t0 = time.perf_counter()
    result = adjust(block, AdjustOptions(), progress=lambda record: stamps.append(time.perf_counter()))
    result.Q_points                   # the points' cofactors are made on first use: inside the adjustment's time
    seconds = time.perf_counter() - t0
    per_iteration = float(np.median(np.diff(stamps))) if len(stamps) > 1 else float("nan")
    sigma_ok = bool(np.all(np.isfinite(result.image_sigma())) and np.all(np.isfinite(result.point_covariance())))
    return {"images": len(block.images), "points": len(block.points), "observations": len(block.observations),
            "iterations": result.iterations, "per_iteration": per_iteration, "seconds": seconds,
            "covariance": covariance[0], "method": ",".join(sorted(methods)), "sigma_ok": sigma_ok,
            "cofactor": type(result.Q_theta).__name__, "converged": result.converged,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def _best(function, repeat: int = 2):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = function()
        times.append(time.perf_counter() - t)
    return min(times), out


def _paths(S, g) -> dict:
    """Seconds of factorisation + one solve of the scaled S by each path (None: path not applicable)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    from sksparse.cholmod import cholesky

    from selfcal.adjust import linalg

    d = 1.0 / np.sqrt(S.diagonal())
    Ss = (sp.diags(d) @ S @ sp.diags(d)).tocsc()
    out = {"n": S.shape[0]}
    band = linalg.band_structure(Ss)
    if band is not None:
        out["width"] = band[2]
        out["banded"] = _best(lambda: linalg._bordered_banded(Ss, band, 1e-13)(g))[0]
    out["cholmod"] = _best(lambda: cholesky(Ss)(g))[0]
    out["superlu"] = _best(lambda: spla.splu(Ss, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                             options={"SymmetricMode": True}).solve(g))[0]
    out["taken"] = linalg.factorise(S).method
    return out


def _linalg_child(kind: str, a: int, b: int) -> dict:
    if kind == "strips":
        from selfcal.adjust import AdjustOptions
        from selfcal.adjust.initial import initial_state
        from selfcal.adjust.schur import linearise, reduce
        from selfcal.adjust.problem import build_problem

        block = _block(a, b)
        options = AdjustOptions()
        problem = build_problem(block, options)
        state, _ = initial_state(problem, block, None)
        S, g, _ = reduce(problem, linearise(problem, state), 0.0, False)
        label = f"strips {a * b}"
    else:
        sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "tests"))
        from test_large_systems import _random_graph_system

        S = _random_graph_system(a)
        g = np.random.default_rng(0).normal(size=S.shape[0])
        label = f"random {a}"
    return {"block": label, **_paths(S, g)}


def _run(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", nargs=2, type=int)
    parser.add_argument("--linalg-child", nargs=3)
    parser.add_argument("--largest", type=int, default=2000, help="largest block in images (default 2000; 5000 adds "
                                                                   "the 5000-image block)")
    parser.add_argument("--dense-covariance", action="store_true", help="Q_theta by the dense inverse (as before)")
    parser.add_argument("--linalg", action="store_true", help="time the factorisation paths instead")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(*args.child, args.dense_covariance)))
        return
    if args.linalg_child:
        kind, a, b = args.linalg_child
        print(json.dumps(_linalg_child(kind, int(a), int(b))))
        return
    print(f"load average at the start: {' '.join(f'{x:.2f}' for x in __import__('os').getloadavg())}")
    if args.linalg:
        print(f"{'system':>14}{'unknowns':>10}{'width':>7}{'banded s':>10}{'CHOLMOD s':>11}{'SuperLU s':>11}  taken")
        jobs = [["strips", str(s), str(p)] for s, p in BLOCKS if 1000 <= s * p <= args.largest]
        jobs += [["random", "1000", "0"], ["random", "2000", "0"]]
        for job in jobs:
            r = _run(["--linalg-child", *job])
            banded = f"{r['banded']:>10.2f}" if "banded" in r else f"{'-':>10}"
            print(f"{r['block']:>14}{r['n']:>10}{r.get('width', '-'):>7}{banded}{r['cholmod']:>11.2f}"
                  f"{r['superlu']:>11.2f}  {r['taken']}", flush=True)
        return
    rows = []
    print(f"{'images':>7}{'points':>9}{'observations':>14}{'iter.':>6}{'s/iter.':>9}{'total s':>9}{'cov. s':>8}"
          f"{'peak MB':>9}  path")
    for strips, per_strip in BLOCKS:
        if strips * per_strip > args.largest:
            continue
        r = _run(["--child", str(strips), str(per_strip)] + (["--dense-covariance"] if args.dense_covariance else []))
        rows.append(r)
        print(f"{r['images']:>7}{r['points']:>9}{r['observations']:>14}{r['iterations']:>6}{r['per_iteration']:>9.3f}"
              f"{r['seconds']:>9.1f}{r['covariance']:>8.2f}{r['peak_mb']:>9.0f}  {r['method']} {r['cofactor']}"
              + ("" if r["converged"] else "  (not converged)") + ("" if r["sigma_ok"] else "  (sigma not finite)"),
              flush=True)
    big = [r for r in rows if r["images"] >= 200]
    if len(big) >= 2:
        span = f"{big[0]['images']} to {big[-1]['images']} images"
        for size in ("observations", "images"):
            x = np.log([r[size] for r in big])
            for key, label in (("per_iteration", "seconds per iteration"), ("seconds", "total seconds")):
                slope = np.polyfit(x, np.log([r[key] for r in big]), 1)[0]
                print(f"growth exponent of {label} vs {size} ({span}): {slope:.2f}")


if __name__ == "__main__":
    main()
