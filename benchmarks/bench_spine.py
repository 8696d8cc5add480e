"""selfcal's engine against SciPy's least_squares on the seed-000 Type 3 block.

Both solve the same weighted least-squares problem (collinearity with free
principal distance and principal point, ground control weighted) from the same
start (selfcal's initial values). SciPy gets the analytic sparse Jacobian, its
best case ('trf' with the LSMR trust-region solver, x_scale='jac'). Each run
is its own process, so its peak memory is its own.

Two meanings of "the same final cost" are measured:

* converged: both iterate to their own convergence. SciPy's default LSMR
  tolerances stall about 1e-5 above the optimum, so it gets tight ones
  (atol = btol = 1e-12), with which it reaches selfcal's cost to 1e-12;
* within 0.1 %: the wall time until each first reaches selfcal's final cost
  + 0.1 % (SciPy with its default LSMR tolerances, stopped by a callback).

Run: ``make bench`` or ``python benchmarks/bench_spine.py [--seed N] [--density D] [--images 28|200|1000]``.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np
import scipy.sparse as sp


#: --images -> (strips, images per strip) of the simulator
BLOCKS = {28: (4, 7), 200: (10, 20), 1000: (20, 50)}


def _problem(seed: int, density: float):
    from selfcal.adjust.initial import initial_state
    from selfcal.adjust.problem import build_problem
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    images = int(sys.argv[sys.argv.index("--images") + 1]) if "--images" in sys.argv else 28
    strips, per_strip = BLOCKS[images]
    sim = simulate_uav(seed=seed, distortion="none", points_per_mm2=density, n_strips=strips,
                       images_per_strip=per_strip)
    block = prune(sim.blocks["type3"])
    problem = build_problem(block)
    state, _ = initial_state(problem, block)
    return block, problem, state


def run_selfcal(seed: int, density: float) -> dict:
    from selfcal.adjust.schur import evaluate_cost
    from selfcal.adjust.solver import solve

    block, problem, state = _problem(seed, density)
    names = problem.theta_names(block.images.image_id)
    stamps = []
    t0 = time.perf_counter()
    outcome = solve(problem, state, names, progress=lambda rec: stamps.append((time.perf_counter() - t0, rec.cost)))
    seconds = time.perf_counter() - t0
    cost = evaluate_cost(problem, outcome.state)
    within = next(t for t, c in stamps if c <= cost * 1.001)
    return {"seconds": seconds, "iterations": outcome.iterations, "cost": cost, "seconds_to_0.1%": within,
            "n_observations": problem.n_observations(), "n_unknowns": problem.n_unknowns()}


def run_scipy(seed: int, density: float) -> dict:
    from scipy.optimize import least_squares

    from selfcal.adjust.schur import evaluate_cost
    from selfcal.geometry.rotation import matrix_from_opk_with_derivatives
    from selfcal.sensors.frame import project_with_jacobians

    block, problem, state = _problem(seed, density)
    n_img, n_pts, m = problem.n_images, problem.n_points, problem.n_image_observations
    img, pt = problem.obs_image, problem.obs_point
    w = 1.0 / problem.obs_sigma[:, 0]
    control_sigma = 1.0 / np.einsum("nii->ni", problem.control_weight)      # the simulated control weights are diagonal
    ctl = problem.control_index
    n_x = 6 * n_img + 3 + 3 * n_pts

    def unpack(x):
        return x[:6 * n_img].reshape(-1, 6), x[6 * n_img:6 * n_img + 3], x[6 * n_img + 3:].reshape(-1, 3)

    def fun(x):
        eop, iop, pts = unpack(x)
        rot = matrix_from_opk_with_derivatives(eop[:, 3:])
        xy, *_ = project_with_jacobians(pts[pt], eop[img], np.broadcast_to(iop, (m, 3)),
                                        rotation=(rot[0][img], rot[1][img]))
        r_img = ((xy - problem.obs_value) * w[:, None]).ravel()
        r_ctl = ((pts[ctl] - problem.control_xyz) / control_sigma).ravel()
        return np.concatenate([r_img, r_ctl])

    rows_img = np.repeat(np.arange(2 * m), 12)
    def jac(x):
        eop, iop, pts = unpack(x)
        rot = matrix_from_opk_with_derivatives(eop[:, 3:])
        _, j_e, j_p, j_i = project_with_jacobians(pts[pt], eop[img], np.broadcast_to(iop, (m, 3)),
                                                  rotation=(rot[0][img], rot[1][img]))
        cols = np.concatenate([6 * img[:, None] + np.arange(6), np.broadcast_to(6 * n_img + np.arange(3), (m, 3)),
                               6 * n_img + 3 + 3 * pt[:, None] + np.arange(3)], axis=1)
        vals = np.concatenate([j_e, j_i, j_p], axis=2) * w[:, None, None]
        J_img = sp.csr_matrix((vals.ravel(), (rows_img, np.repeat(cols, 2, axis=0).ravel())), shape=(2 * m, n_x))
        rc = np.arange(3 * len(ctl))
        cc = (6 * n_img + 3 + 3 * ctl[:, None] + np.arange(3)).ravel()
        J_ctl = sp.csr_matrix(((1.0 / control_sigma).ravel(), (rc, cc)), shape=(3 * len(ctl), n_x))
        return sp.vstack([J_img, J_ctl]).tocsr()

    x0 = np.concatenate([state.image.ravel(), state.cameras[0][:3], state.points.ravel()])
    target = json.loads(sys.argv[sys.argv.index("--target") + 1]) if "--target" in sys.argv else None
    t0 = time.perf_counter()
    tight = "--tight" in sys.argv
    result = least_squares(fun, x0, jac=jac, method="trf", tr_solver="lsmr", x_scale="jac",
                           ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=200,
                           tr_options={"atol": 1e-12, "btol": 1e-12} if tight else {},
                           callback=None if target is None else _stopper(target))
    seconds = time.perf_counter() - t0
    eop, iop, pts = unpack(result.x)
    state.image[:], state.cameras[0][:3], state.points[:] = eop, iop, pts
    return {"seconds": seconds, "iterations": int(result.nfev), "cost": evaluate_cost(problem, state),
            "status": result.message}


def _stopper(target_cost: float):
    """Stop SciPy once it reaches selfcal's cost within 0.1 % (so it is not charged for polishing)."""
    def callback(intermediate_result):
        if intermediate_result.cost <= target_cost * 1.001:
            raise StopIteration
    return callback


