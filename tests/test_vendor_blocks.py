"""Vendor line cameras in block folders (``model = "dg"``: DigitalGlobe / Maxar XML; ``model = "dimap"``: Pleiades
and SPOT 5 DIMAP), through ``selfcal adjust``: truth on the vendors' own metadata files
(../shared/data/pushbroom: ASP's DG and SPOT test files, CNES's Pleiades DIMAP), and the block's errors.

Truth: each image's attitude gets a known roll, pitch and yaw bias (seed 001's d_roll0, d_pitch0, d_yaw0), ground
points are put where the *biased* camera sees a pixel grid (heights spread over 0-300 m), their image
coordinates get 0.1 px noise and their coordinates 0.05 m, and the block folder (points as 0.05 m control, the
sensor files as they are) goes through the command line with sensor model M2 (M1 for the SPOT 5 crop), the
vendor's focal length kept. The biases come back within 4 sigma, sigma0 near 1 (measured: every bias within
2.2 sigma; roll and pitch to 0.02 urad (DG, Pleiades) and 0.07-0.17 urad (SPOT 5), yaw to 2 urad; sigma0
0.089-0.098 px).
"""
import csv
import json
import os

import numpy as np
import pytest

from selfcal.errors import BlockError
from selfcal.io import read_block
from selfcal.sensors.pushbroom import PARAMETER_NAMES, ground_to_image, image_to_ground
from selfcal.sensors.vendor import line_image_from_file

from conftest import SHARED_DATA, run_cli

DATA = os.path.join(SHARED_DATA, "pushbroom")
DG = os.path.join(DATA, "asp_dg_spot")
CASES = {
    # model, [(image id, file)], seed 001's sensor model: a DigitalGlobe stereo pair, a Pleiades primary image, a
    # SPOT 5 scene cut by ASP to 300 of its 12000 detectors: one line of sight, about which no rotation shows,
    # so roll, pitch and yaw are one too many (correlations 0.9999); M1, roll and pitch
    "dg-stereo": ("dg", [("left", os.path.join(DG, "dg_example1.xml")), ("right", os.path.join(DG, "dg_example2.xml"))],
                  "M2"),
    "pleiades": ("dimap", [("phr", os.path.join(DATA, "pleiades", "rpc", "PHRDIMAP_P1BP--2017030824934340CP.XML"))],
                 "M2"),
    "spot5": ("dimap", [("spot", os.path.join(DG, "spot_example1.xml"))], "M1"),
}
#: the true attitude biases (rad) of the images: roll, pitch, yaw
TRUTH = np.array([[2.0e-5, -3.0e-5, 1.0e-4], [-1.5e-5, 2.5e-5, -5.0e-5]])
NOISE_PX = 0.1
GCP_SIGMA_M = 0.05


def _biased(image, truth):
    p = image.parameters.copy()
    p[[0, 2, 4]] = truth
    return image.with_parameters(p)


