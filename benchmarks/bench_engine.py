"""selfcal's engine against Ceres (pycolmap, pyceres) and SciPy on Bundle Adjustment in the Large.

The BAL problem ../shared/data/bal/problem-49-7776-pre.txt (49 cameras, 7,776 points,
31,843 observations; camera = rotation vector, translation, f, k1, k2) is solved from
the file's values by

* selfcal: ``selfcal import bal`` block, free network (Gauss-Newton / Levenberg-
  Marquardt on the Schur complement, analytic Jacobians);
* pycolmap: ``pycolmap.bundle_adjustment`` (Ceres, COLMAP's solver choice) on the same
  problem written as a COLMAP model: camera RADIAL (f, cx = cy = 0, k1, k2), pose
  turned by 180 deg about x (COLMAP looks along +z, BAL along -z), y observed negated;
  principal point fixed. The cost is the same function;
* the command line: ``selfcal import bal`` then ``selfcal adjust --no-report`` with ``--snoop 0`` and with the
  default snooping; the seconds its summary.json reports;
* SciPy: ``least_squares`` ('trf', LSMR, ``x_scale="jac"``), the Jacobian by finite differences
  on the known sparsity (SciPy groups the columns), stopped when its cost is within 0.1 % of
  selfcal's final cost, or after 30 times selfcal's wall time (then the ratio is a lower bound:
  its trust region creeps for many minutes short of that cost).

pyceres is not in the table: pycolmap 4.2's ReprojErrorCost takes the pose as one 7-parameter
block (quaternion + translation), which needs a product manifold that pyceres 2.6 does not expose
to Python; pycolmap's bundle adjuster is Ceres through the same library.

Cheirality and undetermined points: 31 observations of the file (10 points) lie behind their camera at
the start. BAL's formula p = -P/P_z still gives them a residual (SciPy minimises it); COLMAP's cost function
gives a point behind the camera a zero residual. selfcal, as a free network, leaves those observations out
(and the points they leave with one ray), and leaves out the points that their rays do not determine
(sigma with the orientations held above 100x the median: 71 of them), which would otherwise drift along
their rays for as long as a solver iterates. pycolmap is therefore run twice: on the whole file (its
cost includes the drifting points) and on exactly the observations selfcal kept, from the same start
(``pycolmap-kept``): the same function, to compare final costs and times.

Each runs in its own process. Printed: wall time to convergence, iterations, final cost
(1/2 sum of squared pixel residuals), peak memory, the time each first reached the best
final cost + 0.1 %, and the ratios selfcal/peer.

Run: ``make bench`` or ``python benchmarks/bench_engine.py [--skip-scipy]``.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import selfcal  # noqa: F401  (before NumPy, as on the command line: it sets OpenBLAS's thread timeout)
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from robust_peer import frame_colmap_model, write_points3d  # noqa: E402  (the COLMAP text model, written once)

BAL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "bal",
                   "problem-49-7776-pre.txt")


#: SciPy is stopped after this many times selfcal's wall time if it has not reached selfcal's cost + 0.1 %
SCIPY_BUDGET_RATIO = 30.0
SCIPY_BUDGET_S = 600.0


def _problem():
    from selfcal.io.bal import read_bal
    return read_bal(BAL)


def project(points: np.ndarray, params: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """BAL's projection as its page states it, written here apart from selfcal's kernel to referee the costs:
    pixel = f (1 + k1 |p|^2 + k2 |p|^4) p, p = -P_xy / P_z, P = R(r) X + t, per observation ([r, t] (n, 6),
    [f, k1, k2] (n, 3))."""
    from selfcal.geometry.rotation import matrix_from_rotation_vector
    P = np.einsum("nij,nj->ni", matrix_from_rotation_vector(params[:, :3]), points) + params[:, 3:]
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1)
    d = 1.0 + camera[:, 1] * r2 + camera[:, 2] * r2 * r2
    return camera[:, 0:1] * d[:, None] * p


def bal_cost(problem, cameras: np.ndarray, points: np.ndarray) -> float:
    """1/2 sum of squared residuals with BAL's own projection."""
    cam = cameras[problem.obs_camera]
    predicted = project(points[problem.obs_point], cam[:, :6], cam[:, 6:9])
    return 0.5 * float(np.sum((predicted - problem.obs_xy) ** 2))


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_selfcal(target: float | None) -> dict:
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.adjust.residuals.image import image_residuals
    from selfcal.convert import block_from_bal

    block = block_from_bal(_problem())
    t0 = time.perf_counter()
    first = [None]
    last = [0.0]

    def progress(record):
        last[0] = time.perf_counter() - t0
        if target is not None and first[0] is None and record.accepted and record.cost <= target:
            first[0] = last[0]

    result = adjust(block, AdjustOptions(), progress=progress)
    result.Q_points                   # the covariance of every unknown: the points' cofactors are made on first use
    seconds = time.perf_counter() - t0
    behind = _behind(result.problem, result.state)
    v = image_residuals(result.problem, result.state)
    dropped = result.block.dropped
    return {"seconds": seconds, "solve_seconds": last[0], "iterations": result.iterations, "cost": result.cost,
            "to_target": first[0],
            "converged": result.converged, "peak_mb": _peak_mb(), "n_behind": int(behind.sum()),
            "cost_in_front": result.cost - 0.5 * float(np.sum(v[behind] ** 2)),
            "left_out_behind": dropped.observations_behind_camera, "left_out_points": dropped.points_undetermined,
            "rows": result.block.observations.row.tolist()}


