"""The robust scale is the one the settled weights belong to (not that of the first update at a poor start)."""
from dataclasses import replace

import numpy as np

from selfcal.adjust import AdjustOptions, SensorOptions, adjust
from selfcal.adjust.robust import RobustOptions
from selfcal.simulate.prism import prism_block, simulate_prism
from selfcal.stats.cleaning import clean
from selfcal.workflows import seed001
from selfcal.workflows.tested import prune_for


def test_a_pushbroom_triplet_is_cleaned_at_the_scale_of_its_adjusted_residuals():
    """The PRISM triplet starts from telemetry with an attitude bias (residuals 45x their sigma at the start). The
    robust weights settle once the bias is adjusted; the scale must then be the residuals' (about 1), not the start's:
    at 45 no 8 px blunder was rejected and the cleaning said "misfit" of a block that fits to 0.30 px."""
    sim = simulate_prism(seed=3, n_points=600)
    block = seed001.with_focal(prism_block(sim, seed=3), {"F": 1938.20, "N": 1937.45, "B": 1936.66})
    block = seed001.case_block(block, (0, 1, 2), seed001.choose_gcps(block, None))
    rng = np.random.default_rng(5)
    bad = rng.choice(len(block.observations.pixel), 30, replace=False)
    pixel = block.observations.pixel.copy()
    pixel[bad] += rng.choice([-1.0, 1.0], (30, 2)) * 8.0
    block = replace(block, observations=replace(block.observations, pixel=pixel))
    result = adjust(block, AdjustOptions(sensor=SensorOptions(model="M5")), robust=RobustOptions())
    assert result.robust.history[0][0] > 20                 # the first update, at the start
    assert 0.9 <= result.robust.scale < 1.5                 # the settled weights' (measured 1.0)
    _, cleaning = clean(result, RobustOptions().reject, prune_for)
    found = np.isin(block.observations.row[bad], cleaning.rejected_rows)
    others = np.isin(block.observations.row, np.setdiff1d(cleaning.rejected_rows, block.observations.row[bad]))
    assert found.sum() >= 27, found.sum()                   # 8 px blunders of 0.3 px noise (measured 30 of 30)
    # the other rays rejected are those of the blunders' points (a three-ray point with an 8 px blunder starts with
    # every ray far off, and goes whole: measured 57 rays of 29 points), none elsewhere
    point = block.observations.point_index
    assert np.all(np.isin(point[others], point[bad])), np.sum(~np.isin(point[others], point[bad]))
    assert all("bulk of the image residuals" not in m for m in cleaning.messages)
