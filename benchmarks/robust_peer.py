"""The peer for robust adjustment (issue 39): pycolmap's bundle adjuster (Ceres) with a robust loss.

A frame block of one camera is handed to COLMAP as a text model and refined by
``pycolmap.create_default_bundle_adjuster(...).solve()`` from the same start as selfcal:

* **poses**: the images' start values of selfcal's own initial state
  (:func:`selfcal.adjust.initial.initial_state`: the given orientations of images.csv,
  ``block.images.position_m`` and ``attitude_rad``, unless one misses its control points so badly
  that selfcal resects it), turned from selfcal's camera (looking along -z, y up, M object->image)
  to COLMAP's (+z, y down): R = diag(1, -1, -1) M, t = -R X0;
* **points**: selfcal's start values too: gcp at their reference coordinates, tie *and check* points
  intersected from the given orientations (selfcal starts a check point from its rays, not from its
  reference coordinates, which the adjustment must not see: a free point started at its reference
  would only bias a solver that stops early);
* **camera**: COLMAP's ``OPENCV`` model by default (fx, fy, cx, cy, k1, k2, p1, p2; COLMAP has no
  Brown model with one focal length) at the nominal camera of block.toml and no distortion:
  fx = fy = c / p, cx = W/2 + x0/p, cy = H/2 - y0/p (pixels as DESIGN.md §2: COLMAP's (0, 0)
  is also the upper-left corner of the upper-left pixel);
* **control**: the gcp (``role == "gcp"``) are *constant* points at their surveyed coordinates
  (``BundleAdjustmentConfig.add_constant_point``). Ceres's bundle adjuster has no residual for a
  point's a-priori sigma, so it cannot weight them as selfcal does; holding them is the peer's
  nearest equivalent (their sigma, 1.7 / 2.9 cm in the simulation, is well below the check-point
  errors). Check points are free points like the tie points. No gauge is fixed beyond the gcp
  (``BundleAdjustmentGauge.UNSPECIFIED``, pycolmap's default for a config);
* **loss**: Ceres's ``TRIVIAL``, ``HUBER``, ``SOFT_L1`` or ``CAUCHY`` loss on every reprojection
  residual block. A residual block is the 2-vector (col, row) of one observation, and Ceres applies
  the loss rho to its *squared norm* s = |v|^2 (px^2) with the scale a (px):
  Cauchy rho(s) = a^2 log(1 + s/a^2), Huber rho(s) = s for s <= a^2 else 2a sqrt(s) - a^2,
  SoftL1 rho(s) = 2a^2 (sqrt(1 + s/a^2) - 1); the cost is 1/2 sum rho. Default scale a = 2x the
  block's a-priori image sigma (``block.image_sigma_px``; 1 px for sigma 0.5 px). Ceres does not weight
  observations: per-observation ``sigma_px`` is not used (the simulated blocks have one sigma);
* **rejections**: Ceres rejects nothing; the observations whose final residual norm |v| exceeds
  3 a are reported as the peer's equivalent of rejected observations.

The solver: Ceres's Levenberg-Marquardt as COLMAP configures it (the linear solver COLMAP chooses for the
block's size: dense Schur up to 50 images; one thread below 50,000 residuals), at most 200 iterations, Ceres's
own default function tolerance 1e-6 (COLMAP sets 0), COLMAP's gradient tolerance 1e-4. With a robust loss
Ceres creeps: on simulate_uav(seed=1, points_per_mm2=1.0) the check points and the cost are final to 1e-4
after about 10 iterations, yet with a function tolerance of 1e-9 Cauchy ran 119 iterations and Huber did not
converge in 200 (relative decreases of ~1e-7 per iteration).

Run ``python benchmarks/robust_peer.py``: check-point RMSD of pycolmap with the trivial and the Cauchy
loss on the clean seed-000 Type 3 block and with 5 / 10 / 20 / 30 % of its observations moved by
4-15 px in random directions (seeded). Measured (pycolmap 4.2.1, 80,924 observations; chk RMSD against
the references in metres, XY / Z; Ceres iterations):

    outliers   trivial                 Cauchy (a = 1 px)
      0 %      0.0353 / 0.0549   7     0.0362 / 0.0589  22
      5 %      0.0478 / 0.0653   6     0.0347 / 0.0586  30
     10 %      0.0832 / 0.0911   6     0.0356 / 0.0592  42
     20 %      0.1130 / 0.1505   6     0.0382 / 0.0665  50
     30 %      0.1091 / 0.1341   4     0.0363 / 0.0661  57
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

__all__ = ["PeerResult", "pycolmap_adjust_block", "check_point_rmsd", "frame_colmap_model", "colmap_poses",
           "write_points3d", "LOSSES", "REFINE", "move_observations"]

#: selfcal's name -> pycolmap.LossFunctionType member
LOSSES = {"trivial": "TRIVIAL", "huber": "HUBER", "soft_l1": "SOFT_L1", "cauchy": "CAUCHY"}

#: what the peer refines by default: all of the camera's intrinsics, the poses and the free points
REFINE = ("focal_length", "principal_point", "extra_params", "poses", "points")

#: an observation whose final residual norm exceeds this many loss scales counts as rejected
REJECT_SCALES = 3.0


@dataclass
class PeerResult:
    """pycolmap's adjustment of a block. Arrays over observations are in the block's order."""

    chk_xyz: dict[str, np.ndarray]         # adjusted check points by point id
    points_xyz: np.ndarray                 # (n_points, 3) every adjusted point, in the block's order
    camera: dict                           # model, params by name, and c_mm, x0_mm, y0_mm in selfcal's terms
    initial_cost: float                    # Ceres: 1/2 sum rho(|v|^2), px^2
    final_cost: float
    iterations: int                        # Ceres's successful + unsuccessful steps
    seconds: float                         # wall time of the solve (set-up included, model writing excluded)
    termination: str
    residuals_px: np.ndarray               # (n_obs, 2) observed - projected, px
    outlying: np.ndarray                   # (n_obs,) bool: |v| > 3 x loss scale
    loss: str
    loss_scale_px: float
    notes: list[str] = field(default_factory=list)

    @property
    def n_outlying(self) -> int:
        return int(self.outlying.sum())


# --- selfcal block -> COLMAP text model ---------------------------------------------------------------

def colmap_poses(position_m: np.ndarray, attitude_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's cam_from_world of frame images: quaternions (n, 4) as x, y, z, w and translations (n, 3).
    selfcal's camera looks along -z with y up (M = R3(kappa) R2(phi) R1(omega), object -> image);
    COLMAP's along +z with y down: R = diag(1, -1, -1) M, t = -R X0."""
    from scipy.spatial.transform import Rotation
    from selfcal.geometry.rotation import matrix_from_opk

    R = np.diag([1.0, -1.0, -1.0]) @ matrix_from_opk(np.asarray(attitude_rad, float))
    t = -np.einsum("nij,nj->ni", R, np.asarray(position_m, float))
    return Rotation.from_matrix(R).as_quat(), t


