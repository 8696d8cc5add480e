"""Issue 4 acceptance: snooping and screening with a wavelet AP model on the 28-image Type 3 block.

sym4 on the 9x6 grid (254 WAPs), 0.5 px noise, the check-point RMSD against
the marks' reference coordinates (the way a surveyor measures it).
"""
from dataclasses import replace

import numpy as np
import pytest

from selfcal.adjust import adjust, AdjustOptions, APOptions
from selfcal.block import prune
from selfcal.stats import ScreeningOptions, SnoopingOptions
from selfcal.workflows import adjust_with_tests

from conftest import pruned, simulation

pytestmark = pytest.mark.slow

WAP = AdjustOptions(ap=APOptions("wavelet:sym4"))


def chk_rmsd(result) -> np.ndarray:
    pts = result.block.points
    chk = pts.role == "chk"
    d = result.state.points[chk] - pts.xyz_m[chk]
    return np.array([np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1))), np.sqrt(np.mean(d[:, 2] ** 2))])


def test_snooping_with_waps_finds_the_blunders():
    """0.3 % blunders of 4-15 px on the local+Brown field: recall >= 95 %, false rejections <= 1 %,
    and the check-point RMSD within 10 % of the run on the same block without the blunders, pooled over eight
    seeds (12 check points each). One seed alone ranged 0.96-1.19 in height over equally valid choices of the
    WAP functions left out as dependent (which LAPACK's pivoted QR made by the rounding of the machine); pooled
    over the eight, two of those choices gave 1.00 and 1.03."""
    squares = np.zeros((2, 2))                   # (with blunders, without) x (XY, Z)
    for seed in range(1, 9):
        # (not kept in the simulations' cache: eight blocks of 80,000 observations)
        sim = simulation.__wrapped__(seed=seed, distortion="local+brown", blunder_rate=0.003)
        block = pruned(sim, "type3")
        tests = (SnoopingOptions(3.0), ScreeningOptions())
        tested = adjust_with_tests(block, WAP, *tests)
        used = set(tested.result.block.observations.row.tolist())
        blunders = set(sim.truth.blunder_obs.tolist())
        assert len(blunders) > 200
        recall = len(blunders - used) / len(blunders)
        false = len(set(block.observations.row.tolist()) - used - blunders) / len(block.observations)
        assert recall >= 0.95 and false <= 0.01, (seed, recall, false)
        # the blunder-free run: the same noise, the blundered observations taken out
        clean_obs = np.flatnonzero(~np.isin(block.observations.row, sim.truth.blunder_obs))
        clean = prune(replace(block, observations=block.observations.take(clean_obs)))
        reference = adjust_with_tests(clean, WAP, *tests)
        squares += np.array([chk_rmsd(tested.result), chk_rmsd(reference.result)]) ** 2
    assert np.all(squares[0] <= 1.10 ** 2 * squares[1]), np.sqrt(squares / 8)


def test_screening_of_waps_on_the_brown_field():
    """Brown-only field: screening removes >= 20 % of the WAPs over two seeds (>= 15 % on each: the interior
    orientation's guard keeps the WAPs whose drop would move c, x0 or y0 by 0.1 sigma; measured 18.5 and 32.3 %,
    without the guard 34.6 and 36.2 %) and costs <= 5 % of check-point RMSD, pooled over the two seeds (12 check
    points each; one seed alone ranged 0.94-1.05 over seeds 1-4; measured XY 0.984, Z 0.982, without the guard
    0.963, 1.012)."""
    squares = np.zeros((2, 2))                   # (full, screened) x (XY, Z)
    kept = 0
    for seed in (1, 2):
        block = pruned(simulation(seed=seed, distortion="brown"), "type3")
        full = adjust(block, WAP)
        screened = adjust_with_tests(block, WAP, None, ScreeningOptions())
        assert screened.n_ap_initial == 254
        assert screened.n_ap_significant <= 0.85 * screened.n_ap_initial, screened.n_ap_significant
        kept += screened.n_ap_significant
        squares += np.array([chk_rmsd(full), chk_rmsd(screened.result)]) ** 2
    assert kept <= 0.80 * 2 * 254, kept
    assert np.all(squares[1] <= 1.05 ** 2 * squares[0]), np.sqrt(squares)
    assert screened.result.converged
    # the translation ranges shrink with the screening (Table 3 of seed 000)
    model = screened.result.problem.cameras[0].ap
    before = model.active_ranges(np.ones(model.n_params, bool))
    after = model.active_ranges(screened.ap_free["ilce7m3"])
    assert after[0] >= before[0] and after[1] <= before[1] and after[2] >= before[2] and after[3] <= before[3]
    # the joint F-test guards the drops by t and by correlation; the coefficients dropped because their effect on the
    # adjusted rays and points is below 0.1 px (issue 44, together below it too) may be significant, and make the
    # dropped set so
    by_effect = [d for _, d in screened.screening_log if d.reason.startswith("its effect is")]
    assert all(d.reason.endswith("(< 0.1 px)") for d in by_effect)
    assert by_effect or not any(joint.jointly_significant for _, joint in screened.screening_rounds)
    log_names = {d.name for _, d in screened.screening_log}
    assert len(log_names) == screened.n_ap_initial - screened.n_ap_significant
