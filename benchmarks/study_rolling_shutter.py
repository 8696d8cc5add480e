"""Rolling-shutter cameras (issue 41): the in-adjustment model against today's global-shutter model, Brown + affinity,
and OpenDroneMap's two-step correction, on simulated blocks with known truth.

    python benchmarks/study_rolling_shutter.py [--seeds 10] [--density 1.0] [--flights serpentine,corridor]
                                               [--lens none,field] [--no-cost] [--coverage 30] [--sweep 3]
                                               [--global-only]

Blocks: seed 000's camera and terrain (selfcal.simulate.simulate_uav), flown ``serpentine`` (4 strips of 7 with a
fixed heading: the camera moves forwards on one strip, backwards on the next) or as a ``corridor`` (2 strips of 14
out and back), 8 m/s, a readout of 33 ms (the Phantom 4's in ODM's table), GNSS + IMU with strip-wise errors and 15
sparse GCP (scenario type2), 24 check points; ``--density`` image points per mm². Lens ``none``: no distortion, AP
none; ``field``: Brown's distortion and two local bumps (local+brown), wavelet APs (wavelet:db4). Every seed is
simulated twice, with the rolling shutter and with a global shutter: the same images, points, noise and trajectory.

Rows, per flight and lens (median and largest over the seeds of check-point RMSD / the global-shutter block's):

* ``model``: the rolling-shutter model (prior 30 +- 30 ms, the prior of a camera nobody measured), with the readout
  recovered against the truth (count of seeds within 2 sigma);
* ``global``: today's model on the rolling-shutter block; ``brown``: Brown + affinity (b1, b2) alone;
* ``odm``: OpenDroneMap's two-step correction as its documentation describes it - adjust as a global shutter, take
  each image's velocity from the adjusted poses of its strip's neighbours in time, move each observation to where
  the middle line's pose would have seen it, x + pi(X; C) - pi(X; C + v dt) with dt = (row - H/2)/H x readout and
  the tabulated readout (the truth: ODM's best case), and adjust again; ``ODM, 0.8x``: the same with a table value
  20 % short of the truth (a camera in another capture mode: ODM's table gives the Mavic 2 Pro 47 or 56 ms);
* on the global-shutter block: the model's readout within 2 sigma of 0 (count of seeds), screened out by ``--screen``
  (count), and the check points against today's (largest relative difference; screened: against today's screened
  adjustment, over all seeds and over those where the readout was screened out);
* on the rolling-shutter block with ``--screen``: the readout kept (count).

``--global-only``: only the global-shutter block's rows and the rolling-shutter block screened.

Then the readout's coverage: its z-scores over 30 more seeds (lens none); a sweep over the simulator's range of
readouts (20-75 ms) and speeds (5-12 m/s). Then the cost: the engine's time (and time per iteration) of the rolling-shutter model against the global-shutter
model on the same full-density block (80,000 image points).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from selfcal import bundle_adjust
from selfcal.adjust import AdjustOptions, APOptions, adjust
from selfcal.block import prune
from selfcal.sensors.frame import pixel_from_photo, project
from selfcal.sensors.rolling import line_share, strip_rates
from selfcal.simulate import simulate_uav

READOUT_MS = 33.0
SPEED_MPS = 8.0
#: ODM's two-step correction again with a table value this far from the truth (a camera in another capture mode)
TABLE_OFF = 0.8
LENSES = {"none": ("none", "none"), "field": ("local+brown", "wavelet:db4")}
FAST = {"robust": "none", "snoop": 0, "control_loo": False}


def global_shutter(block):
    """The block with its camera declared a global shutter (today's model)."""
    camera = next(iter(block.cameras.values()))
    return replace(block, cameras={camera.camera_id: replace(camera, shutter=None, readout_ms=None,
                                                             sigma_readout_ms=None)})


def odm_two_step(block, ap: str, readout_ms: float):
    """OpenDroneMap's correction: a global-shutter adjustment, then every observation moved to the middle line's pose
    with the tabulated readout and the velocities of the adjusted poses, then the adjustment again."""
    block = global_shutter(block)
    first = bundle_adjust(block, ap=ap, **FAST)
    result = first.result
    adjusted = result.block
    state = result.state
    image_of = {i: k for k, i in enumerate(adjusted.images.image_id)}
    point_of = {p: k for k, p in enumerate(adjusted.points.point_id)}
    # velocities from the adjusted poses of each strip's images, in time (ODM: the neighbouring shots)
    strips = np.asarray(adjusted.images.strip_id, object)
    velocity, _ = strip_rates(adjusted.images.time_s, state.image[:, :3], strips)
    camera = next(iter(adjusted.cameras.values()))
    iop = state.cameras[0][:3]
    obs = block.observations
    img = np.array([image_of.get(i, -1) for i in block.images.image_id[obs.image_index]])
    pt = np.array([point_of.get(p, -1) for p in block.points.point_id[obs.point_index]])
    use = (img >= 0) & (pt >= 0)
    dt = line_share(obs.pixel[use], camera.width_px, camera.height_px, "down") * readout_ms / 1000.0
    eop = state.image[img[use]]
    moved = eop.copy()
    moved[:, :3] += velocity[img[use]] * dt[:, None]
    frame = (camera.width_px, camera.height_px, camera.pixel_size_mm)
    middle = pixel_from_photo(project(state.points[pt[use]], eop, iop), *frame)
    line = pixel_from_photo(project(state.points[pt[use]], moved, iop), *frame)
    pixel = obs.pixel.copy()
    pixel[use] += middle - line
    corrected = replace(block, observations=replace(obs, pixel=pixel))
    return bundle_adjust(corrected, ap=ap, **FAST)


def _readout(outcome) -> tuple[float, float, float]:
    """The readout (ms), its sigma (with the images' spread: the velocities' errors) and the adjustment's own sigma
    (NaN where held)."""
    entry = outcome.files["camera.json"]["cameras"]["ilce7m3"]["readout_ms"]
    sigma = float(entry["sigma"]) if entry["sigma"] is not None else float("nan")
    return float(entry["value"]), sigma, float(entry.get("sigma_adjustment", sigma))


def _rmsd(outcome) -> np.ndarray:
    return np.array([outcome.summary["rmsd_chk_xy_m"], outcome.summary["rmsd_chk_z_m"]])


def _screened_readout(outcome) -> tuple[bool, str]:
    """Whether screening held the readout (at 0), and why (the decision's reason, or "kept")."""
    held = not outcome.files["camera.json"]["cameras"]["ilce7m3"]["readout_ms"]["estimated"]
    why = next((d["reason"] for d in outcome.files["screening.json"]["dropped"] if d["name"] == "readout"), "kept")
    return held, why


def study(flight: str, lens: str, seeds: int, density: float, global_only: bool = False) -> dict:
    """One flight and lens over ``seeds`` seeds; ``global_only``: only the rows of the global-shutter block and the
    rolling-shutter block screened (not the model against today's, Brown and ODM on the rolling-shutter block)."""
    distortion, ap = LENSES[lens]
    ratios: dict[str, list] = {k: [] for k in ("model", "global", "brown", "odm", "odm_off")}
    reference, readouts, zero, screened, today, rolling_screened = [], [], [], [], [], []
    for seed in range(seeds):
        kw = dict(seed=100 + seed, distortion=distortion, flight=flight, speed_mps=SPEED_MPS, points_per_mm2=density)
        rolling = simulate_uav(rolling_shutter_ms=READOUT_MS, **kw).blocks["type2"]
        taken_global = simulate_uav(**kw).blocks["type2"]
        t0 = time.perf_counter()
        line = f"  {flight:10s} {lens:5s} seed {100 + seed}:"
        if not global_only:
            gs = _rmsd(bundle_adjust(global_shutter(taken_global), ap=ap, **FAST))
            reference.append(gs)
            model = bundle_adjust(rolling, ap=ap, **FAST)
            ratios["model"].append(_rmsd(model) / gs)
            readouts.append(_readout(model))
            ratios["global"].append(_rmsd(bundle_adjust(global_shutter(rolling), ap=ap, **FAST)) / gs)
            ratios["brown"].append(_rmsd(bundle_adjust(global_shutter(rolling), ap="brown", **FAST)) / gs)
            ratios["odm"].append(_rmsd(odm_two_step(rolling, ap, READOUT_MS)) / gs)
            ratios["odm_off"].append(_rmsd(odm_two_step(rolling, ap, TABLE_OFF * READOUT_MS)) / gs)
            value, sigma, _ = readouts[-1]
            line += (f" GS XY {gs[0]:.4f} Z {gs[1]:.4f} m; model/GS {ratios['model'][-1][0]:.3f} "
                     f"{ratios['model'][-1][1]:.3f}, global {ratios['global'][-1][0]:.2f} "
                     f"{ratios['global'][-1][1]:.2f}, brown {ratios['brown'][-1][0]:.2f} {ratios['brown'][-1][1]:.2f}, odm {ratios['odm'][-1][0]:.3f} "
                     f"{ratios['odm'][-1][1]:.3f}; readout {value:.2f} +- {sigma:.2f} ms,")
        # the model on the global-shutter block
        declared = replace(taken_global, cameras=rolling.cameras)
        gs_model = bundle_adjust(declared, ap=ap, **FAST)
        zero.append(_readout(gs_model))
        if reference:
            today.append(np.abs(_rmsd(gs_model) / reference[-1] - 1.0))
        with_screen = bundle_adjust(declared, ap=ap, screen=True, **FAST)
        today_screened = bundle_adjust(global_shutter(taken_global), ap=ap, screen=True, **FAST)
        held, why = _screened_readout(with_screen)
        screened.append((held, float(np.max(np.abs(_rmsd(with_screen) / _rmsd(today_screened) - 1.0))), why))
        # the model on the rolling-shutter block, screened: the readout must stay
        rolling_screen = bundle_adjust(rolling, ap=ap, screen=True, **FAST)
        rolling_screened.append((*_screened_readout(rolling_screen), _readout(rolling_screen)[0]))
        print(f"{line} on the GS block {zero[-1][0]:+.2f} +- {zero[-1][1]:.2f}, screened: {why} (vs today's "
              f"{100 * screened[-1][1]:.4f} %); rolling block screened: {rolling_screened[-1][1]} "
              f"({rolling_screened[-1][2]:.2f} ms) ({time.perf_counter() - t0:.0f} s)", flush=True)
    return {"ratios": {k: np.array(v) for k, v in ratios.items()}, "readouts": np.array(readouts),
            "zero": np.array(zero), "screened": screened, "today": np.array(today), "reference": np.array(reference),
            "rolling_screened": rolling_screened}


def print_study(flight: str, lens: str, out: dict) -> None:
    n = len(out["zero"])
    print(f"\n{flight}, lens {lens} ({LENSES[lens][1]} APs), {n} seeds: check-point RMSD / the global-shutter block's "
          f"(median, max)")
    if len(out["readouts"]):
        print(f"  {'':8s} {'XY median':>10s} {'XY max':>8s} {'Z median':>10s} {'Z max':>8s}  within 1.15x (XY and Z)")
        for row, label in (("model", "model"), ("global", "no model"), ("brown", "brown+aff"),
                           ("odm", "ODM 2-step"), ("odm_off", f"ODM, {TABLE_OFF:g}x")):
            r = out["ratios"][row]
            inside = int(np.sum((r[:, 0] <= 1.15) & (r[:, 1] <= 1.15)))
            print(f"  {label:10s} {np.median(r[:, 0]):8.3f} {r[:, 0].max():8.3f} {np.median(r[:, 1]):10.3f} "
                  f"{r[:, 1].max():8.3f}  {inside}/{n}")
        value, sigma, sigma_adjustment = out["readouts"].T
        within = int(np.sum(np.abs(value - READOUT_MS) <= 2 * sigma))
        print(f"  readout: mean {value.mean():.3f} ms (truth {READOUT_MS:g}), sd over seeds {value.std(ddof=1):.3f}, "
              f"mean sigma {sigma.mean():.3f} (the adjustment's {sigma_adjustment.mean():.3f}); within 2 sigma of the "
              f"truth in {within}/{n} ({int(np.sum(np.abs(value - READOUT_MS) <= 2 * sigma_adjustment))}/{n} with the "
              f"adjustment's sigma)")
    z_value, z_sigma, _ = out["zero"].T
    unscreened = (f"; check points against today's (no screening): largest |difference| "
                  f"{100 * out['today'].max():.2f} %") if len(out["today"]) else ""
    print(f"  global-shutter block: readout {z_value.mean():+.3f} ms (sd {z_value.std(ddof=1):.3f}, mean sigma "
          f"{z_sigma.mean():.3f}), within 2 sigma of 0 in {int(np.sum(np.abs(z_value) <= 2 * z_sigma))}/{n}"
          f"{unscreened}")
    held = sum(h for h, _, _ in out["screened"])
    worst = max(d for _, d, _ in out["screened"])
    worst_held = max((d for h, d, _ in out["screened"] if h), default=float("nan"))
    reasons = sorted({why.split(" (")[0].split(" px")[0] for h, _, why in out["screened"] if h})
    print(f"  with --screen: readout screened out in {held}/{n} ({'; '.join(reasons) or 'none'}); check points "
          f"against today's screened adjustment: largest |difference| {100 * worst:.4f} % ({100 * worst_held:.4f} % "
          f"where screened out)")
    kept = [value for h, _, value in out["rolling_screened"] if not h]
    print(f"  rolling-shutter block with --screen: readout kept in {len(kept)}/{n}"
          + (f" ({min(kept):.2f}-{max(kept):.2f} ms)" if kept else ""))


def acceptance(results: dict) -> None:
    """Issue 41's acceptance, one row per flight and lens."""
    print("\nacceptance (issue 41), per flight and lens over the seeds:")
    print(f"  {'flight, lens':18s} {'model within 1.15x':>18s} {'readout within 2 sigma':>22s} "
          f"{'GS: screened out or within 2 sigma':>34s} {'GS, screened: vs today':>22s} {'(where out)':>11s} "
          f"{'RS, screened: kept':>18s}")
    for (flight, lens), out in results.items():
        n = len(out["zero"])
        if len(out["readouts"]):
            r = out["ratios"]["model"]
            inside = f"{int(np.sum((r[:, 0] <= 1.15) & (r[:, 1] <= 1.15)))}/{n}"
            value, sigma, _ = out["readouts"].T
            within = f"{int(np.sum(np.abs(value - READOUT_MS) <= 2 * sigma))}/{n}"
        else:
            inside = within = "-"
        z_value, z_sigma, _ = out["zero"].T
        held = np.array([h for h, _, _ in out["screened"]])
        zero = int(np.sum(held | (np.abs(z_value) <= 2 * z_sigma)))
        worst = max(d for _, d, _ in out["screened"])
        worst_held = max((d for h, d, _ in out["screened"] if h), default=float("nan"))
        kept = sum(not h for h, _, _ in out["rolling_screened"])
        print(f"  {flight + ', ' + lens:18s} {inside:>18s} {within:>22s} {zero:>31d}/{n} "
              f"{100 * worst:>19.3f} % {100 * worst_held:>9.3f} % {kept:>15d}/{n}")


def coverage(seeds: int, density: float = 0.6) -> None:
    """How often the readout lies within 2 sigma of the truth over many seeds (lens none, AP none): the z-scores
    (estimate - truth) / sigma of the rolling-shutter and of the global-shutter blocks, per flight, with the sigma
    of the results (the images' spread added) and the adjustment's alone. At 95.4 % coverage 2 or more of 10 seeds
    miss with a probability of 7 %, 3 or more of 30 with 16 %."""
    print(f"\ncoverage over {seeds} seeds (200...), {density} points per mm^2, lens none: z = (readout - truth) / sigma")
    for flight in ("serpentine", "corridor"):
        for label, truth in (("rolling shutter", READOUT_MS), ("global shutter", 0.0)):
            z, z_adjustment, spread = [], [], []
            for seed in range(200, 200 + seeds):
                kw = dict(seed=seed, distortion="none", flight=flight, speed_mps=SPEED_MPS, points_per_mm2=density)
                rolling = simulate_uav(rolling_shutter_ms=READOUT_MS, **kw).blocks["type2"]
                block = rolling if truth else replace(simulate_uav(**kw).blocks["type2"], cameras=rolling.cameras)
                outcome = bundle_adjust(block, ap="none", **FAST)
                value, sigma, sigma_adjustment = _readout(outcome)
                z.append((value - truth) / sigma)
                z_adjustment.append((value - truth) / sigma_adjustment)
                spread.append(outcome.files["camera.json"]["cameras"]["ilce7m3"]["readout_ms"]
                              ["spread_between_images"])
            z, z_adjustment = np.array(z), np.array(z_adjustment)
            print(f"  {flight:10s} {label:15s} mean z {z.mean():+.2f}, sd z {z.std(ddof=1):.2f}, within 2 sigma "
                  f"{int(np.sum(np.abs(z) <= 2))}/{seeds}; with the adjustment's sigma: sd "
                  f"{z_adjustment.std(ddof=1):.2f}, {int(np.sum(np.abs(z_adjustment) <= 2))}/{seeds}; spread between "
                  f"images median {np.median(spread):.3f} ms", flush=True)


def sweep(seeds: int, density: float = 0.6) -> None:
    """The simulator's range (readouts 20-75 ms at 5-12 m/s), lens none, AP none: the model's check points against the
    global-shutter block's, today's model's, and the readout against the truth."""
    print(f"\nsweep over readout and speed, {seeds} seeds (300...), {density} points per mm^2, lens none: check-point "
          f"RMSD / the global-shutter block's (XY, Z; largest over the seeds), readout - truth in sigma (largest |z|)")
    for flight in ("serpentine", "corridor"):
        for readout, speed in ((20.0, 5.0), (33.0, 8.0), (50.0, 10.0), (75.0, 12.0)):
            model, blind, z = [], [], []
            for seed in range(300, 300 + seeds):
                kw = dict(seed=seed, distortion="none", flight=flight, speed_mps=speed, points_per_mm2=density)
                rolling = simulate_uav(rolling_shutter_ms=readout, **kw).blocks["type2"]
                gs = _rmsd(bundle_adjust(simulate_uav(**kw).blocks["type2"], ap="none", **FAST))
                outcome = bundle_adjust(rolling, ap="none", **FAST)
                model.append(_rmsd(outcome) / gs)
                blind.append(_rmsd(bundle_adjust(global_shutter(rolling), ap="none", **FAST)) / gs)
                value, sigma, _ = _readout(outcome)
                z.append((value - readout) / sigma)
            model_max, blind_max = np.max(model, axis=0), np.max(blind, axis=0)
            print(f"  {flight:10s} {readout:4.0f} ms {speed:4.0f} m/s: model {model_max[0]:.3f} {model_max[1]:.3f}, "
                  f"no model {blind_max[0]:.2f} {blind_max[1]:.2f}; readout |z| <= {np.max(np.abs(z)):.2f}",
                  flush=True)


def cost(repeats: int = 2) -> None:
    """Engine time of the rolling-shutter model against the global-shutter model on the same block (full density),
    the best of ``repeats`` runs each."""
    print("\ncost: selfcal.adjust.adjust on the serpentine block, 3.5 points per mm^2 (best of "
          f"{repeats}; per iteration in brackets)")
    rolling = prune(simulate_uav(seed=100, distortion="none", flight="serpentine", rolling_shutter_ms=READOUT_MS)
                    .blocks["type2"])
    taken_global = prune(simulate_uav(seed=100, distortion="none", flight="serpentine").blocks["type2"])
    for label, block in (("rolling-shutter block", rolling), ("global-shutter block", taken_global)):
        for ap in ("none", "brown"):
            times = {}
            for model, b in (("global", global_shutter(block)), ("rolling", replace(block, cameras=rolling.cameras))):
                best = None
                for _ in range(repeats):
                    result = adjust(b, AdjustOptions(ap=APOptions(ap)))
                    if best is None or result.seconds < best[0]:
                        best = (result.seconds, result.iterations)
                times[model] = best
            (tg, ig), (tr, ir) = times["global"], times["rolling"]
            print(f"  {label:22s} ap {ap:6s} global {tg:6.2f} s ({ig} it, {tg / ig:.3f} s/it)  rolling {tr:6.2f} s "
                  f"({ir} it, {tr / ir:.3f} s/it)  ratio {tr / tg:.2f} (per iteration {tr / ir / (tg / ig):.2f})",
                  flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--density", type=float, default=1.0, help="image points per mm² (default 1)")
    parser.add_argument("--flights", default="serpentine,corridor")
    parser.add_argument("--lens", default="none,field")
    parser.add_argument("--no-cost", action="store_true")
    parser.add_argument("--global-only", action="store_true",
                        help="only the global-shutter block's rows and the rolling-shutter block screened")
    parser.add_argument("--coverage", type=int, default=30, metavar="N",
                        help="seeds of the readout's coverage study (0: none; default 30)")
    parser.add_argument("--sweep", type=int, default=3, metavar="N",
                        help="seeds of the sweep over readouts 20-75 ms and speeds 5-12 m/s (0: none; default 3)")
    args = parser.parse_args(argv)
    results = {}
    for flight in args.flights.split(","):
        for lens in args.lens.split(","):
            results[flight, lens] = study(flight, lens, args.seeds, args.density, args.global_only)
    for (flight, lens), out in results.items():
        print_study(flight, lens, out)
    acceptance(results)
    if args.coverage:
        coverage(args.coverage)
    if args.sweep:
        sweep(args.sweep)
    if not args.no_cost:
        cost()
    return 0


if __name__ == "__main__":
    sys.exit(main())
