"""selfcal beside COLMAP's bundle adjuster on a real reconstruction (Coal Oil Point Reserve).

The COLMAP model in ../shared/data/copr/sparse (38 images, 65,371 points, 313,672
observations, one OPENCV camera) is refined twice from the same start:

* by pycolmap's bundle adjuster (Ceres), camera model OPENCV (fx, fy, cx, cy, k1,
  k2, p1, p2), focal length, principal point and distortion refined, squared loss;
* by selfcal with the ``brown`` APs (c, x0, y0, k1, k2, k3, p1, p2, b1, b2), as a
  free network (no control), without data snooping, from the import's initial
  Brown values.

Both reprojection errors are measured on the same observations: those of the
imported block (a point observed twice in one image keeps its first
observation; 0.8 % of COLMAP's are such repeats), each projected by the
refined model of each program. RMS = sqrt(mean(|v|^2)) in pixels.

Run: ``make bench`` or ``python benchmarks/bench_colmap.py``.
"""
from __future__ import annotations

import os
import time
from dataclasses import replace

import numpy as np

COPR = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "copr", "sparse")
PIXEL_MM = 0.0052


def selfcal_run(path: str):
    from selfcal.adjust import adjust, AdjustOptions, APOptions
    from selfcal.block import prune
    from selfcal.convert import block_from_colmap
    from selfcal.io.colmap import read_colmap

    block, _ = block_from_colmap(read_colmap(path), None, pixel_size_mm=PIXEL_MM)
    block = prune(replace(block, datum="free"))
    start = time.perf_counter()
    result = adjust(block, AdjustOptions(ap=APOptions("brown")))
    seconds = time.perf_counter() - start
    v_px = result.residuals_px
    return block, float(np.sqrt(np.mean(np.sum(v_px ** 2, axis=1)))), seconds, result.iterations


def pycolmap_run(path: str, block):
    import pycolmap

    reconstruction = pycolmap.Reconstruction(path)
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_principal_point = True
    options.print_summary = False
    start = time.perf_counter()
    pycolmap.bundle_adjustment(reconstruction, options)
    seconds = time.perf_counter() - start
    by_name = {image.name: image for image in reconstruction.images.values()}
    obs = block.observations
    squares = 0.0
    for k, name in enumerate(block.images.image_id):
        sel = obs.image_index == k
        image = by_name[name]
        ids = [int(str(p)[len("colmap"):]) for p in block.points.point_id[obs.point_index[sel]]]
        xyz = np.array([reconstruction.points3D[i].xyz for i in ids])
        projected = image.camera.img_from_cam(image.cam_from_world() * xyz)
        squares += float(np.sum((projected - obs.pixel[sel]) ** 2))
    return float(np.sqrt(squares / len(obs.pixel))), seconds


def main() -> None:
    path = os.path.abspath(COPR)
    block, rms_selfcal, t_selfcal, iterations = selfcal_run(path)
    rms_colmap, t_colmap = pycolmap_run(path, block)
    print(f"COPR: {len(block.images)} images, {len(block.points)} points, {len(block.observations)} observations "
          f"(the same for both)")
    print(f"{'engine':<34} {'reprojection RMS [px]':>22} {'seconds':>8}")
    print(f"{'pycolmap (Ceres), OPENCV':<34} {rms_colmap:>22.4f} {t_colmap:>8.1f}")
    print(f"{'selfcal brown, free network':<34} {rms_selfcal:>22.4f} {t_selfcal:>8.1f}  ({iterations} iterations)")
    print(f"ratio selfcal / pycolmap: reprojection RMS {rms_selfcal / rms_colmap:.4f}, "
          f"time {t_selfcal / t_colmap:.2f}")


if __name__ == "__main__":
    main()
