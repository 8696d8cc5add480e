"""selfcal's projection uncertainty against mrcal's on the same chessboard observations (issue 40 item 5).

A simulated chessboard calibration (:func:`selfcal.simulate.chessboard.simulate_chessboard`: a 10 x 8 board, 20
poses, a 3000 x 2000 lens of OpenCV's rational model, 0.3 px noise) is adjusted by selfcal with its ``opencv``
sensor (``distortion = "rational"``: fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6, mrcal's LENSMODEL_OPENCV8) and
by mrcal (Debian's python3-mrcal, in /usr/bin/python3: benchmarks/mrcal_side.py) from the same start, regularisation
off (``--regularization`` turns mrcal's on: then the two solve different problems). Compared on a grid of pixels:

* ``projection``: the covariance of the pixel of a camera-frame point at ``--distance`` m through the solved
  model, with the intrinsics' and the board poses' covariance, as ``mrcal.projection_uncertainty`` defines it
  (mrcal 2.2, "mean-frames"; selfcal: :func:`selfcal.stats.projection_sigma.projection_covariance`), both at the
  observations' a-priori sigma (mrcal: ``observed_pixel_uncertainty``, selfcal: variance factor 1); ratio of
  sqrt(trace / 2) (mrcal's ``rms-stdev``) and of the worst direction's σ, selfcal / mrcal;
* ``distortion``: the σ of the distortion's correction alone, f (d(n) - n) with the coefficients' covariance
  (distortion_sigma.csv's definition: the core fx, fy, cx, cy excluded), from each tool's covariance of its
  intrinsics (mrcal's by its own propagation), at the same n;
* the solutions: the largest difference of the two calibrations' projections over the grid (px).

Query pixels where the solved model has no ray (beyond the fold of the rational model's image of the field: the
frame's corners) are left out of both; their count is printed.

    python benchmarks/peer_mrcal_uncertainty.py [--seeds 1,2,3] [--frames 20] [--distance 1.2] [--regularization]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import time

import numpy as np

from selfcal.adjust import AdjustOptions, APOptions, SolverOptions, adjust
from selfcal.geometry.rotation import matrix_from_opk
from selfcal.sensors.bal import rotation_vector_from_matrix
from selfcal.sensors.opencv import distortion_with_jacobians, undistort
from selfcal.simulate.chessboard import simulate_chessboard
from selfcal.stats.projection_sigma import camera_points, projection_covariance

MRCAL_PYTHON = "/usr/bin/python3"
#: selfcal converged to 1e-6 of a sigma (OPENCV8's k4..k6 nearly undo k1..k3: a long, flat valley)
TIGHT = SolverOptions(function_tolerance=1e-6, step_tolerance=1e-8, cost_tolerance=1e-16)
HERE = os.path.dirname(os.path.abspath(__file__))
#: OpenCV's distortion models -> mrcal's lens models
LENSMODELS = {"opencv4": "LENSMODEL_OPENCV4", "plumb_bob": "LENSMODEL_OPENCV5", "rational": "LENSMODEL_OPENCV8",
              "thin_prism": "LENSMODEL_OPENCV12"}


def mrcal_available() -> bool:
    return os.path.exists(MRCAL_PYTHON) and subprocess.run([MRCAL_PYTHON, "-c", "import mrcal"],
                                                           capture_output=True).returncode == 0


def frames_rt_toref(eop: np.ndarray) -> np.ndarray:
    """mrcal's board poses (board -> camera, Rodrigues r then t, OpenCV's camera axes) of image orientations
    (X0, Y0, Z0, omega, phi, kappa; rad) of a chessboard block."""
    M = matrix_from_opk(eop[:, 3:])
    R = M * np.array([1.0, -1.0, -1.0])[None, :, None]           # photogrammetric -> OpenCV camera axes
    t = -np.einsum("nij,nj->ni", R, eop[:, :3])
    return np.column_stack([rotation_vector_from_matrix(R), t])


def run_mrcal(block, board, intrinsics, eop, query, distance_m, sigma_px, distortion, regularization) -> dict:
    """mrcal's calibration of a chessboard block's observations from a seed (``intrinsics``, the images'
    ``eop``), its projection uncertainty at ``query`` (mrcal pixels) and ``distance_m`` (benchmarks/mrcal_side.py)."""
    camera = next(iter(block.cameras.values()))
    with tempfile.TemporaryDirectory() as tmp:
        inp, out = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(inp, observations=block.observations.pixel.reshape(len(eop), board[1], board[0], 2) - 0.5,
                 object_width_n=board[0], object_height_n=board[1], spacing=0.1,
                 imagersize=[camera.width_px, camera.height_px], lensmodel=LENSMODELS[distortion],
                 intrinsics=intrinsics, frames_rt_toref=frames_rt_toref(eop), query=query, distance=distance_m,
                 sigma=sigma_px, regularization=int(regularization))
        t0 = time.perf_counter()
        subprocess.run([MRCAL_PYTHON, os.path.join(HERE, "mrcal_side.py"), inp, out], check=True)
        return dict(np.load(out)) | {"seconds": time.perf_counter() - t0}


def _undistorted(core: np.ndarray, pixel: np.ndarray) -> np.ndarray:
    """Normalised coordinates of selfcal pixels through an OpenCV camera's core (fx, fy, cx, cy, coefficients)."""
    return undistort((pixel - core[2:4] - 0.5) / core[:2], core[4:])