def _behind(problem, state) -> np.ndarray:
    """Observations whose point lies behind the camera (BAL: P_z > 0), in the problem's order."""
    from selfcal.sensors.bal import behind_camera
    return behind_camera(state.points[problem.obs_point], state.image[problem.obs_image])


def _colmap_model(problem, folder: str) -> None:
    """The BAL problem as a COLMAP text model (RADIAL cameras, one per image)."""
    from selfcal.geometry.rotation import matrix_from_rotation_vector
    from scipy.spatial.transform import Rotation

    flip = np.diag([1.0, -1.0, -1.0])
    R = flip @ matrix_from_rotation_vector(problem.cameras[:, :3])
    t = (problem.cameras[:, 3:6] @ flip.T).tolist()
    q = Rotation.from_matrix(R).as_quat().tolist()                 # x, y, z, w
    cameras, xy, points = problem.cameras.tolist(), problem.obs_xy.tolist(), problem.points.tolist()
    with open(os.path.join(folder, "cameras.txt"), "w") as f:
        for k, c in enumerate(cameras):
            f.write(f"{k + 1} RADIAL 2000 2000 {c[6]!r} 0 0 {c[7]!r} {c[8]!r}\n")
    with open(os.path.join(folder, "images.txt"), "w") as f:
        for k in range(len(problem.cameras)):
            sel = np.flatnonzero(problem.obs_camera == k)
            f.write(f"{k + 1} {q[k][3]!r} {q[k][0]!r} {q[k][1]!r} {q[k][2]!r} {t[k][0]!r} {t[k][1]!r} {t[k][2]!r} "
                    f"{k + 1} img{k}\n")
            f.write(" ".join(f"{xy[i][0]!r} {-xy[i][1]!r} {problem.obs_point[i] + 1}"
                             for i in sel) + "\n")
    track: dict[int, list[str]] = {}
    for k in range(len(problem.cameras)):
        for j, i in enumerate(np.flatnonzero(problem.obs_camera == k)):
            track.setdefault(int(problem.obs_point[i]), []).append(f"{k + 1} {j}")
    write_points3d(folder, points, track)


def _colmap_cost(reconstruction) -> float:
    return _colmap_cost_and_behind(reconstruction)[0]


def _colmap_cost_and_behind(reconstruction) -> tuple[float, int]:
    """1/2 sum of squared pixel residuals, and the number of observations whose point projects to NaN (behind its
    camera: COLMAP's cost gives it a zero residual, and so does this sum)."""
    squares, behind = 0.0, 0
    for image in reconstruction.images.values():
        points = [(p.xy, reconstruction.points3D[p.point3D_id].xyz) for p in image.points2D if p.has_point3D()]
        xy = np.array([a for a, _ in points])
        xyz = np.array([b for _, b in points])
        projected = image.camera.img_from_cam(image.cam_from_world() * xyz)
        squares += float(np.nansum((projected - xy) ** 2))
        behind += int(np.sum(np.isnan(projected).any(axis=1)))
    return 0.5 * squares, behind


def _kept(problem, rows):
    """The problem with only the observations ``rows`` (and the points they see)."""
    from selfcal.io.bal import BalProblem

    rows = np.asarray(rows, np.int64)
    points = np.unique(problem.obs_point[rows])
    new = np.full(len(problem.points), -1)
    new[points] = np.arange(len(points))
    return BalProblem(problem.cameras, problem.points[points], problem.obs_camera[rows], new[problem.obs_point[rows]],
                      problem.obs_xy[rows])


