"""selfcal's calibration of a known camera, on real blocks: Strecha et al.'s fountain-P11 and Herz-Jesus-P8.

Strecha, von Hansen, Van Gool, Fua, Thoennessen (CVPR 2008), "On benchmarking camera calibration and multi-view
stereo for high resolution imagery": 11 and 8 convergent images (3072 x 2048) of two façades, undistorted (the
camera is distortion-free), with ground-truth cameras: K (fx 2759.48, fy 2764.16, cx 1520.69, cy 1006.81: an
affinity of 0.17 % in the truth), R and the centre of every image. Research use only: the data stay out of the
repository. Get them from https://github.com/openMVG/SfM_quality_evaluation (Benchmarking_Camera_Calibration_2008:
fountain-P11 and Herz-Jesus-P8, each with images/*.jpg and gt/*.jpg.camera) and give their folder:

    python benchmarks/study_known_camera.py DATA [--work DIR] [--sets fountain-P11,Herz-Jesus-P8]
                                                 [--camera-model PINHOLE] [--jackknife G] [--models ...]

What it does, per set:
1. COLMAP (Debian's `colmap`, CPU): feature_extractor with one shared camera (PINHOLE by default, as a user of
   undistorted images would; SIMPLE_RADIAL with --camera-model), exhaustive_matcher, mapper; then COLMAP's own
   bundle_adjuster with the principal point refined too: the peer's intrinsics (COLMAP's pixel convention is
   selfcal's, (0, 0) the upper-left corner of the first pixel). Cached in --work.
2. `selfcal import colmap` (a free network: no control; pixel size 0.005 mm: every number below is in pixels) and
   `selfcal adjust` with each model of --models (default: none, brown, --ap auto, the default without --ap,
   brown --screen, wavelet:db4 --screen, and brown with --ap-at measured: the basis at the measured coordinates,
   as before), each with --jackknife G (default: one group per image).
3. Against the truth, K read in selfcal's pixel convention (the held true cameras fit the tie points best within
   0.25 px of it, see the held-truth line): c, x0, y0 (c against fy: selfcal's one principal distance is fy's, an
   affinity b1 gives fx) with the stated sigma, the jackknife's sigma and |error|/sigma; fx, fy, cx, cy of
   `selfcal export opencv` with the sigma the export propagates; the correction Delta over the observed area (the
   nodes of distortion_grid.csv within 5 % of the width of an observation: RMS and max |Delta|); the calibration's
   error against the true K over that area (where the calibration puts the true ray of each node: RMS, max); the
   export's misfit; the images' centres and rotations against the true cameras after a 7-parameter similarity of
   the centres. The same for COLMAP's cameras.
4. With --simulate N: the block's own geometry (its tie points triangulated with the true cameras, in the images
   that see them) projected by the true camera with white noise of the held-truth residual's size, adjusted with
   brown, the AP basis at the measured and at the adjusted coordinates: what the estimator does where the model
   is exactly right.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np

#: selfcal adjust runs: label -> arguments
MODELS = {
    "none": ["--ap", "none"],
    "brown": ["--ap", "brown"],
    "auto": ["--ap", "auto"],
    "default": [],
    "brown --screen": ["--ap", "brown", "--screen"],
    "db4 --screen": ["--ap", "wavelet:db4", "--screen"],
    "brown at measured": ["--ap", "brown", "--ap-at", "measured"],
}
PIXEL_MM = 0.005
FLIP = np.diag([1.0, -1.0, -1.0])


def selfcal_command() -> list[str]:
    here = os.path.join(os.path.dirname(sys.executable), "selfcal")
    return [here] if os.path.exists(here) else [shutil.which("selfcal") or "selfcal"]


def run(command: list[str], log: str | None = None) -> str:
    done = subprocess.run(command, capture_output=True, text=True)
    if log:
        with open(log, "a") as f:
            f.write(" ".join(command) + "\n" + done.stdout + done.stderr + "\n")
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return done.stdout


def read_truth(folder: str) -> dict:
    """image name -> (K, R world-to-camera, C): Strecha's files hold K, a zero row, R camera-to-world, C, w h."""
    out = {}
    for path in sorted(glob.glob(os.path.join(folder, "gt", "*.camera"))):
        v = np.array(open(path).read().split(), float)
        out[os.path.basename(path)[:-len(".camera")]] = (v[:9].reshape(3, 3), v[12:21].reshape(3, 3).T, v[21:24])
    if not out:
        raise SystemExit(f"no ground-truth cameras in {folder}/gt (see the docstring for the data)")
    return out