def distortion_covariance(core: np.ndarray, n: np.ndarray, cov_coefficients: np.ndarray, count: int) -> np.ndarray:
    """Covariance (m, 2, 2) px² of the distortion's correction f (d(n) - n) at normalised n given the covariance of
    the first ``count`` coefficients (the core held)."""
    _, _, dk = distortion_with_jacobians(n, core[4:])
    J = dk[:, :, :count] * core[:2][None, :, None]
    return np.einsum("mai,ij,mbj->mab", J, cov_coefficients, J)


def compare(seed: int = 1, n_frames: int = 20, board=(10, 8), distance_m: float = 1.0, nodes=(13, 9),
            regularization: bool = False, sigma_px: float = 0.3, distortion: str = "rational",
            independent: bool = True) -> dict:
    """One calibration by both tools and their numbers (module docstring); ``independent``: mrcal also from the
    simulation's start (else only from selfcal's solution)."""
    from dataclasses import replace
    from selfcal.block import OpenCVCamera
    from selfcal.sensors.opencv import COEFFICIENT_NAMES, DISTORTION_MODELS
    from selfcal.simulate.chessboard import DEFAULT_CAMERA, project_opencv
    from selfcal.stats.field_sigma import observed_nodes
    camera = replace(DEFAULT_CAMERA, distortion=distortion)
    sim = simulate_chessboard(seed, camera=camera, n_frames=n_frames, board=board, image_sigma_px=sigma_px)
    block = sim.block
    count = DISTORTION_MODELS[distortion]
    t0 = time.perf_counter()
    result = adjust(block, AdjustOptions(ap=APOptions("none"), solver=TIGHT))
    seconds_selfcal = time.perf_counter() - t0
    core = np.asarray(result.state.cameras[0], float)
    W, H = camera.width_px, camera.height_px
    cols, rows = np.meshgrid(np.linspace(0, W - 1, nodes[0]), np.linspace(0, H - 1, nodes[1]))
    query = np.column_stack([cols.ravel(), rows.ravel()])           # mrcal's pixels
    n = _undistorted(core, query + 0.5)
    p = camera_points(n, distance_m)
    cov_s = projection_covariance(result, camera.camera_id, p, variance_factor=1.0)
    # mrcal from selfcal's solution (the same point of an ill-conditioned model's valley: the linearised covariance
    # is that point's), and from the simulation's start (independent)
    m = run_mrcal(block, board, core[:4 + count], result.state.image, query, distance_m, sigma_px, distortion,
                  regularization)
    alone = None
    if independent:
        start = block.cameras[camera.camera_id]
        seed_intrinsics = np.r_[start.fx_px, start.fy_px, start.cx_px, start.cy_px, start.coefficients[:count]]
        start_eop = np.column_stack([block.images.position_m, block.images.attitude_rad])
        alone = run_mrcal(block, board, seed_intrinsics, start_eop, query, distance_m, sigma_px, distortion,
                          regularization)
    # the conventions: mrcal projects its seed (selfcal's solution) as selfcal does
    solved = OpenCVCamera("c", W, H, *core[:4], distortion=distortion, **dict(zip(COEFFICIENT_NAMES, core[4:])))
    M = matrix_from_opk(result.state.image[:, 3:])
    ours = np.array([project_opencv(solved, M[i], result.state.image[i, :3], sim.corners_m)
                     for i in range(n_frames)]).reshape(m["projected"].shape) - 0.5
    convention_px = float(np.max(np.abs(ours - m["projected"])))
    observed = observed_nodes(query[:, 0] + 0.5, query[:, 1] + 0.5, block.observations.pixel, 0.05 * W)

    def projected(intrinsics):
        """Pixels (mrcal's) of the query points through intrinsics (fx, fy, cx, cy, coefficients)."""
        k = np.r_[intrinsics[4:], np.zeros(12 - count)]
        return distortion_with_jacobians(p[:, :2] / p[:, 2:], k, jacobians=False)[0] * intrinsics[:2] + intrinsics[2:4]

    def rms(c):
        return np.sqrt(0.5 * np.trace(c, axis1=1, axis2=2))

    def worst(c):
        return np.sqrt(np.linalg.eigvalsh(c)[:, -1])
    ours_of = projected(core[:4 + count])
    cov_m = m["cov_q"]
    cam = result.problem.cameras[0]
    names = [f"{cam.camera_id}: {cam.names[j]}" for j in range(4 + count)]
    cov_core = result.covariance(names) / result.variance_factor        # a-priori: variance factor 1
    var_m = m["var_intrinsics"]
    dist_s = distortion_covariance(core, n, cov_core[4:, 4:], count)
    dist_m = distortion_covariance(core, n, var_m[4:, 4:], count)
    out = {"seed": seed, "frames": n_frames, "distortion": distortion, "regularization": regularization,
           "distance_m": distance_m, "convention_px": convention_px, "observed": observed,
           "same_solution_px": float(np.nanmax(np.linalg.norm(ours_of - projected(m["intrinsics"]), axis=1))),
           "rms_selfcal_px": float(result.sigma0_px), "rms_mrcal_px": float(m["rms_px"]),
           "projection_rms_ratio": rms(cov_s) / rms(cov_m), "projection_worst_ratio": worst(cov_s) / worst(cov_m),
           "projection_rms_mrcal_px": rms(cov_m), "projection_rms_selfcal_px": rms(cov_s),
           "distortion_ratio": rms(dist_s) / rms(dist_m), "distortion_rms_selfcal_px": rms(dist_s),
           "intrinsics_sigma_ratio": np.sqrt(np.diag(cov_core) / np.diag(var_m)),
           "seconds_selfcal": seconds_selfcal, "seconds_mrcal": m["seconds"]}
    if alone is not None:
        apart = np.linalg.norm(ours_of - projected(alone["intrinsics"]), axis=1)
        out |= {"solution_px": float(np.nanmax(apart)),
                "solution_observed_px": float(np.nanmax(np.where(observed, apart, np.nan))),
                "rms_mrcal_alone_px": float(alone["rms_px"]),
                "projection_rms_ratio_independent": rms(cov_s) / rms(alone["cov_q"]),
                "seconds_mrcal": alone["seconds"]}
    return out