def write_points3d(folder: str, points: list, track: dict[int, list[str]]) -> None:
    """COLMAP's points3D.txt: id (1-based index), X, Y, Z, colour (none), error (none), track (image id,
    2-D index)."""
    with open(os.path.join(folder, "points3D.txt"), "w") as f:
        for p, xyz in enumerate(points):
            f.write(f"{p + 1} {xyz[0]!r} {xyz[1]!r} {xyz[2]!r} 0 0 0 0 {' '.join(track.get(p, []))}\n")


def frame_colmap_model(block, folder: str, camera_model: str = "SIMPLE_PINHOLE", position_m=None,
                       attitude_rad=None, xyz_m=None) -> None:
    """A frame block (one camera) as a COLMAP text model in ``folder``.

    The camera is ``camera_model`` at the block's nominal interior orientation: every focal-length
    parameter f = c / p, cx = W/2 + x0/p, cy = H/2 - y0/p, every extra (distortion) parameter 0.
    Image k of the block is COLMAP image k + 1 (named ``img{k}``), point j is point3D j + 1, and the 2-D
    points of an image are its observations in the block's order. Poses: :func:`colmap_poses` of
    ``position_m`` / ``attitude_rad`` (default: images.csv's); points: ``xyz_m`` (default: points.csv's)."""
    import pycolmap

    cameras = list(block.cameras.values())
    if len(cameras) != 1 or getattr(cameras[0], "model", None) != "frame":
        raise ValueError(f"the COLMAP peer takes a block of one frame camera, not {len(cameras)} camera(s) "
                         f"of model(s) {sorted({getattr(c, 'model', '?') for c in cameras})}")
    cam = cameras[0]
    f = cam.focal_mm / cam.pixel_size_mm
    camera = pycolmap.Camera.create_from_model_name(1, camera_model, f, cam.width_px, cam.height_px)
    params = np.zeros(len(camera.params))
    params[camera.focal_length_idxs()] = f
    params[camera.principal_point_idxs()] = [cam.width_px / 2 + cam.x0_mm / cam.pixel_size_mm,
                                             cam.height_px / 2 - cam.y0_mm / cam.pixel_size_mm]
    position_m = block.images.position_m if position_m is None else position_m
    attitude_rad = block.images.attitude_rad if attitude_rad is None else attitude_rad
    xyz_m = block.points.xyz_m if xyz_m is None else xyz_m
    q, t = colmap_poses(position_m, attitude_rad)
    q, t = q.tolist(), t.tolist()
    obs = block.observations
    pixel = obs.pixel.tolist()
    with open(os.path.join(folder, "cameras.txt"), "w") as handle:
        handle.write(f"1 {camera_model} {cam.width_px} {cam.height_px} {' '.join(repr(float(v)) for v in params)}\n")
    track: dict[int, list[str]] = {}
    with open(os.path.join(folder, "images.txt"), "w") as handle:
        for k in range(len(block.images)):
            sel = np.flatnonzero(obs.image_index == k)
            handle.write(f"{k + 1} {q[k][3]!r} {q[k][0]!r} {q[k][1]!r} {q[k][2]!r} {t[k][0]!r} {t[k][1]!r} "
                         f"{t[k][2]!r} 1 img{k}\n")
            handle.write(" ".join(f"{pixel[i][0]!r} {pixel[i][1]!r} {obs.point_index[i] + 1}" for i in sel) + "\n")
            for j, i in enumerate(sel):
                track.setdefault(int(obs.point_index[i]), []).append(f"{k + 1} {j}")
    write_points3d(folder, np.asarray(xyz_m, float).tolist(), track)