def run_pycolmap(target: float | None, rows_file: str | None = None) -> dict:
    import pycolmap

    problem = _problem()
    if rows_file is not None:
        with open(rows_file) as handle:
            problem = _kept(problem, json.load(handle))
    with tempfile.TemporaryDirectory() as folder:
        _colmap_model(problem, folder)
        reconstruction = pycolmap.Reconstruction(folder)
    seconds = _pycolmap_adjust(reconstruction, refine_principal_point=False)
    cost, behind = _colmap_cost_and_behind(reconstruction)
    return {"seconds": seconds, "iterations": 0, "cost": cost, "behind": behind, "to_target": None,
            "converged": True, "peak_mb": _peak_mb()}


def _pycolmap_adjust(reconstruction, refine_principal_point: bool) -> float:
    """pycolmap's bundle adjustment (Ceres; squared loss, focal length and distortion refined) to
    Ceres's convergence; returns the seconds. (pycolmap 4.2 returns no summary: iterations unknown.)"""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_principal_point = refine_principal_point
    options.ceres.solver_options.max_num_iterations = 200
    options.ceres.solver_options.function_tolerance = 1e-9
    t0 = time.perf_counter()
    pycolmap.bundle_adjustment(reconstruction, options)
    return time.perf_counter() - t0


def run_scipy(target: float | None, budget_s: float = SCIPY_BUDGET_S) -> dict:
    import scipy.sparse as sp
    from scipy.optimize import least_squares

    problem = _problem()
    n_cam, n_pt = len(problem.cameras), len(problem.points)
    m = len(problem.obs_xy)

    def unpack(x):
        return x[:9 * n_cam].reshape(n_cam, 9), x[9 * n_cam:].reshape(n_pt, 3)

    def fun(x):
        cameras, points = unpack(x)
        cam = cameras[problem.obs_camera]
        return (project(points[problem.obs_point], cam[:, :6], cam[:, 6:9]) - problem.obs_xy).ravel()

    # sparsity: each residual pair depends on its camera's 9 and its point's 3 parameters
    rows = np.repeat(np.arange(2 * m), 12)
    cols = np.concatenate([
        (9 * problem.obs_camera[:, None] + np.arange(9)), (9 * n_cam + 3 * problem.obs_point[:, None] + np.arange(3))],
        axis=1)
    cols = np.repeat(cols, 2, axis=0).ravel()
    sparsity = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(2 * m, 9 * n_cam + 3 * n_pt))
    x0 = np.concatenate([problem.cameras.ravel(), problem.points.ravel()])
    t0 = time.perf_counter()
    first = [None]

    def callback(intermediate_result):
        if target is not None and first[0] is None and intermediate_result.cost <= target:
            first[0] = time.perf_counter() - t0
            raise StopIteration
        if time.perf_counter() - t0 > budget_s:
            raise StopIteration

    fit = least_squares(fun, x0, jac_sparsity=sparsity, method="trf", x_scale="jac", tr_solver="lsmr",
                        ftol=1e-10, xtol=1e-10, gtol=1e-10, callback=callback)   # the callback stops it
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "iterations": int(fit.nfev), "cost": float(fit.cost), "to_target": first[0],
            "converged": first[0] is not None, "peak_mb": _peak_mb()}


# --- synthetic frame blocks -------------------------------------------------------------------------

#: images -> (strips, images per strip) of selfcal.simulate.simulate_uav
SYNTHETIC = {28: (4, 7), 200: (10, 20), 1000: (20, 50)}


def _synthetic_block(images: int):
    """A free-network frame block with its start: Type 3 geometry, points as tie points at their
    intersected start values, orientation from images.csv (approximate), c, x0, y0 free, no APs."""
    from dataclasses import replace
    from selfcal.adjust.initial import initial_state
    from selfcal.adjust.problem import build_problem
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    strips, per_strip = SYNTHETIC[images]
    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=0.5, n_strips=strips, images_per_strip=per_strip)
    block = prune(sim.blocks["type3"])
    state, _ = initial_state(build_problem(block), block)
    points = replace(block.points, role=np.full(len(block.points), "tie", dtype=object), xyz_m=state.points,
                     sigma_m=np.full_like(state.points, np.nan))
    images = replace(block.images, position_m=state.image[:, :3], attitude_rad=state.image[:, 3:])
    return replace(block, points=points, images=images, datum="free")