def _range(values: np.ndarray, spec: str = ".4f") -> str:
    return f"{np.nanmin(values):{spec}}-{np.nanmax(values):{spec}}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--distance", type=float, default=1.0)
    parser.add_argument("--distortion", default="rational", choices=sorted(LENSMODELS))
    parser.add_argument("--regularization", action="store_true")
    args = parser.parse_args()
    if not mrcal_available():
        raise SystemExit(f"mrcal is not importable by {MRCAL_PYTHON}: apt-get install python3-mrcal")
    print(f"OpenCV '{args.distortion}' model, {args.frames} poses of a 10 x 8 board, 0.3 px, distance "
          f"{args.distance} m, mrcal regularisation {'on' if args.regularization else 'off'}; 13 x 9 query pixels\n")
    print("Ratios selfcal / mrcal over the query pixels where observations lie (5 % of the width, as "
          "distortion_sigma.csv's observed area) and, after the slash, over every query pixel with a ray.\n")
    print("| seed | query pixels observed / with a ray | pixel convention [px] | solutions differ, observed / all "
          "[px] | projection σ mrcal, observed [px] | rms-stdev ratio | worst-direction ratio | rms-stdev ratio, mrcal "
          "from its own start | distortion σ selfcal, observed [px] | distortion σ ratio | intrinsics σ ratio | "
          "s selfcal / mrcal |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in (int(s) for s in args.seeds.split(",")):
        r = compare(seed, args.frames, distance_m=args.distance, regularization=args.regularization,
                    distortion=args.distortion)
        ray = np.isfinite(r["projection_rms_ratio"])
        seen = ray & r["observed"]

        def both(key, spec=".4f"):
            return f"{_range(r[key][seen], spec)} / {_range(r[key][ray], spec)}"
        print(f"| {seed} | {int(seen.sum())} / {int(ray.sum())} of {ray.size} | {r['convention_px']:.1e} | "
              f"{r['solution_observed_px']:.1e} / {r['solution_px']:.1e} | "
              f"{_range(r['projection_rms_mrcal_px'][seen], '.3f')} | {both('projection_rms_ratio')} | "
              f"{both('projection_worst_ratio')} | {both('projection_rms_ratio_independent')} | "
              f"{_range(r['distortion_rms_selfcal_px'][seen], '.3f')} | {both('distortion_ratio')} | "
              f"{_range(r['intrinsics_sigma_ratio'])} | {r['seconds_selfcal']:.2f} / {r['seconds_mrcal']:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
