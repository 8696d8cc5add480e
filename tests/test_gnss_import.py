"""Camera GNSS from the images (issue 23 item 4): per-image sigmas of the trajectory observations, EXIF GPS and
DJI XMP read from JPEGs written with Pillow, ODM geo.txt, strips from time and heading, geographic GCPs."""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from selfcal.adjust.normal import parameter_observations
from selfcal.adjust.initial import initial_state
from selfcal.adjust.problem import build_problem
from selfcal.block import prune
from selfcal.errors import BlockError
from selfcal.io.block_folder import read_block, write_block

from conftest import simulation


# ---------------------------------------------------------------------------- per-image sigmas

@pytest.fixture(scope="module")
def uav():
    return simulation(seed=5, distortion="none", points_per_mm2=0.6)


def test_per_image_sigma_overrides_the_block_sigma_in_the_engine(uav, tmp_path):
    """An image's own GNSS/IMU sigma (images.csv) whitens its observation instead of block.toml's: with the
    same residual, 10 times the sigma gives a tenth of the whitened residual; the others are unchanged."""
    block = prune(uav.blocks["type2"])
    n = len(block.images)
    own = np.full((n, 3), np.nan)
    own[3] = [0.5, 0.5, 1.0]                                  # 10 x [gnss] sigma_m = 0.05, 0.05, 0.10
    own_imu = np.full((n, 3), np.nan)
    own_imu[7] = np.radians([0.2, 0.2, 0.5])                  # 10 x [imu] sigma_deg
    write_block(replace(block, images=replace(block.images, gnss_sigma_m=own, imu_sigma_rad=own_imu)),
                tmp_path / "own")
    text = (tmp_path / "own" / "images.csv").read_text()
    assert "sigma_gnss_X_m" in text.splitlines()[0] and "sigma_imu_kappa_deg" in text.splitlines()[0]
    read = read_block(tmp_path / "own")
    np.testing.assert_allclose(read.images.gnss_sigma_m[3], [0.5, 0.5, 1.0])
    np.testing.assert_allclose(np.degrees(read.images.imu_sigma_rad[7]), [0.2, 0.2, 0.5])
    assert np.isnan(read.images.gnss_sigma_m[np.arange(n) != 3]).all()

    residuals = {}
    for name, b in (("block", block), ("own", read)):
        problem = build_problem(b, gnss_drift=-1, imu_drift=-1)
        state, _ = initial_state(problem, b)
        state.image[:, :3] += [0.3, -0.2, 0.4]                # every observation gets a residual
        state.image[:, 3:6] += np.radians([0.05, -0.04, 0.1])
        _, r = parameter_observations(problem, state)
        k = int(np.sum(np.isfinite(problem.image_prior_sigma) & problem.image_free))
        traj = r[k:].reshape(2, n, 3)                         # GNSS rows, then IMU rows
        residuals[name] = traj
        gnss = next(t for t in problem.trajectory if t.sensor == "GNSS")
        if name == "own":
            np.testing.assert_allclose(gnss.sigma[3], [0.5, 0.5, 1.0])
            np.testing.assert_allclose(gnss.sigma[0], block.gnss_sigma_m)
    ratio = residuals["own"] / residuals["block"]
    np.testing.assert_allclose(ratio[0, 3], 0.1, rtol=1e-9)
    np.testing.assert_allclose(ratio[1, 7], 0.1, rtol=1e-9)
    mask = np.ones((2, n), bool)
    mask[0, 3] = mask[1, 7] = False
    np.testing.assert_allclose(ratio[mask], 1.0, rtol=1e-12)


def test_per_image_sigma_needs_its_section_and_a_positive_value(uav, tmp_path):
    block = prune(uav.blocks["type1"])                       # no [gnss]
    own = np.full((len(block.images), 3), np.nan)
    own[0] = 0.02
    with pytest.raises(BlockError, match=r"sigma_gnss_X_m.*no \[gnss\]|no \[gnss\]") as info:
        write_block(replace(block, images=replace(block.images, gnss_sigma_m=own)), tmp_path / "b", source="x")
    assert "sigma_gnss_X_m" in str(info.value)
    write_block(prune(uav.blocks["type2"]), tmp_path / "t2")
    path = tmp_path / "t2" / "images.csv"
    lines = path.read_text().splitlines()
    lines[0] += ",sigma_gnss_Z_m"
    lines[1:] = [line + "," for line in lines[1:]]
    lines[2] = lines[2] + "-0.1"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BlockError) as info:
        read_block(tmp_path / "t2")
    assert info.value.line == 3 and info.value.column == "sigma_gnss_Z_m" and "positive" in info.value.reason