def run_selfcal_frame(images: int) -> dict:
    """selfcal's solve (to its last iteration: Ceres computes no covariance) and, where it can, the
    whole adjustment with the covariance (free networks: up to 6000 orientation unknowns)."""
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.errors import AdjustmentError

    block = _synthetic_block(images)
    runs = []
    for _ in range(2):          # the first in the process, then again (warm: Numba's kernels loaded)
        records = []
        t0 = time.perf_counter()
        try:
            adjust(block, AdjustOptions(),
                   progress=lambda record: records.append((time.perf_counter(), record))).Q_points
            total = time.perf_counter() - t0
        except AdjustmentError:
            total = float("nan")
        runs.append((records[-1][0] - t0, total, records[-1][1]))
    (first, total, last), (warm, _, _) = runs
    weight = block.image_sigma_px ** 2                         # selfcal's cost is in units of sigma
    return {"seconds": first, "warm_seconds": warm, "total_seconds": total, "iterations": last.iteration,
            "cost": last.cost * weight, "converged": True, "peak_mb": _peak_mb(),
            "observations": len(block.observations)}


def run_pycolmap_frame(images: int) -> dict:
    import pycolmap

    block = _synthetic_block(images)
    with tempfile.TemporaryDirectory() as folder:
        frame_colmap_model(block, folder)          # SIMPLE_PINHOLE at the block's nominal camera
        reconstruction = pycolmap.Reconstruction(folder)
    seconds = _pycolmap_adjust(reconstruction, refine_principal_point=True)
    return {"seconds": seconds, "iterations": 0, "cost": _colmap_cost(reconstruction), "converged": True,
            "peak_mb": _peak_mb(), "observations": len(block.observations)}


def run_cli(snoop: str) -> dict:
    """``selfcal import bal`` then ``selfcal adjust --no-report`` (``--snoop 0`` or the default snooping) in
    this process; the seconds summary.json reports, and the wall time of the adjust command."""
    from selfcal.cli.main import main as selfcal_main

    with tempfile.TemporaryDirectory() as folder:
        block, out = os.path.join(folder, "block"), os.path.join(folder, "results")
        if selfcal_main(["import", "bal", BAL, "--out", block]) != 0:
            raise RuntimeError("selfcal import bal failed")
        extra = ["--snoop", "0"] if snoop == "0" else []
        t0 = time.perf_counter()
        code = selfcal_main(["adjust", block, "--out", out, "--no-report", "--quiet"] + extra)
        wall = time.perf_counter() - t0
        with open(os.path.join(out, "summary.json")) as handle:
            summary = json.load(handle)
    return {"exit": code, "seconds": summary["seconds"], "wall": wall, "rejected": summary["n_obs_rejected"]}


def run_numba_setup(_target=None) -> dict:
    """Seconds of the first call of one of selfcal's cached Numba kernels in a fresh process (its module already
    imported): Numba's one-off set-up of its compiler context (the registries of its typing and lowering
    modules) plus the loading of that one kernel from the cache; and of a second call."""
    from selfcal.adjust.kernels import spd_inverse_3x3

    V = np.eye(3)[None].copy()
    out = np.empty_like(V)
    t0 = time.perf_counter()
    spd_inverse_3x3(V, out)
    t1 = time.perf_counter()
    spd_inverse_3x3(V, out)
    return {"first": t1 - t0, "second": time.perf_counter() - t1}


RUNNERS = {"selfcal": run_selfcal, "pycolmap": run_pycolmap, "pycolmap-kept": run_pycolmap, "scipy": run_scipy,
           "selfcal-frame": run_selfcal_frame, "pycolmap-frame": run_pycolmap_frame, "numba-setup": run_numba_setup}


