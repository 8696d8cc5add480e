"""Initial values: missing or poor orientations are recovered by space resection."""
from dataclasses import replace

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, adjust
from selfcal.adjust.initial import resect
from selfcal.errors import AdjustmentError
from selfcal.sensors.frame import project

from conftest import pruned, simulation


def test_resection_recovers_a_tilted_image_from_a_plane_similarity_start():
    rng = np.random.default_rng(0)
    eop = np.array([120.0, -40.0, 260.0, np.radians(3.0), np.radians(-4.0), np.radians(130.0)])
    xyz = np.column_stack([rng.uniform(-30, 270, 12), rng.uniform(-180, 100, 12), rng.uniform(0, 40, 12)])
    iop = np.array([21.0, 0.02, -0.01])
    xy = project(xyz, np.broadcast_to(eop, (12, 6)), iop)
    est = resect(xy, xyz, iop)
    np.testing.assert_allclose(est[:3], eop[:3], atol=1e-6)
    np.testing.assert_allclose(est[3:], eop[3:], atol=1e-9)


def test_resection_needs_four_points():
    with pytest.raises(AdjustmentError, match="at least 4 points"):
        resect(np.zeros((3, 2)), np.zeros((3, 3)), np.array([21.0, 0, 0]))


@pytest.fixture(scope="module")
def reference():
    sim = simulation(seed=3, distortion="none", points_per_mm2=0.3)
    block = pruned(sim, "type3")
    return block, adjust(block, AdjustOptions())


def test_missing_orientations_are_resected(reference):
    block, ref = reference
    pos = block.images.position_m.copy()
    att = block.images.attitude_rad.copy()
    pos[[0, 9, 20]] = np.nan                  # three images without any orientation
    att[[0, 9, 20]] = np.nan
    att[5] = np.nan                           # one with a position only
    images = replace(block.images, position_m=pos, attitude_rad=att)
    result = adjust(replace(block, images=images), AdjustOptions())
    assert result.converged
    assert sum("space resection" in n for n in result.notes) == 4
    np.testing.assert_allclose(result.state.points, ref.state.points, atol=1e-6)
    assert result.sigma0_px == pytest.approx(ref.sigma0_px, rel=1e-9)


def test_poor_orientation_is_detected_and_resected(reference):
    block, ref = reference
    pos = block.images.position_m.copy()
    pos[12] += [60.0, -45.0, 30.0]            # a GNSS position tens of metres off
    images = replace(block.images, position_m=pos)
    result = adjust(replace(block, images=images), AdjustOptions())
    assert any("re-oriented by space resection" in n and block.images.image_id[12] in n for n in result.notes)
    np.testing.assert_allclose(result.state.points, ref.state.points, atol=1e-6)
