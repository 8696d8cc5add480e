"""Robust adjustment on the real blocks and on every sensor (issue 39): COPR with wrong observations added, BAL
problem-49 with 10 % outliers against its clean solution, a pushbroom triplet and an RPC stereo pair with 10 %
wrong tie points."""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHARED_DATA
from selfcal.adjust import AdjustOptions, RobustOptions
from selfcal.stats import SnoopingOptions
from selfcal.workflows.tested import adjust_with_tests, prune_for

COPR = os.path.join(SHARED_DATA, "copr", "sparse")
BAL = os.path.join(SHARED_DATA, "bal", "problem-49-7776-pre.txt")


def _moved(block, share: float, low_px: float, high_px: float, seed: int):
    """``block`` with ``share`` of its observations moved by ``low_px``-``high_px`` in a random direction (kept in
    the frame), and which ones."""
    rng = np.random.default_rng(seed)
    obs = block.observations
    rows = rng.choice(len(obs), int(round(share * len(obs))), replace=False)
    length = rng.uniform(low_px, high_px, rows.size)
    angle = rng.uniform(0.0, 2.0 * np.pi, rows.size)
    pixel = obs.pixel.copy()
    pixel[rows] += np.column_stack([length * np.cos(angle), length * np.sin(angle)])
    cams = [block.cameras[c] for c in block.images.camera_id[obs.image_index[rows]]]
    size = np.array([[getattr(c, "width_px", np.inf), getattr(c, "height_px", np.inf)] for c in cams])
    pixel[rows] = np.clip(pixel[rows], 0.0, size)
    return replace(block, observations=replace(obs, pixel=pixel)), rows


@pytest.fixture(scope="module")
def copr():
    from selfcal.convert import block_from_colmap
    from selfcal.io.colmap import read_colmap
    assert os.path.isdir(COPR), f"shared test data missing: {COPR}"
    block, _ = block_from_colmap(read_colmap(COPR), None, pixel_size_mm=0.0052)
    block = prune_for(replace(block, datum="free"))
    clean = adjust_with_tests(block, AdjustOptions(ap="brown"), SnoopingOptions(), robust=RobustOptions())
    return block, clean


@pytest.mark.slow
@pytest.mark.parametrize("share", [0.05, 0.20])
def test_copr_camera_survives_wrong_observations(copr, share):
    """The real COPR block (a free network, 313,000 COLMAP observations, Brown APs) with 5 % and 20 % of its
    observations moved by 20-500 px: the adjusted camera (c, x0, y0 and every Brown term) within 1 sigma of the
    clean run's, and the moved observations rejected (at least 99 %)."""
    block, clean = copr
    wrong, rows = _moved(block, share, 20.0, 500.0, seed=int(share * 100))
    tested = adjust_with_tests(wrong, AdjustOptions(ap="brown"), SnoopingOptions(), robust=RobustOptions())
    assert not tested.failure and tested.result.converged
    a, b = clean.result, tested.result
    sigma = np.hypot(a.camera_sigma()[0], b.camera_sigma()[0])
    diff = b.state.cameras[0] - a.state.cameras[0]
    names = a.problem.cameras[0].names
    ratio = np.abs(diff) / sigma
    print(share, {n: round(float(r), 2) for n, r in zip(names, ratio)})
    assert np.all(ratio[np.isfinite(ratio)] < 1.0), dict(zip(names, ratio))
    out = ~np.isin(wrong.observations.row[rows], b.block.observations.row)
    assert out.mean() >= 0.99


@pytest.mark.slow
def test_bal_with_ten_percent_outliers_reaches_the_clean_cost_over_the_inliers():
    """BAL problem-49 (49 cameras, 31,843 observations, a free network) with 10 % of its observations moved by
    20-200 px: the robust adjustment's cost over the inliers (the unmoved observations it kept, at its estimate)
    within 1 % of the clean least-squares solution's cost over the same observations."""
    from selfcal.adjust import adjust
    from selfcal.convert import block_from_bal
    from selfcal.io.bal import read_bal
    assert os.path.exists(BAL), f"shared test data missing: {BAL}"
    block = prune_for(block_from_bal(read_bal(BAL)))
    clean = adjust(block, AdjustOptions())
    wrong, rows = _moved(block, 0.10, 20.0, 200.0, seed=49)
    tested = adjust_with_tests(wrong, AdjustOptions(), SnoopingOptions(), robust=RobustOptions())
    result = tested.result
    moved = set(wrong.observations.row[rows].tolist())
    kept = np.array([r not in moved for r in result.block.observations.row])
    inliers = result.block.observations.row[kept]

    def cost(adjusted, rows_wanted):
        where = np.isin(adjusted.block.observations.row, rows_wanted)
        v = adjusted.residuals_px[where]
        return float(np.sum(v * v))
    robust_cost = cost(result, inliers)
    clean_cost = cost(clean, inliers)
    print(f"cost over {inliers.size} inliers: robust {robust_cost:.2f}, clean {clean_cost:.2f}")
    assert abs(robust_cost - clean_cost) <= 0.01 * clean_cost
    assert inliers.size >= 0.97 * (len(block.observations) - rows.size)
