"""`selfcal plan` against the run it plans: predicted and measured peak memory and seconds per iteration.

The synthetic frame blocks of bench_scaling.py (seed-000 simulator, more and longer strips, 0.5 tie points per
mm^2, Type 3 control, no distortion, AP model none) from 28 to 2000 images, then two blocks of another density
(OTHER_BLOCKS), which the constants were not fitted on. Each block is written once as a block folder (one process);
another plans it (:func:`selfcal.workflows.plan.plan_block`, no adjustment) and a third adjusts it from the folder
as the engine of ``selfcal adjust`` does, with the sigma of every unknown (Q_theta, the image sigma, every point's
covariance), so that its peak resident memory (``resource.getrusage``'s ru_maxrss) is its own. Printed side by
side: predicted and measured peak MB and median seconds per iteration, with their ratios (issue 43 asks within
20 %), and the factorisation and covariance paths; each block's details as JSON on stderr.

``--lattice STRIPS PER_STRIP ALONG ACROSS`` measures instead the image graph of a lattice strip block as the plan
measures a block's (pairs, band, CHOLMOD's factor): the paper estimate of DESIGN-NOTES (issue 43 item 4).

``--workflow`` measures instead ``selfcal adjust BLOCK`` with its default options (the tested workflow and the report)
against the plan's ``workflow_peak_mb``.

``--ap MODEL`` plans and adjusts that AP model (a wavelet on 9x6) instead of none (with ``--workflow``: instead of
``selfcal adjust``'s default).

The adjustment's resident memory is also sampled every 20 ms: its peak during the iterations and during the
covariance after them (Q_theta, the points' cofactors) are printed beside the peak.

Run: ``python benchmarks/bench_plan.py [--largest 2000] [--blocks 4x7,14x36@1.0] [--workflow] [--ap MODEL]``.
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
from pathlib import Path

import selfcal  # noqa: F401  (before NumPy, as on the command line: it sets OpenBLAS's thread timeout)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scaling import BLOCKS  # noqa: E402  (the same blocks)

#: blocks of another tie-point density, which the constants were not fitted on: (strips, images per strip, points
#: per mm^2)
OTHER_BLOCKS = [(14, 36, 1.0), (40, 50, 0.25)]


def _block(n_strips: int, per_strip: int, points_per_mm2: float = 0.5):
    """bench_scaling.py's block (its density by default)."""
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav

    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=points_per_mm2, n_strips=n_strips,
                       images_per_strip=per_strip)
    return prune(sim.blocks["type3"])


def _write_child(n_strips: int, per_strip: int, points_per_mm2: float, folder: str) -> dict:
    """Simulate one block and write it as a block folder (the plan and the adjustment read it, as the CLI does)."""
    from selfcal.io import write_block

    write_block(_block(n_strips, per_strip, points_per_mm2), folder)
    return {"folder": folder}


class _RSSSampler:
    """The resident memory of this process sampled every 20 ms on a thread of its own, to tell the peak of the
    iterations from that of the covariance after them (issue 43: which parts of the plan are alive together)."""

    def __init__(self):
        import threading

        self.samples: list[tuple[float, float]] = []
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        page_mb = os.sysconf("SC_PAGE_SIZE") / 2.0 ** 20
        while self.running:
            with open("/proc/self/statm") as handle:
                self.samples.append((time.perf_counter(), int(handle.read().split()[1]) * page_mb))
            time.sleep(0.02)

    def stop(self, split: float) -> dict:
        """The peak RSS (MB) sampled up to ``split`` (the last iteration's end) and after it."""
        self.running = False
        self.thread.join()
        before = [r for t, r in self.samples if t <= split]
        after = [r for t, r in self.samples if t > split]
        return {"iterations": max(before, default=float("nan")), "covariance": max(after, default=float("nan"))}