def colmap(images: str, work: str, camera_model: str) -> tuple[str, str]:
    """The mapper's model and the peer's (bundle_adjuster with the principal point refined); cached."""
    os.makedirs(work, exist_ok=True)
    db, sparse, peer = (os.path.join(work, n) for n in ("database.db", "sparse", "peer"))
    log = os.path.join(work, "colmap.log")
    if not os.path.exists(os.path.join(sparse, "0", "cameras.bin")):
        for path in (db, sparse):
            if os.path.isdir(path):
                shutil.rmtree(path)
            elif os.path.exists(path):
                os.remove(path)
        os.makedirs(sparse)
        run(["colmap", "feature_extractor", "--database_path", db, "--image_path", images,
             "--ImageReader.camera_model", camera_model, "--ImageReader.single_camera", "1",
             "--SiftExtraction.use_gpu", "0"], log)
        run(["colmap", "exhaustive_matcher", "--database_path", db, "--SiftMatching.use_gpu", "0"], log)
        run(["colmap", "mapper", "--database_path", db, "--image_path", images, "--output_path", sparse], log)
    if not os.path.exists(os.path.join(peer, "cameras.bin")):
        os.makedirs(peer, exist_ok=True)
        run(["colmap", "bundle_adjuster", "--input_path", os.path.join(sparse, "0"), "--output_path", peer,
             "--BundleAdjustment.refine_principal_point", "1"], log)
    return os.path.join(sparse, "0"), peer


def similarity_errors(names, centres, world_to_camera, truth) -> tuple[float, float, float]:
    """Centres' RMS residual after a 7-parameter similarity onto the true centres (m), the same relative to the
    true centres' RMS spread, and the RMS angle (deg) between each camera's rotation and the true one."""
    from selfcal.geometry.similarity import fit_similarity
    true_c = np.array([truth[n][2] for n in names])
    sim, residual = fit_similarity(np.asarray(centres), true_c)
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    spread = float(np.sqrt(np.mean(np.sum((true_c - true_c.mean(0)) ** 2, axis=1))))
    angles = []
    for n, R in zip(names, world_to_camera):
        d = R @ sim.rotation.T @ truth[n][1].T
        angles.append(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))
    return rms, rms / spread, float(np.sqrt(np.mean(np.square(angles))))