def _cli_child(snoop: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", "cli", "--target", snoop], capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _child(which: str, target, budget_s: float | None = None, rows_file: str | None = None) -> dict:
    extra = ["--budget", repr(budget_s)] if budget_s is not None else []
    extra += ["--rows", rows_file] if rows_file is not None else []
    out = subprocess.run([sys.executable, __file__, "--child", which, "--target", repr(target)] + extra,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child")
    parser.add_argument("--target", default="None")
    parser.add_argument("--skip-scipy", action="store_true")
    parser.add_argument("--budget", type=float, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--rows", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--images", default="28,200,1000", help="synthetic frame blocks (default 28,200,1000)")
    args = parser.parse_args()
    if args.child:
        if args.child == "cli":
            print(json.dumps(run_cli(args.target)))
            return
        if args.child.endswith("-frame") or args.child == "numba-setup":
            print(json.dumps(RUNNERS[args.child](int(args.target))))
            return
        target = None if args.target == "None" else float(args.target)
        budget = {} if args.budget is None else {"budget_s": args.budget}
        if args.rows is not None:
            budget["rows_file"] = args.rows
        print(json.dumps(RUNNERS[args.child](target, **budget)))
        return
    results = {name: _child(name, None) for name in ("selfcal", "pycolmap")}
    ours = results["selfcal"]
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as handle:
        json.dump(ours.pop("rows"), handle)
    try:
        results["pycolmap-kept"] = _child("pycolmap-kept", None, rows_file=handle.name)
    finally:
        os.unlink(handle.name)
    target = ours["cost"] * 1.001
    if not args.skip_scipy:
        # SciPy's trust region creeps near the end: it gets SCIPY_BUDGET_RATIO times selfcal's time
        results["scipy"] = _child("scipy", target, SCIPY_BUDGET_RATIO * ours["seconds"])
    problem = _problem()
    print(f"BAL problem-49-7776: {len(problem.cameras)} cameras, {len(problem.points)} points, "
          f"{len(problem.obs_xy)} observations; initial cost {bal_cost(problem, problem.cameras, problem.points):.2f}")
    print(f"{'engine':<14}{'seconds':>9}{'iter.':>7}{'final cost':>14}{'peak MB':>9}")
    for name, r in results.items():
        its = str(r["iterations"]) if r["iterations"] else "-"
        print(f"{name:<14}{r['seconds']:>9.2f}{its:>7}{r['cost']:>14.4f}{r['peak_mb']:>9.0f}")
    kept = results["pycolmap-kept"]
    print(f"selfcal left out {ours['left_out_behind']} observations behind their camera and {ours['left_out_points']} "
          f"points its rays do not determine; on the observations it kept: selfcal {ours['cost']:.4f}, pycolmap "
          f"{kept['cost']:.4f} ({100 * (ours['cost'] / kept['cost'] - 1):+.4f} %)"
          + (f"; pycolmap ended with {kept['behind']} observations behind their camera (zero residual in its cost)"
             if kept["behind"] else ""))
    print(f"selfcal/pycolmap time: {ours['seconds'] / kept['seconds']:.2f} on the same observations, "
          f"{ours['seconds'] / results['pycolmap']['seconds']:.2f} against pycolmap on the whole file "
          f"(selfcal's time includes the covariance of every unknown, which Ceres does not compute; to its final "
          f"cost, the last iteration: {ours['solve_seconds']:.2f} s, ratio {ours['solve_seconds'] / kept['seconds']:.2f})")
    for snoop in ("0", "default"):
        cli = _cli_child(snoop)
        print(f"selfcal import bal + selfcal adjust --no-report{' --snoop 0' if snoop == '0' else ''}: exit {cli['exit']}, "
              f"{cli['rejected']} observations rejected, "
              f"summary.json {cli['seconds']:.2f} s (command {cli['wall']:.2f} s); against pycolmap on the whole file "
              f"{cli['seconds'] / results['pycolmap']['seconds']:.2f}, on the same observations "
              f"{cli['seconds'] / kept['seconds']:.2f}")
    if "scipy" in results:
        r = results["scipy"]
        if r["to_target"] is not None:
            print(f"SciPy reached selfcal's final cost + 0.1 % after {r['to_target']:.1f} s: scipy/selfcal "
                  f"{r['to_target'] / ours['seconds']:.1f}x")
        else:
            print(f"SciPy was stopped at {r['cost']:.4f} after {r['seconds']:.1f} s without reaching selfcal's final "
                  f"cost + 0.1 % ({target:.4f}): scipy/selfcal > {r['seconds'] / ours['seconds']:.1f}x")
    sizes = [int(v) for v in args.images.split(",") if v]
    if sizes:
        print("\nsynthetic frame blocks (free network, c, x0, y0 free, no APs; cost = 1/2 sum of squared px)")
        setup = _child("numba-setup", 0)
        print(f"selfcal s: the first adjustment in its process; warm: the same adjustment again. Numba's one-off set-up "
              f"in a process, measured in a fresh one: {setup['first']:.2f} s for the first call of one cached kernel "
              f"({1e6 * setup['second']:.0f} us the second time); each further kernel then loads in a few ms")
        print(f"{'images':>7}{'observations':>14}{'selfcal s':>10}{'warm':>7}{'(+cov.)':>9}{'iter.':>6}{'pycolmap s':>11}"
              f"{'selfcal cost':>15}{'pycolmap cost':>15}{'ratio':>7}{'warm':>6}")
        for n in sizes:
            a = _child("selfcal-frame", n)
            b = _child("pycolmap-frame", n)
            print(f"{n:>7}{a['observations']:>14}{a['seconds']:>10.2f}{a['warm_seconds']:>7.2f}{a['total_seconds']:>9.2f}"
                  f"{a['iterations']:>6}{b['seconds']:>11.2f}{a['cost']:>15.4f}{b['cost']:>15.4f}"
                  f"{a['seconds'] / b['seconds']:>7.2f}{a['warm_seconds'] / b['seconds']:>6.2f}", flush=True)

if __name__ == "__main__":
    main()