def _adjust_child(folder: str, ap: str | None = None) -> dict:
    """Adjust one block folder with the sigma of every unknown (AP model ``ap``: none by default, a wavelet on 9x6);
    its peak RSS and seconds per iteration."""
    from selfcal.adjust import AdjustOptions, APOptions, adjust
    from selfcal.allocator import keep_freed_memory
    from selfcal.io import read_block

    keep_freed_memory()                 # as the CLI does
    from selfcal.stats.plan import machine_speed

    block = read_block(folder)
    speed = machine_speed()             # the probe, as the plan takes it
    stamps: list[float] = []
    options = AdjustOptions() if ap is None else AdjustOptions(ap=APOptions(ap))
    samples = _RSSSampler()
    result = adjust(block, options, progress=lambda record: stamps.append(time.perf_counter()))
    iterated = stamps[-1] if stamps else time.perf_counter()
    result.Q_points                     # the points' cofactors, made on first use
    sigma_ok = bool(np.all(np.isfinite(result.image_sigma())) and np.all(np.isfinite(result.point_covariance())))
    phases = samples.stop(iterated)
    per_iteration = float(np.median(np.diff(stamps))) if len(stamps) > 1 else float("nan")
    # ru_maxrss also holds the peak of the process this one was forked from (Linux keeps it over the exec): the bench's
    # parent, about 100 MB, below every block's peak; tests/test_plan.py, run inside pytest, reads /proc's VmHWM
    return {"images": len(block.images), "observations": len(block.observations), "iterations": result.iterations,
            "seconds_per_iteration": per_iteration, "sigma_ok": sigma_ok, "phase_peaks_mb": phases,
            "machine_speed": speed, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def _workflow_child(folder: str, ap: str | None = None) -> dict:
    """``selfcal adjust FOLDER`` with its default options (the tested workflow and the report; ``--ap ap`` where
    given), in this process: its peak resident memory (/proc's VmHWM, the peak since the exec) against the plan's
    ``workflow_peak_mb``."""
    from selfcal.cli.main import main as selfcal_main
    from selfcal.io import read_block
    from selfcal.workflows.plan import plan_block

    block = read_block(folder)
    planned = plan_block(block, ap=ap, probe=False).workflow_peak_mb
    out = tempfile.mkdtemp(prefix="bench-plan-results-")
    t = time.perf_counter()
    code = selfcal_main(["adjust", folder, "--out", os.path.join(out, "results"), "--quiet"]
                        + ([] if ap is None else ["--ap", ap]))
    seconds = time.perf_counter() - t
    shutil.rmtree(out)
    peak = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM")) / 1024.0
    return {"images": len(block.images), "observations": len(block.observations), "exit": code,
            "workflow_peak_mb": peak, "planned_workflow_peak_mb": planned, "seconds": seconds}


def _plan_child(folder: str, ap: str | None = None) -> dict:
    from selfcal.io import read_block
    from selfcal.workflows.plan import plan_block

    t = time.perf_counter()
    plan = plan_block(read_block(folder), ap=ap or "none")
    return {**plan.as_dict(), "plan_seconds": time.perf_counter() - t}


def _lattice_child(n_strips: int, per_strip: int, along: int, across: int) -> dict:
    """The image graph of a strip block as a lattice (each image joined to the images within ``along`` positions in
    its strip and ``across`` strips), measured as the plan measures a block's: its pairs, band and CHOLMOD factor."""
    import scipy.sparse as sp

    from selfcal.workflows.plan import image_graph_sizes

    t = time.perf_counter()
    strip, position = np.meshgrid(np.arange(n_strips), np.arange(per_strip), indexing="ij")
    index = strip * per_strip + position
    rows, cols = [], []
    for ds in range(0, across + 1):
        for da in range(-along, along + 1):
            if ds == 0 and da <= 0:
                continue
            ok = (strip + ds < n_strips) & (position + da >= 0) & (position + da < per_strip)
            rows.append(index[ok])
            cols.append(index[strip[ok] + ds, position[ok] + da])
    a, b = np.concatenate(rows), np.concatenate(cols)
    # one "point" per pair: the incidence of pairs reproduces the graph exactly
    n_pairs = a.size
    obs_image = np.concatenate([a, b])
    obs_point = np.concatenate([np.arange(n_pairs), np.arange(n_pairs)])
    sizes = image_graph_sizes(obs_image, obs_point, n_strips * per_strip, n_pairs)
    return {"images": n_strips * per_strip, **sizes, "seconds": time.perf_counter() - t,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def _run(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write-child", nargs=4)
    parser.add_argument("--lattice", nargs=4, type=int, metavar=("STRIPS", "PER_STRIP", "ALONG", "ACROSS"),
                        help="measure the image graph of a lattice strip block instead (the paper estimate's fill)")
    parser.add_argument("--adjust-child")
    parser.add_argument("--plan-child")
    parser.add_argument("--workflow-child")
    parser.add_argument("--workflow", action="store_true",
                        help="measure `selfcal adjust BLOCK` with its default options instead (the plan's workflow peak)")
    parser.add_argument("--largest", type=int, default=2000, help="largest block in images (default 2000)")
    parser.add_argument("--ap", help="the AP model planned and adjusted (default: none; with --workflow, selfcal "
                                     "adjust's default), e.g. wavelet:db4 (on 9x6)")
    parser.add_argument("--blocks", help="strips x images per strip [@ points per mm^2], e.g. 4x7,14x36@1.0 (default: "
                                         "bench_scaling's at 0.5, then OTHER_BLOCKS)")
    args = parser.parse_args()
    if args.write_child:
        strips, per_strip, density, folder = args.write_child
        print(json.dumps(_write_child(int(strips), int(per_strip), float(density), folder)))
        return
    if args.lattice:
        print(json.dumps(_lattice_child(*args.lattice)))
        return
    if args.adjust_child:
        print(json.dumps(_adjust_child(args.adjust_child, args.ap)))
        return
    if args.plan_child:
        print(json.dumps(_plan_child(args.plan_child, args.ap)))
        return
    if args.workflow_child:
        print(json.dumps(_workflow_child(args.workflow_child, args.ap)))
        return
    model = [] if args.ap is None else ["--ap", args.ap]
    if args.blocks:
        blocks = []
        for text in args.blocks.split(","):
            size, _, density = text.partition("@")
            strips, per_strip = size.split("x")
            blocks.append((int(strips), int(per_strip), float(density or 0.5)))
    else:
        blocks = [(s, p, 0.5) for s, p in BLOCKS if s * p <= args.largest]
        blocks += [b for b in OTHER_BLOCKS if b[0] * b[1] <= args.largest]
    print(f"load average at the start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    work = tempfile.mkdtemp(prefix="bench-plan-")
    if args.workflow:
        print(f"{'images':>7}{'pts/mm2':>8}{'obs.':>9}{'workflow peak MB pred.':>23}{'meas.':>8}{'ratio':>7}{'s':>8}")
        for strips, per_strip, density in blocks:
            folder = os.path.join(work, f"block-{strips}x{per_strip}@{density}")
            _run(["--write-child", str(strips), str(per_strip), str(density), folder])
            m = _run(["--workflow-child", folder, *model])
            shutil.rmtree(folder)
            print(f"{m['images']:>7}{density:>8.2f}{m['observations']:>9}{m['planned_workflow_peak_mb']:>23.0f}"
                  f"{m['workflow_peak_mb']:>8.0f}{m['planned_workflow_peak_mb'] / m['workflow_peak_mb']:>7.2f}"
                  f"{m['seconds']:>8.1f}" + ("" if m["exit"] == 0 else f"  (exit {m['exit']})"), flush=True)
        return
    print(f"{'images':>7}{'pts/mm2':>8}{'obs.':>9}{'path':>26}{'peak MB pred.':>14}{'meas.':>8}{'ratio':>7}"
          f"{'s/iter. pred.':>14}{'meas.':>8}{'ratio':>7}{'MB iterations / covariance':>28}")
    for strips, per_strip, density in blocks:
        folder = os.path.join(work, f"block-{strips}x{per_strip}@{density}")
        _run(["--write-child", str(strips), str(per_strip), str(density), folder])
        p = _run(["--plan-child", folder, *model])
        m = _run(["--adjust-child", folder, *model])
        shutil.rmtree(folder)
        path = f"{p['factorisation']} {p['covariance']}"
        print(f"{m['images']:>7}{density:>8.2f}{m['observations']:>9}{path:>26}{p['peak_mb']:>14.0f}{m['peak_mb']:>8.0f}"
              f"{p['peak_mb'] / m['peak_mb']:>7.2f}{p['seconds_per_iteration']:>14.3f}"
              f"{m['seconds_per_iteration']:>8.3f}{p['seconds_per_iteration'] / m['seconds_per_iteration']:>7.2f}"
              f"{m['phase_peaks_mb']['iterations']:>17.0f} / {m['phase_peaks_mb']['covariance']:<8.0f}"
              + ("" if m["sigma_ok"] else "  (sigma not finite)"), flush=True)
        print("  " + json.dumps({"measured": m, "planned": p}), file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