# --- the peer's adjustment -----------------------------------------------------------------------------

def _start(block):
    """selfcal's start values: (position (n, 3), attitude (n, 3), points (n_points, 3), notes)."""
    from selfcal.adjust.initial import initial_state
    from selfcal.adjust.problem import build_problem

    state, notes = initial_state(build_problem(block), block)
    return state.image[:, :3], state.image[:, 3:6], state.points, notes


def _residuals(reconstruction, block) -> np.ndarray:
    """observed - projected (n_obs, 2) px in the block's order, by the reconstruction's cameras and points.
    NaN where a point projects behind its camera."""
    obs = block.observations
    xyz = np.full((len(block.points), 3), np.nan)
    for pid, point in reconstruction.points3D.items():
        xyz[pid - 1] = point.xyz
    out = np.full((len(obs), 2), np.nan)
    for image_id, image in reconstruction.images.items():
        sel = np.flatnonzero(obs.image_index == image_id - 1)
        if sel.size:
            projected = image.camera.img_from_cam(image.cam_from_world() * xyz[obs.point_index[sel]])
            out[sel] = obs.pixel[sel] - projected
    return out


def pycolmap_adjust_block(block, loss: str = "cauchy", loss_scale_px: float | None = None,
                          camera_model: str = "OPENCV", refine=REFINE, max_iterations: int = 200,
                          function_tolerance: float = 1e-6, num_threads: int = -1) -> PeerResult:
    """pycolmap's bundle adjustment (Ceres) of a frame block from selfcal's start (module docstring).

    Parameters
    ----------
    block : selfcal.block.Block
        One frame camera, pruned (:func:`selfcal.block.prune`), with or without outliers.
    loss : {"trivial", "huber", "soft_l1", "cauchy"}
    loss_scale_px : float, optional
        Ceres's loss scale a in pixels, applied to the norm of an observation's 2-D residual (Cauchy:
        rho(s) = a^2 log(1 + s / a^2), s = |v|^2). Default 2 x ``block.image_sigma_px``.
    camera_model : str
        A COLMAP camera model (OPENCV: fx, fy, cx, cy, k1, k2, p1, p2; FULL_OPENCV, RADIAL, ...).
    refine : iterable of str
        Which of ``REFINE`` are estimated: focal_length, principal_point, extra_params (distortion),
        poses, points (the free ones; gcp are always held).
    max_iterations, function_tolerance : Ceres's stopping rules (module docstring)
    num_threads : int
        Ceres's threads (-1: all cores).

    Returns
    -------
    PeerResult
    """
    import pycolmap
    from selfcal.block import prune

    if loss not in LOSSES:
        raise ValueError(f"unknown loss '{loss}' (known: {', '.join(LOSSES)})")
    refine = set(refine)
    unknown = refine - set(REFINE)
    if unknown:
        raise ValueError(f"unknown refine option(s) {sorted(unknown)} (known: {', '.join(REFINE)})")
    if len(prune(block).observations) != len(block.observations):
        raise ValueError("the block has observations that cannot take part (a point with one ray, an image with "
                         "too few points): prune it first (selfcal.block.prune), as selfcal does")
    scale = 2.0 * float(block.image_sigma_px) if loss_scale_px is None else float(loss_scale_px)
    position, attitude, xyz, notes = _start(block)
    with tempfile.TemporaryDirectory() as folder:
        frame_colmap_model(block, folder, camera_model, position, attitude, xyz)
        reconstruction = pycolmap.Reconstruction(folder)

    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_focal_length = "focal_length" in refine
    options.refine_principal_point = "principal_point" in refine
    options.refine_extra_params = "extra_params" in refine
    options.refine_rig_from_world = "poses" in refine
    options.refine_points3D = "points" in refine
    options.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, LOSSES[loss])
    options.ceres.loss_function_scale = scale
    solver = options.ceres.solver_options
    solver.max_num_iterations = max_iterations
    solver.function_tolerance = function_tolerance
    solver.num_threads = num_threads
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.images:
        config.add_image(image_id)
    gcp = np.flatnonzero(block.points.role == "gcp")
    for j in gcp:
        config.add_constant_point(int(j) + 1)
    if not len(gcp):
        notes.append("no gcp: the datum is the start's (no gauge fixed), check points are not meaningful")

    t0 = time.perf_counter()
    summary = pycolmap.create_default_bundle_adjuster(options, config, reconstruction).solve()
    seconds = time.perf_counter() - t0
    ceres = summary.ceres_summary

    points = np.full((len(block.points), 3), np.nan)
    for pid, point in reconstruction.points3D.items():
        points[pid - 1] = point.xyz
    chk = np.flatnonzero(block.points.role == "chk")
    camera = reconstruction.cameras[1]
    info = [name.strip() for name in camera.params_info.split(",")]
    cam = next(iter(block.cameras.values()))
    p = cam.pixel_size_mm
    camera_out = {"model": camera.model.name, "params": dict(zip(info, map(float, camera.params))),
                  "c_mm": float(camera.mean_focal_length()) * p,
                  "x0_mm": (float(camera.principal_point_x) - cam.width_px / 2) * p,
                  "y0_mm": (cam.height_px / 2 - float(camera.principal_point_y)) * p}
    v = _residuals(reconstruction, block)
    outlying = ~(np.hypot(v[:, 0], v[:, 1]) <= REJECT_SCALES * scale)          # NaN (behind) counts
    return PeerResult(
        chk_xyz={block.points.point_id[j]: points[j].copy() for j in chk}, points_xyz=points, camera=camera_out,
        initial_cost=float(ceres.initial_cost), final_cost=float(ceres.final_cost),
        iterations=int(ceres.num_successful_steps + ceres.num_unsuccessful_steps), seconds=seconds,
        termination=str(ceres.termination_type.name), residuals_px=v, outlying=outlying, loss=loss,
        loss_scale_px=scale, notes=notes)