def observed_nodes(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """The 61 x 41 nodes of distortion_grid.csv within 5 % of the width of an observation, (n, 2) (col, row)."""
    from scipy.spatial import cKDTree
    cols, rows = np.meshgrid(np.linspace(0, width, 61), np.linspace(0, height, 41))
    nodes = np.column_stack([cols.ravel(), rows.ravel()])
    distance, _ = cKDTree(pixels).query(nodes)
    return nodes[distance <= 0.05 * width]


def truth_error_field(project, K: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """|where a calibration puts the true ray of each node - the node| (px); ``project(n)`` maps normalised
    coordinates (OpenCV's camera frame) to selfcal's pixels."""
    n = np.column_stack([(nodes[:, 0] - K[0, 2]) / K[0, 0], (nodes[:, 1] - K[1, 2]) / K[1, 1]])
    return np.hypot(*(project(n) - nodes).T)


def held_truth(block, truth):
    """The tie points triangulated with the true cameras held (rays intersected, then three Gauss-Newton steps per
    point on the image residuals, rays off by more than 3 px left out): (their true projection of every
    observation (m, 2), which observations are within 3 px of it)."""
    from selfcal.geometry.similarity import intersect_rays
    obs = block.observations
    names = list(block.images.image_id)
    K = np.array([truth[n][0] for n in names])[obs.image_index]
    R = np.array([truth[n][1] for n in names])[obs.image_index]
    C = np.array([truth[n][2] for n in names])[obs.image_index]
    pt = obs.point_index
    rays = np.linalg.solve(K, np.column_stack([obs.pixel, np.ones(len(pt))])[..., None])[..., 0]
    X = intersect_rays(C, np.einsum("nji,nj->ni", R, rays), pt, len(block.points))

    def project(points):
        u = np.einsum("nij,nj->ni", K, np.einsum("nij,nj->ni", R, points[pt] - C))
        return u[:, :2] / u[:, 2:]
    for _ in range(3):
        f0 = project(X)
        J = np.empty((len(pt), 2, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = 1e-6
            J[:, :, k] = (project(X + step) - f0) / 1e-6
        r = obs.pixel - f0
        ok = np.isfinite(r).all(1) & (np.hypot(*r.T) < 3)
        A = np.zeros((len(X), 3, 3))
        b = np.zeros((len(X), 3))
        np.add.at(A, pt[ok], np.einsum("nki,nkj->nij", J[ok], J[ok]))
        np.add.at(b, pt[ok], np.einsum("nki,nk->ni", J[ok], r[ok]))
        good = np.abs(np.linalg.det(A)) > 1e-12
        X[good] += np.linalg.solve(A[good], b[good][..., None])[..., 0]
    exact = project(X)
    return exact, np.isfinite(exact).all(1) & (np.hypot(*(obs.pixel - exact).T) < 3)


def held_truth_sigma0(block, truth) -> float:
    """RMS image residual (px per coordinate) of the tie points with the true cameras held (:func:`held_truth`)."""
    exact, ok = held_truth(block, truth)
    return float(np.sqrt(np.mean((block.observations.pixel - exact)[ok] ** 2)))


def read_opencv_export(path: str) -> dict:
    """fx, fy, cx, cy (selfcal's convention: OpenCV's + 0.5), their sigma and the misfit of an OpenCV YAML."""
    text = open(path).read()

    def matrix(key):
        m = re.search(key + r": !!opencv-matrix.*?data: \[(.*?)\]", text, re.S)
        return np.array([float(v) for v in m.group(1).replace("\n", " ").split(",")])
    K = matrix("camera_matrix")
    sigma = matrix("parameter_sigma")[:4] if "parameter_sigma" in text else np.full(4, np.nan)
    misfit = {k: float(re.search(k + r": ([0-9.eE+-]+)", text).group(1)) for k in ("misfit_rms_px", "misfit_max_px")}
    model = re.search(r"distortion_model: (\S+)", text)
    return {"fx": K[0], "fy": K[4], "cx": K[2] + 0.5, "cy": K[5] + 0.5, "sigma": sigma,
            "model": model.group(1) if model else "?", **misfit}


def study_results(res: str, block, truth, K: np.ndarray, nodes: np.ndarray) -> dict:
    """Everything the tables print of one results folder."""
    from selfcal.calibration import Calibration
    from selfcal.geometry.rotation import matrix_from_opk
    from selfcal.io.results import read_camera_json, read_results_table
    summary = json.load(open(os.path.join(res, "summary.json")))
    cam_id, entry = next(iter(read_camera_json(res)["cameras"].items()))
    cal = Calibration.from_camera_json(cam_id, entry)
    p = cal.pixel_size_mm
    out = {"model": summary["ap_model"], "sigma0": summary["sigma0_px"], "n_ap": summary.get("n_ap_significant"),
           "n_ap0": summary.get("n_ap_initial")}
    precision = summary.get("calibration_precision") or {}
    by_name = {q["name"]: q for q in (precision.get("cameras") or {}).get(cam_id, [])}
    out["trusted"] = precision.get("trusted")
    truths = {"c": K[1, 1], "x0": K[0, 2] - cal.width_px / 2, "y0": cal.height_px / 2 - K[1, 2]}
    values = {"c": cal.focal_mm / p, "x0": cal.x0_mm / p, "y0": cal.y0_mm / p}
    sigmas = {"c": entry["focal_mm"]["sigma"], "x0": entry["x0_mm"]["sigma"], "y0": entry["y0_mm"]["sigma"]}
    for k in ("c", "x0", "y0"):
        sigma = None if sigmas[k] is None else sigmas[k] / p
        jack = by_name.get(k, {}).get("sigma_jackknife")
        out[k] = (values[k], values[k] - truths[k], sigma, jack)
    # the correction over the observed area, and where the calibration puts the true rays
    delta = np.hypot(*cal.delta_px(nodes).T)
    out["delta_rms"], out["delta_max"] = float(np.sqrt(np.mean(delta ** 2))), float(delta.max())
    pp, f = np.array(cal.principal_point_px), cal.focal_px
    error = truth_error_field(lambda n: cal.measured_from_ideal(pp + f * n), K, nodes)
    out["truth_rms"], out["truth_max"] = float(np.sqrt(np.mean(error ** 2))), float(error.max())
    # the export
    yaml = os.path.join(res, "..", os.path.basename(res) + "-opencv.yaml")
    run(selfcal_command() + ["export", "opencv", res, "--out", yaml, "--quiet"])
    out["export"] = read_opencv_export(yaml)
    # the images against the true cameras
    images = read_results_table(res, "images.csv")
    names = [str(n) for n in images["image_id"]]
    centres = np.column_stack([images["X0"], images["Y0"], images["Z0"]])
    M = matrix_from_opk(np.radians(np.column_stack([images["omega_deg"], images["phi_deg"], images["kappa_deg"]])))
    out["orientation"] = similarity_errors(names, centres, FLIP @ M, truth)
    return out


def peer_results(sparse: str, truth, K: np.ndarray, nodes: np.ndarray) -> dict:
    from selfcal.calibration_models import opencv_radial_tangential
    from selfcal.geometry.rotation import matrix_from_quaternion
    from selfcal.io.colmap import read_colmap
    model = read_colmap(sparse)
    cam = next(iter(model.cameras.values()))
    q = cam.params
    fx, fy = (q["f"], q["f"]) if "f" in q else (q["fx"], q["fy"])
    k = np.array([q.get("k1", q.get("k", 0.0)), q.get("k2", 0.0), q.get("p1", 0.0), q.get("p2", 0.0)])

    def project(n):
        d = opencv_radial_tangential(n, k)
        return np.column_stack([fx * d[:, 0] + q["cx"], fy * d[:, 1] + q["cy"]])
    error = truth_error_field(project, K, nodes)
    R = matrix_from_quaternion(model.qvec)
    centres = -np.einsum("nji,nj->ni", R, model.tvec)
    names = [str(n) for n in model.image_names]
    return {"model": cam.model, "fx": fx, "fy": fy, "cx": q["cx"], "cy": q["cy"], "k": k,
            "truth_rms": float(np.sqrt(np.mean(error ** 2))), "truth_max": float(error.max()),
            "orientation": similarity_errors(names, centres, R, truth)}


def simulated_at_real_geometry(block, truth, seeds: int, noise_px: float) -> list[str]:
    """The block's own geometry with white noise: its tie points triangulated with the true cameras, projected
    back exactly and given ``noise_px`` of Gaussian noise, adjusted with brown (least squares, no tests) with the
    AP basis at the measured and at the adjusted coordinates; c against fy, x0, y0, b1 against the truth's.
    Returns the table's lines."""
    from dataclasses import replace

    from selfcal.adjust import AdjustOptions, APOptions, adjust
    from selfcal.block import prune
    obs = block.observations
    exact, ok = held_truth(block, truth)
    keep = np.flatnonzero(ok)
    K0 = next(iter(truth.values()))[0]
    cam = next(iter(block.cameras.values()))
    r0_px = 0.5 * float(np.hypot(cam.width_px, cam.height_px))
    truth_of = {"c": K0[1, 1], "x0": K0[0, 2] - cam.width_px / 2, "y0": cam.height_px / 2 - K0[1, 2],
                "b1": (1 - K0[1, 1] / K0[0, 0]) * r0_px}
    z: dict[str, dict[str, list[float]]] = {"measured": {}, "adjusted": {}}
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        pixel = exact[keep] + rng.normal(0.0, noise_px, (keep.size, 2))
        inside = (pixel[:, 0] > 0) & (pixel[:, 0] < cam.width_px) & (pixel[:, 1] > 0) & (pixel[:, 1] < cam.height_px)
        sub = obs.take(keep[inside])
        sim = prune(replace(block, observations=replace(sub, pixel=pixel[inside], ap_at_px=None), datum="free"))
        for at in z:
            r = adjust(sim, AdjustOptions(ap=APOptions("brown", evaluated_at=at)))
            values, sigma = r.state.cameras[0], r.camera_sigma()[0]
            p = cam.pixel_size_mm
            got = {"c": (values[0] / p, sigma[0] / p), "x0": (values[1] / p, sigma[1] / p),
                   "y0": (values[2] / p, sigma[2] / p), "b1": (values[8], sigma[8])}
            for k, (v, s_) in got.items():
                z[at].setdefault(k, []).append((v - truth_of[k]) / s_)
                z[at].setdefault(k + " px", []).append(v - truth_of[k])
    lines = [f"\nThe same geometry simulated ({seeds} seeds, {noise_px:.2f} px of white noise, the true camera; brown, "
             f"least squares): error mean ± sd px, z = error/σ mean ± sd",
             "", "| AP basis at | c − fy | z | x0 | z | y0 | z | b1 | z |", "|---|---|---|---|---|---|---|---|---|"]
    for at, by in z.items():
        cells = []
        for k in ("c", "x0", "y0", "b1"):
            e, zz = np.array(by[k + " px"]), np.array(by[k])
            cells += [f"{e.mean():+.2f} ± {e.std(ddof=1) if e.size > 1 else 0:.2f}",
                      f"{zz.mean():+.1f} ± {zz.std(ddof=1) if zz.size > 1 else 0:.1f}"]
        lines.append(f"| {at} | " + " | ".join(cells) + " |")
    return lines


def cell(value, sigma=None, spec=".2f") -> str:
    if value is None:
        return "–"
    return f"{value:{spec}}" + ("" if sigma is None else f" ± {sigma:{spec}}")


def ratio(error, sigma) -> str:
    return "–" if sigma is None or not sigma else f"{abs(error) / sigma:.1f}"


def print_tables(name: str, K: np.ndarray, info: dict, rows: dict, peers: dict) -> None:
    print(f"\n### {name}: {info['images']} images, {info['points']} points, {info['observations']} observations "
          f"(COLMAP {info['camera_model']}); held true cameras: RMS image residual {info['held']:.3f} px per "
          f"coordinate; observed area {info['nodes']} of 2501 grid nodes")
    print(f"truth: fx {K[0, 0]:.2f}, fy {K[1, 1]:.2f}, cx {K[0, 2]:.2f}, cy {K[1, 2]:.2f} px; selfcal's c against fy "
          f"(its b1 gives fx), x0 = cx - W/2 = {K[0, 2] - 1536:.2f}, y0 = H/2 - cy = {1024 - K[1, 2]:.2f} px\n")
    print("| run | model (APs kept) | σ̂0 px | c − fy px (σ; σ jackknife) | c % | x0 − true (σ; σ_J) | "
          "y0 − true (σ; σ_J) | \\|e\\|/σ c, x0, y0 | \\|e\\|/σ_J c, x0, y0 | σ verdict |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    verdicts = {True: "trusted", False: "not trusted", None: "not verified"}
    for label, r in rows.items():
        if "failed" in r:
            print(f"| {label} | failed: {r['failed'][:80]} |||||||||")
            continue
        c, x0, y0 = r["c"], r["x0"], r["y0"]

        def said(v):
            return f"{v[1]:+.2f} ({cell(v[2])}; {cell(v[3])})"
        print(f"| {label} | {r['model']} ({r['n_ap']}/{r['n_ap0']}) | {r['sigma0']:.3f} | {said(c)} | "
              f"{100 * c[1] / K[1, 1]:+.3f} | {said(x0)} | {said(y0)} | "
              f"{ratio(c[1], c[2])}, {ratio(x0[1], x0[2])}, {ratio(y0[1], y0[2])} | "
              f"{ratio(c[1], c[3])}, {ratio(x0[1], x0[3])}, {ratio(y0[1], y0[3])} | {verdicts[r['trusted']]} |")
    print("\n| run | export model | fx (σ) | fy (σ) | cx (σ) | cy (σ) | \\|e\\|/σ fx, fy, cx, cy | "
          "Δ over observed RMS / max px | vs true K RMS / max px | export misfit RMS / max px | "
          "centres RMS mm (ppm) | rotations RMS ° |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    truth = (K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    for label, r in rows.items():
        if "failed" in r:
            continue
        e = r["export"]
        est = (e["fx"], e["fy"], e["cx"], e["cy"])
        o = r["orientation"]
        print(f"| {label} | {e['model']} | " + " | ".join(f"{v:.2f} ({s:.2f})" for v, s in zip(est, e["sigma"])) +
              " | " + ", ".join(ratio(v - t, s) for v, t, s in zip(est, truth, e["sigma"])) +
              f" | {r['delta_rms']:.3f} / {r['delta_max']:.3f} | {r['truth_rms']:.2f} / {r['truth_max']:.2f} | "
              f"{e['misfit_rms_px']:.3f} / {e['misfit_max_px']:.3f} | {1000 * o[0]:.1f} ({1e6 * o[1]:.0f}) | "
              f"{o[2]:.4f} |")
    for label, r in peers.items():
        o = r["orientation"]
        print(f"| COLMAP {label} | {r['model']} k {np.round(r['k'], 5).tolist()} | {r['fx']:.2f} | {r['fy']:.2f} | "
              f"{r['cx']:.2f} | {r['cy']:.2f} | – | – | {r['truth_rms']:.2f} / {r['truth_max']:.2f} | – | "
              f"{1000 * o[0]:.1f} ({1e6 * o[1]:.0f}) | {o[2]:.4f} |")


def study_set(data: str, name: str, work: str, args) -> None:
    from selfcal.io.block_folder import read_block
    folder = os.path.join(data, name)
    truth = read_truth(folder)
    Ks = np.array([t[0] for t in truth.values()])
    K = Ks[0]
    if np.ptp(Ks, axis=0).max() > 1e-6:
        raise SystemExit(f"{name}: the images' K differ; this study assumes one camera")
    work = os.path.join(work, name)
    t0 = time.perf_counter()
    sparse, peer = colmap(os.path.join(folder, "images"), work, args.camera_model)
    selfcal = selfcal_command()
    block_dir = os.path.join(work, "block")
    run(selfcal + ["import", "colmap", sparse, "--out", block_dir, "--pixel-size-mm", str(PIXEL_MM), "--force",
                   "--quiet"])
    block = read_block(block_dir)
    cam = next(iter(block.cameras.values()))
    nodes = observed_nodes(block.observations.pixel, cam.width_px, cam.height_px)
    info = {"images": len(block.images), "points": len(block.points), "observations": len(block.observations),
            "camera_model": args.camera_model, "held": held_truth_sigma0(block, truth), "nodes": len(nodes)}
    groups = args.jackknife if args.jackknife is not None else len(block.images)
    rows = {}
    for label in args.models:
        res = os.path.join(work, "res-" + re.sub(r"[^a-z0-9]+", "-", label.lower()).strip("-"))
        t1 = time.perf_counter()
        try:
            run(selfcal + ["adjust", block_dir, "--out", res, "--no-report", "--force", "--quiet",
                           "--jackknife", str(groups)] + MODELS[label])
            rows[label] = study_results(res, block, truth, K, nodes)
        except RuntimeError as exc:
            rows[label] = {"failed": str(exc).splitlines()[0]}
        print(f"  {name} {label}: {time.perf_counter() - t1:.0f} s", file=sys.stderr)
    peers = {"mapper": peer_results(sparse, truth, K, nodes), "BA with pp": peer_results(peer, truth, K, nodes)}
    print_tables(name, K, info, rows, peers)
    if args.simulate:
        print("\n".join(simulated_at_real_geometry(block, truth, args.simulate, info["held"])))
    print(f"\n({name}: {time.perf_counter() - t0:.0f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="folder holding fountain-P11/ and Herz-Jesus-P8/ (images/, gt/)")
    parser.add_argument("--work", default=os.path.join("/tmp", "selfcal-known-camera"),
                        help="where COLMAP's and selfcal's outputs go (COLMAP's are reused)")
    parser.add_argument("--sets", default="fountain-P11,Herz-Jesus-P8")
    parser.add_argument("--camera-model", default="PINHOLE", choices=("PINHOLE", "SIMPLE_RADIAL"))
    parser.add_argument("--jackknife", type=int, default=None, help="groups (default: one per image; 0: none)")
    parser.add_argument("--simulate", type=int, default=5, metavar="N",
                        help="also adjust N noise seeds of the block's geometry with the true camera (0: none)")
    parser.add_argument("--models", default=",".join(MODELS),
                        help=f"selfcal runs, comma-separated, of: {', '.join(MODELS)}")
    args = parser.parse_args()
    args.models = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in args.models if m not in MODELS]
    if unknown:
        raise SystemExit(f"unknown run '{unknown[0]}' (known: {', '.join(MODELS)})")
    if not shutil.which("colmap"):
        raise SystemExit("COLMAP's command line is needed (Debian: apt install colmap)")
    for name in args.sets.split(","):
        study_set(args.data, name.strip(), args.work, args)


if __name__ == "__main__":
    main()
