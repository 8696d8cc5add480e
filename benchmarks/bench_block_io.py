"""Reading a block's observations: selfcal's block folder beside pycolmap reading the same observations as a
COLMAP model (issue 43 item 3, streaming input).

The synthetic strip blocks of bench_scaling.py (seed-000 simulator, 0.5 tie points per mm^2, Type 3, AP model none),
each written once (one process) as a block folder and as a COLMAP sparse model of the same images, points and
observations (binary, by selfcal's writer, and text, by pycolmap's). Each reading runs in a process of its own,
which measures its seconds and its peak resident memory above the interpreter with its modules loaded (so that the
import of NumPy or pycolmap is not counted): `selfcal.io.read_block` (observations.csv read a chunk of 2^16 rows at
a time), selfcal's COLMAP reader (`selfcal.io.colmap.read_colmap`, the whole file at once) on the binary and the
text model, and
`pycolmap.Reconstruction` (C++) on the binary and the text model. Printed: seconds and MB per million
observations, and selfcal's block folder against pycolmap's text and binary reading (ratios).

Run: ``python benchmarks/bench_block_io.py [--blocks 20x50,50x100]`` (STRIPSxIMAGES_PER_STRIP).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import selfcal  # noqa: F401  (before NumPy, as on the command line)
import numpy as np


def _rss_mb() -> float:
    """This process's resident memory now (/proc/self/statm)."""
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def _peak_mb() -> float:
    """The peak resident memory of this process (/proc's VmHWM: since the exec, not the parent's)."""
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _write(strips: int, per_strip: int, folder: str) -> dict:
    """The block folder and its COLMAP model (binary: selfcal's writer; text: pycolmap's)."""
    import pycolmap

    from selfcal.block import prune
    from selfcal.io import write_block
    from selfcal.io.colmap import ColmapCamera, ColmapModel, write_colmap_bin
    from selfcal.simulate import simulate_uav

    block = prune(simulate_uav(seed=1, distortion="none", points_per_mm2=0.5, n_strips=strips,
                               images_per_strip=per_strip).blocks["type3"])
    write_block(block, os.path.join(folder, "block"))
    camera = next(iter(block.cameras.values()))
    n_images, n_points = len(block.images.image_id), len(block.points.point_id)
    obs = block.observations
    xyz = np.where(np.isfinite(block.points.xyz_m), block.points.xyz_m, 0.0)
    model = ColmapModel(
        cameras={1: ColmapCamera(1, "SIMPLE_PINHOLE", camera.width_px, camera.height_px,
                                 {"f": 3000.0, "cx": camera.width_px / 2, "cy": camera.height_px / 2})},
        image_ids=np.arange(1, n_images + 1), image_names=np.array([f"{i}.jpg" for i in block.images.image_id]),
        image_camera=np.ones(n_images, int), qvec=np.tile([1.0, 0, 0, 0], (n_images, 1)),
        tvec=np.zeros((n_images, 3)), obs_image=obs.image_index + 1, obs_xy=obs.pixel,
        obs_point=obs.point_index + 1, point_ids=np.arange(1, n_points + 1), point_xyz=xyz,
        point_error=np.full(n_points, 0.5))
    os.makedirs(os.path.join(folder, "bin"))
    write_colmap_bin(os.path.join(folder, "bin"), model)
    os.makedirs(os.path.join(folder, "txt"))
    pycolmap.Reconstruction(os.path.join(folder, "bin")).write_text(os.path.join(folder, "txt"))
    sizes = {name: sum(os.path.getsize(os.path.join(folder, name, f)) for f in os.listdir(os.path.join(folder, name)))
             for name in ("block", "bin", "txt")}
    return {"images": n_images, "points": n_points, "observations": len(obs), "bytes": sizes}


def _read(how: str, folder: str) -> dict:
    """One reading in this process: seconds and peak MB above the modules loaded."""
    if how == "selfcal":
        from selfcal.io import read_block as reader
        path = os.path.join(folder, "block")
    elif how.startswith("selfcal-colmap"):
        from selfcal.io.colmap import read_colmap as reader
        path = os.path.join(folder, how.split("-")[2])
    else:
        import pycolmap
        reader = pycolmap.Reconstruction
        path = os.path.join(folder, how.split("-")[1])
    base = _rss_mb()
    start = time.perf_counter()
    reader(path)
    return {"seconds": time.perf_counter() - start, "peak_mb": _peak_mb() - base}


def _child(*args: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


READERS = ("selfcal", "selfcal-colmap-bin", "selfcal-colmap-txt", "pycolmap-bin", "pycolmap-txt")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blocks", default="20x50,50x100", help="STRIPSxIMAGES_PER_STRIP, comma-separated")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, *rest = args.child
        print(json.dumps(_write(int(rest[0]), int(rest[1]), rest[2]) if kind == "write" else _read(kind, rest[0])))
        return
    print(f"{'images':>7} {'observations':>12} | " + " | ".join(f"{r:>18} s  MB" for r in READERS)
          + " | block folder / pycolmap txt, bin: s, MB")
    for text in args.blocks.split(","):
        strips, per_strip = (int(v) for v in text.split("x"))
        folder = tempfile.mkdtemp(prefix="bench-block-io-")
        try:
            sizes = _child("write", str(strips), str(per_strip), folder)
            runs = {how: _child(how, folder) for how in READERS}
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        own, txt, binary = runs["selfcal"], runs["pycolmap-txt"], runs["pycolmap-bin"]
        print(f"{sizes['images']:>7} {sizes['observations']:>12} | "
              + " | ".join(f"{runs[r]['seconds']:>20.2f} {runs[r]['peak_mb']:>5.0f}" for r in READERS)
              + f" | {own['seconds'] / txt['seconds']:.2f} {own['peak_mb'] / txt['peak_mb']:.2f}, "
                f"{own['seconds'] / binary['seconds']:.2f} {own['peak_mb'] / binary['peak_mb']:.2f}")
        print(json.dumps({"sizes": sizes, "runs": runs}), file=sys.stderr)


if __name__ == "__main__":
    main()