def check_point_rmsd(block, adjusted_xyz_by_id: dict) -> tuple[float, float]:
    """Check-point RMSD (rmsd_xy_m, rmsd_z_m) of adjusted coordinates against the block's references of its
    ``chk`` points, as selfcal's summary.json: sqrt(mean(dX^2 + dY^2)) and sqrt(mean(dZ^2)) (object frame
    axes; a local or projected block). Every chk point of the block must be in ``adjusted_xyz_by_id``."""
    pts = block.points
    chk = np.flatnonzero(pts.role == "chk")
    missing = [pts.point_id[j] for j in chk if pts.point_id[j] not in adjusted_xyz_by_id]
    if missing:
        raise ValueError(f"{len(missing)} check point(s) without adjusted coordinates: {missing[:5]}")
    if not len(chk):
        raise ValueError("the block has no check point (role 'chk')")
    d = np.array([adjusted_xyz_by_id[pts.point_id[j]] for j in chk], float) - pts.xyz_m[chk]
    return float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


# --- the script -------------------------------------------------------------------------------------------

def move_observations(block, share: float, seed: int = 0, low_px: float = 4.0, high_px: float = 15.0):
    """``block`` with ``share`` of its observations (drawn without replacement) moved by low-high px in
    random directions (uniform size and angle, seeded); returns (block, moved rows)."""
    from dataclasses import replace

    rng = np.random.default_rng(seed)
    obs = block.observations
    n = int(round(share * len(obs)))
    rows = np.sort(rng.choice(len(obs), n, replace=False))
    size = rng.uniform(low_px, high_px, n)
    angle = rng.uniform(0.0, 2 * np.pi, n)
    pixel = obs.pixel.copy()
    pixel[rows] += np.column_stack([size * np.cos(angle), size * np.sin(angle)])
    return replace(block, observations=replace(obs, pixel=pixel)), rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="simulate_uav seed (default 0: seed 000's block)")
    parser.add_argument("--points-per-mm2", type=float, default=3.5)
    parser.add_argument("--rates", default="0,0.05,0.10,0.20,0.30")
    parser.add_argument("--losses", default="trivial,cauchy")
    args = parser.parse_args()
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    sim = simulate_uav(seed=args.seed, points_per_mm2=args.points_per_mm2)
    clean = prune(sim.blocks["type3"])
    print(f"simulate_uav(seed={args.seed}, points_per_mm2={args.points_per_mm2}) type3 ({sim.info['distortion']}): "
          f"{len(clean.images)} images, {len(clean.points)} points, {len(clean.observations)} observations, "
          f"{int((clean.points.role == 'gcp').sum())} gcp held, {int((clean.points.role == 'chk').sum())} chk free; "
          f"pycolmap {__import__('pycolmap').__version__}, OPENCV, loss scale 2 x sigma = "
          f"{2 * clean.image_sigma_px:g} px; outliers moved 4-15 px (seed 0)")
    print(f"{'outliers':>8} {'loss':>8} {'chk XY [m]':>11} {'chk Z [m]':>10} {'seconds':>8} {'iter':>5} "
          f"{'|v|>3a':>7} {'moved|v|>3a':>11} {'c [mm]':>8} {'termination':>12}")
    for rate in [float(r) for r in args.rates.split(",")]:
        block, rows = move_observations(clean, rate, seed=0) if rate else (clean, np.zeros(0, int))
        for loss in args.losses.split(","):
            r = pycolmap_adjust_block(block, loss=loss)
            xy, z = check_point_rmsd(block, r.chk_xyz)
            print(f"{rate:>8.0%} {loss:>8} {xy:>11.4f} {z:>10.4f} {r.seconds:>8.2f} {r.iterations:>5d} "
                  f"{r.n_outlying:>7d} {int(r.outlying[rows].sum()):>5d}/{len(rows):<5d} {r.camera['c_mm']:>8.4f} "
                  f"{r.termination:>12}", flush=True)


if __name__ == "__main__":
    main()