def _child(which: str, seed: int, density: float, target: float | None, tight: bool = False,
           images: int = 28) -> dict:
    argv = [sys.executable, __file__, "--child", which, "--seed", str(seed), "--density", str(density),
            "--images", str(images)]
    if target is not None:
        argv += ["--target", json.dumps(target)]
    if tight:
        argv += ["--tight"]
    out = subprocess.run(argv, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--density", type=float, default=3.5, help="image points per mm^2 (paper: 3.2-3.9)")
    parser.add_argument("--child", choices=["selfcal", "scipy"])
    parser.add_argument("--target")
    parser.add_argument("--tight", action="store_true")
    parser.add_argument("--images", type=int, default=28, choices=sorted(BLOCKS),
                        help="block size: 28 (the paper's), 200 or 1000 images (Type 3 control)")
    args = parser.parse_args()
    if args.child:
        out = run_selfcal(args.seed, args.density) if args.child == "selfcal" else run_scipy(args.seed, args.density)
        out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(json.dumps(out))
        return
    ours = _child("selfcal", args.seed, args.density, None, images=args.images)
    converged = _child("scipy", args.seed, args.density, None, tight=True, images=args.images)
    stopped = _child("scipy", args.seed, args.density, ours["cost"], images=args.images)
    print(f"seed-000 Type 3 geometry, {args.images} images: {ours['n_observations']} observations, "
          f"{ours['n_unknowns']} unknowns")
    print(f"{'solver':<44}{'seconds':>9}{'evals':>7}{'final cost':>16}{'peak MB':>9}")
    rows = (("selfcal (Schur complement + Cholesky)", ours),
            ("scipy trf/LSMR tight, to convergence", converged),
            ("scipy trf/LSMR default, stopped at +0.1 %", stopped))
    for name, r in rows:
        print(f"{name:<44}{r['seconds']:>9.2f}{r['iterations']:>7d}{r['cost']:>16.6f}{r['peak_rss_mb']:>9.0f}")
    print(f"converged:   scipy/selfcal time {converged['seconds'] / ours['seconds']:5.1f}x   "
          f"cost ratio {converged['cost'] / ours['cost']:.12f}")
    print(f"within 0.1%: scipy/selfcal time {stopped['seconds'] / ours['seconds_to_0.1%']:5.1f}x   "
          f"(selfcal {ours['seconds_to_0.1%']:.2f} s, scipy {stopped['seconds']:.2f} s)")


if __name__ == "__main__":
    main()
