"""A block in a projected CRS adjusted in its local tangent plane against the projection taken as Cartesian (issue
44 item 4, DESIGN.md §2).

Seed 000's simulated block, ten times enlarged (9 x 5 km, 2150 m above ground, 360 m of relief, GSD 0.6 m), placed
in UTM 33N 255 km east of the central meridian (k = 1.0004, meridian convergence 2.3 degrees) at 400 m above the
ellipsoid (:func:`selfcal.simulate.projected.place_in_crs`): control and check points given in UTM + ellipsoidal
height. Each block is adjusted twice: as it is (``crs = "EPSG:32633"``: in the tangent plane, results written back
in UTM) and with ``crs = "local"`` (the projection taken as a Cartesian frame: what selfcal did before). The
check points' errors are taken against the truth in UTM (not the noisy references), so the projection's error is
seen apart from the survey's.

Two settings: ``exact``, control without survey error, 0.02 px of image noise, GNSS 1 cm / IMU 0.001 deg
without shift (the projection's error alone), and ``real``, the simulation's own noise (0.5 px, marks 17/29 mm
x 10, GNSS 5/10 cm x 10 with strip shifts); each with the interior orientation held at the truth (a calibrated
camera) and estimated (c, x0, y0 free).

    python benchmarks/study_tangent_plane.py [--seeds 3]
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from selfcal import bundle_adjust
from selfcal.simulate import simulate_uav
from selfcal.simulate.projected import place_in_crs

CRS, LON, LAT, HEIGHT_M, SCALE = "EPSG:32633", 18.24, 45.1, 400.0, 10.0


def _simulation(seed: int, setting: str):
    if setting == "exact":
        sim = simulate_uav(seed=seed, distortion="none", points_per_mm2=0.3, image_sigma_px=0.02, gnss_shift_m=0.0,
                           gnss_drift_mm_s=0.0, imu_shift_deg=0.0, gnss_sigma_m=(0.001,) * 3,
                           imu_sigma_deg=(1e-4,) * 3)
    else:
        sim = simulate_uav(seed=seed, distortion="none", points_per_mm2=0.3)
    return place_in_crs(sim, CRS, LON, LAT, HEIGHT_M, SCALE)[0]


def _block(placed, scenario: str, setting: str, iop: str):
    truth = placed.truth
    block = placed.blocks[scenario]
    if setting == "exact":
        marks = block.points.role != "tie"
        block = replace(block, points=replace(
            block.points, xyz_m=np.where(marks[:, None], truth.xyz, np.nan),
            sigma_m=np.where(marks[:, None], np.full(truth.xyz.shape, 0.005), np.nan)))
    if iop == "held":
        camera = replace(truth.camera, sigma_focal_mm=0.0, sigma_x0_mm=0.0, sigma_y0_mm=0.0)
        block = replace(block, cameras={camera.camera_id: camera})
    return block


def _check_errors(outcome, truth) -> np.ndarray:
    header, columns, _ = outcome.files["points.csv"]
    c = dict(zip(header, columns))
    where = {p: k for k, p in enumerate(truth.point_id)}
    chk = np.flatnonzero(c["role"] == "chk")
    return np.column_stack([c["X"], c["Y"], c["Z"]])[chk] - truth.xyz[[where[p] for p in c["point_id"][chk]]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    seeds = range(1, parser.parse_args().seeds + 1)
    print(f"{'setting':6s} {'IOP':5s} {'type':6s} | check points against the truth in UTM, RMSD XY / Z (m), mean "
          f"over {len(seeds)} seeds | sigma0 (px)\n{'':20s} | {'tangent plane':>17s} {'projection':>17s} "
          f"{'ratio Z':>8s} | plane  projection")
    for setting in ("exact", "real"):
        sims = {seed: _simulation(seed, setting) for seed in seeds}
        for iop in ("held", "free"):
            for scenario in ("type1", "type2", "type3"):
                rows = {"plane": [], "projection": []}
                for seed, placed in sims.items():
                    block = _block(placed, scenario, setting, iop)
                    for label, b in (("plane", block), ("projection", replace(block, crs="local"))):
                        out = bundle_adjust(b, "none", control_loo=False,
                                            **({"robust": "none", "snoop": 0, "gnss_drift": -1, "imu_drift": -1}
                                               if setting == "exact" else {}))
                        d = _check_errors(out, placed.truth)
                        rows[label].append((np.sqrt(np.mean(np.sum(d[:, :2] ** 2, 1))), np.sqrt(np.mean(d[:, 2] ** 2)),
                                            out.summary["sigma0_px"]))
                p, q = np.mean(rows["plane"], axis=0), np.mean(rows["projection"], axis=0)
                print(f"{setting:6s} {iop:5s} {scenario:6s} | {p[0]:8.4f} {p[1]:8.4f} {q[0]:8.4f} {q[1]:8.4f} "
                      f"{q[1] / p[1]:8.2f} | {p[2]:.4f} {q[2]:.4f}", flush=True)


if __name__ == "__main__":
    main()