def _write_block(folder, model, images, rng, truth=TRUTH, n=40):
    """A block folder of the images' sensor files and control points seen by the biased cameras."""
    os.makedirs(folder)
    first = _biased(line_image_from_file(images[0][1], images[0][0]), truth[0])
    rows = rng.uniform(0.05, 0.95, n) * first.rows
    cols = rng.uniform(0.05, 0.95, n) * first.camera.columns
    ground = image_to_ground(first, rows, cols, rng.uniform(0, 300, n))
    observations = []
    for k, (image_id, path) in enumerate(images):
        image = _biased(line_image_from_file(path, image_id), truth[k])
        row, col = ground_to_image(image, ground)
        inside = np.isfinite(row) & (row > 0) & (row < image.rows) & (col > 0) & (col < image.camera.columns)
        noise = rng.normal(0, NOISE_PX, (n, 2))
        observations += [(image_id, f"p{j}", col[j] + noise[j, 0], row[j] + noise[j, 1]) for j in np.flatnonzero(inside)]
    with open(os.path.join(folder, "block.toml"), "w") as f:
        f.write(f'name = "vendor"\ncrs = "EPSG:4978"\n\n[cameras.sat]\nmodel = "{model}"\n\n'
                f"[observations]\nimage_sigma_px = {NOISE_PX}\n")
    with open(os.path.join(folder, "images.csv"), "w") as f:
        f.write("image_id,camera_id,strip_id,time_s,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sensor_file\n")
        f.writelines(f"{image_id},sat,,,,,,,,,{path}\n" for image_id, path in images)
    with open(os.path.join(folder, "points.csv"), "w") as f:
        f.write("point_id,role,X,Y,Z,sigma_xy_m,sigma_z_m\n")
        surveyed = ground + rng.normal(0, GCP_SIGMA_M, ground.shape)            # the control as surveyed
        f.writelines(f"p{j},gcp,{x:.4f},{y:.4f},{z:.4f},{GCP_SIGMA_M},{GCP_SIGMA_M}\n"
                     for j, (x, y, z) in enumerate(surveyed))
    with open(os.path.join(folder, "observations.csv"), "w") as f:
        f.write("image_id,point_id,col_px,row_px\n")
        f.writelines(f"{i},{p},{c:.4f},{r:.4f}\n" for i, p, c, r in observations)
    return len(observations)


@pytest.mark.parametrize("case", sorted(CASES))
def test_attitude_biases_are_recovered_through_the_block_folder(case, tmp_path):
    model, images, sensor_model = CASES[case]
    truth = TRUTH * ([1, 1, 0] if sensor_model == "M1" else 1)            # M1 estimates no yaw
    n_obs = _write_block(tmp_path / "block", model, images, np.random.default_rng(11), truth)
    assert n_obs >= 30 * len(images)
    block = read_block(tmp_path / "block")
    assert block.cameras["sat"].model == model and block.cameras["sat"].focal_mm > 0
    assert run_cli("adjust", str(tmp_path / "block"), "--out", str(tmp_path / "res"), "--sensor-model", sensor_model,
                   "--keep-focal", "--snoop", "0", "--no-report", "--quiet") == 0
    with open(tmp_path / "res" / "summary.json") as handle:
        summary = json.load(handle)
    assert summary["converged"] and summary["sensors"] == [model] and summary["datum"] == "control"
    assert 0.7 < summary["sigma0_px"] / NOISE_PX < 1.3, summary["sigma0_px"]
    with open(tmp_path / "res" / "parameters.csv") as handle:
        rows = [r for r in csv.DictReader(handle) if r["active"] == "1" and r["group"] == "EOP"]
    assert len(rows) == (2 if sensor_model == "M1" else 3) * len(images)
    to_rad = {"rad": 1.0, "urad": 1e-6, "deg": np.pi / 180}
    for row in rows:
        k = [i for i, _ in images].index(row["owner"])
        true = truth[k][("d_roll0", "d_pitch0", "d_yaw0").index(row["parameter"])]
        value, sigma = (float(row[c]) * to_rad[row["unit"]] for c in ("value", "sigma"))
        assert abs(value - true) < 4 * sigma, (case, row)
        assert sigma < 0.2 * max(abs(true), 1e-5), (case, row)          # determined, not just consistent
    assert set(PARAMETER_NAMES[:6]) >= {r["parameter"] for r in rows}


def test_a_vendor_file_of_the_other_model_is_named(tmp_path):
    """model = "dimap" with a DigitalGlobe XML: the error names the file and the model to use (exit code 2)."""
    model, images, _ = CASES["dg-stereo"]
    _write_block(tmp_path / "block", "dimap", images[:1], np.random.default_rng(1), n=10)
    with pytest.raises(BlockError, match='model = "dg"'):
        read_block(tmp_path / "block")
    assert run_cli("adjust", str(tmp_path / "block"), "--out", str(tmp_path / "res"), "--quiet") == 2
    assert not os.path.exists(tmp_path / "res")
