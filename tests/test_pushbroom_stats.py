"""The statistics of the one engine on pushbroom blocks (seed 001's PRISM triplet, simulated): variance
components, internal and external reliability, and the choice of an AP model by BIC, tested against the
simulated truth."""
import dataclasses

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, APOptions, SensorOptions
from selfcal.simulate.prism import LINE_ERROR_PX, TRUE_FOCAL_MM, prism_block, simulate_prism
from selfcal.stats import SnoopingOptions, VarianceOptions
from selfcal.stats.reliability import noncentrality
from selfcal.workflows import choose_ap_model
from selfcal.workflows.seed001 import case_block, choose_gcps, run_case, with_focal

NOISE_PX = 0.3


@pytest.fixture(scope="module")
def triplet():
    """300 points in the triplet with 0.3 px noise, the true focal lengths."""
    sim = simulate_prism(seed=5, n_points=300, image_sigma_px=NOISE_PX)
    return sim, with_focal(prism_block(sim, seed=5), TRUE_FOCAL_MM)


def _with_image_sigma(block, sigma_px: float):
    obs = dataclasses.replace(block.observations, sigma_px=np.full(len(block.observations), sigma_px))
    return dataclasses.replace(block, observations=obs, image_sigma_px=sigma_px)


@pytest.mark.parametrize("factor", [2.0, 0.5])
def test_variance_component_of_the_image_points_finds_the_simulated_noise(triplet, factor):
    """The a-priori sigma of the image points off by 2x (either way): the estimated sigma of the image group
    is the simulated 0.3 px within 10 % (its own precision is about 2.5 % with ~800 redundancy), and the
    variance factor of the reweighted adjustment is 1."""
    sim, block = triplet
    wrong = _with_image_sigma(block, factor * NOISE_PX)
    case = run_case(wrong, "M6", choose_gcps(wrong, 5), (0, 1, 2), sim.dem, "F+N+B",
                    snooping=SnoopingOptions(), variance=VarianceOptions())
    components = {c.group: c for c in case.tested.variance_components}
    image = components["image"]
    assert image.estimated and abs(image.sigma_aposteriori[0] / NOISE_PX - 1.0) < 0.10, image
    assert abs(case.result.variance_factor - 1.0) < 0.05
    assert case.tested.variance_converged


def test_minimal_detectable_blunders_and_external_reliability(triplet):
    """Every image coordinate of the triplet is controlled (0 < r < 1); its MDB is delta0 sigma / sqrt(r) and
    Baarda's external reliability delta0 sqrt((1 - r) / r); the w-tests of the blunder-free triplet stay
    below 4.5 (the largest of ~1700 standard normals) and their mean square is the redundancy share."""
    sim, block = triplet
    case = run_case(block, "M6", choose_gcps(block, 5), (0, 1, 2), sim.dem, "F+N+B")
    tests = case.tested.tests
    r = tests.image_redundancy
    delta0 = noncentrality(3.0)
    assert np.all((r > 0.05) & (r < 1.0))
    np.testing.assert_allclose(tests.image_mdb_px, delta0 * NOISE_PX / np.sqrt(r), rtol=1e-12)
    np.testing.assert_allclose(tests.image_external, delta0 * np.sqrt((1 - r) / r), rtol=1e-12)
    assert np.max(np.abs(tests.image_w)) < 4.5
    # sum of w^2 r = v^T P v: the image part of Omega, near the image redundancy
    omega_image = float(np.sum(tests.image_w ** 2 * r))
    assert abs(omega_image / r.sum() - 1.0) < 0.15


def test_ap_model_is_chosen_by_bic_on_a_pushbroom_block():
    """With a chip-wise error of the nadir line (up to 0.9 px, 0.1 px noise) BIC chooses wavelet1d:db4 on the
    nadir camera over no APs; without the error it keeps no APs."""
    candidates = [("none", (12, 12)), ("wavelet1d:db4", (12, 12))]
    options = AdjustOptions(ap=APOptions(cameras=("N",)), sensor=SensorOptions(model="M6"))
    for error, expected in ((LINE_ERROR_PX, "wavelet1d:db4"), (None, "none")):
        sim = simulate_prism(seed=4, n_points=300, image_sigma_px=0.1, detector_error_px=error)
        block = with_focal(prism_block(sim, seed=4), TRUE_FOCAL_MM)
        sub = case_block(block, (0, 1, 2), choose_gcps(block, 5))
        choice = choose_ap_model(sub, candidates, options, snooping=None)
        assert choice.model == expected, [(s.label, s.bic) for s in choice.candidates]
