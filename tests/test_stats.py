"""Statistics against truth: redundancy numbers, w-tests, reliability, data snooping."""
import numpy as np
import pytest
from scipy.stats import norm

from selfcal.adjust import AdjustOptions, adjust
from selfcal.stats import SnoopingOptions, adjust_with_tests, observation_tests
from selfcal.stats.reliability import noncentrality

from conftest import pruned, residual_vector, simulation, unpack


@pytest.fixture(scope="module")
def small_result():
    sim = simulation(seed=5, distortion="none", points_per_mm2=0.04)
    block = pruned(sim, "type2")
    return adjust(block, AdjustOptions(gnss_drift=1, imu_drift=0))


def test_redundancy_numbers_equal_dense_reference(small_result):
    result = small_result
    problem, state = result.problem, result.state
    n = problem.n_theta + 3 * problem.n_points
    r0 = residual_vector(problem, state)
    J = np.empty((r0.size, n))
    h = np.where(np.arange(n) < problem.n_theta, 1e-6, 1e-5)
    for k in range(n):
        e = np.zeros(n)
        e[k] = h[k]
        J[:, k] = -(residual_vector(problem, unpack(problem, state, e))
                    - residual_vector(problem, unpack(problem, state, -e))) / (2 * h[k])
    Q = np.linalg.inv(J.T @ J)
    redundancy = 1.0 - np.einsum("ij,jk,ik->i", J, Q, J)
    tests = observation_tests(result)
    m = problem.n_image_observations
    image = redundancy[:2 * m].reshape(m, 2)                 # sorted (by point) order
    np.testing.assert_allclose(tests.image_redundancy[problem.obs_order], image, atol=2e-6)
    k = 3 * len(problem.control_index)
    np.testing.assert_allclose(tests.control_redundancy.ravel(), redundancy[2 * m:2 * m + k], atol=2e-6)
    np.testing.assert_allclose(tests.parameter_redundancy, redundancy[2 * m + k:], atol=2e-6)
    assert tests.parameter_redundancy.size > 0


@pytest.fixture(scope="module")
def full_result():
    sim = simulation(seed=1, distortion="none")
    return adjust(pruned(sim, "type2"), AdjustOptions())


def test_redundancy_numbers_sum_to_the_redundancy(full_result):
    tests = observation_tests(full_result)
    assert tests.total_redundancy == pytest.approx(full_result.redundancy, rel=1e-6)
    assert np.all(tests.image_redundancy > 0) and np.all(tests.image_redundancy <= 1 + 1e-9)


def test_w_tests_of_a_blunder_free_block_are_standard_normal(full_result):
    tests = observation_tests(full_result)
    ok = tests.image_redundancy > 0.05            # coordinates controlled by the others
    w = tests.image_w[ok]
    assert w.size > 150_000
    assert abs(w.mean()) < 0.01
    assert w.std() == pytest.approx(1.0, abs=0.01)
    for k in (1.0, 2.0, 3.0):
        expected = 2 * norm.sf(k)
        assert np.mean(np.abs(w) > k) == pytest.approx(expected, rel=0.1, abs=2e-4)


def test_reliability_follows_baarda(full_result):
    tests = observation_tests(full_result, critical=3.0)
    assert tests.delta0 == pytest.approx(3.0 + 0.8416, abs=1e-4) and noncentrality(3.29, 0.8) == pytest.approx(4.13, abs=0.01)
    sigma = full_result.block.observations.sigma_px[:, None]
    r = tests.image_redundancy
    np.testing.assert_allclose(tests.image_mdb_px, tests.delta0 * sigma / np.sqrt(r))
    np.testing.assert_allclose(tests.image_external, tests.delta0 * np.sqrt((1 - r) / r))
    # a typical tie-point coordinate (r ~ 0.7) detects blunders of ~2.3 px at 0.5 px noise
    assert 1.8 < np.median(tests.image_mdb_px) < 3.0


@pytest.mark.parametrize("mode", ["batch", "single"])
def test_data_snooping_finds_blunders(mode):
    """0.3 % blunders of 4-15 px: recall and false rejections against the simulated truth.

    A blunder counts as found when its observation no longer takes part in the
    final adjustment: rejected, or dropped with a point that kept a single ray
    (in a two-ray point both rays get the same |w| and either may be rejected).
    """
    density = 3.5 if mode == "batch" else 0.6
    sim = simulation(seed=1, distortion="none", blunder_rate=0.003, points_per_mm2=density)
    block = pruned(sim, "type3")
    tested = adjust_with_tests(block, AdjustOptions(), SnoopingOptions(3.0, mode=mode))
    used = set(tested.result.block.observations.row.tolist())
    blunders = set(sim.truth.blunder_obs.tolist())
    found = len(blunders - used) / len(blunders)
    false = len(set(block.observations.row.tolist()) - used - blunders) / len(block.observations)
    assert found >= 0.95, found
    assert false <= 0.01, false
    assert not (set(tested.rejected_rows.tolist()) - set(block.observations.row.tolist()))
    clean = adjust(pruned(simulation(seed=1, distortion="none", points_per_mm2=density), "type3"))
    assert tested.result.sigma0_px == pytest.approx(clean.sigma0_px, rel=0.03)


def test_snooping_disabled_rejects_nothing():
    sim = simulation(seed=1, distortion="none", blunder_rate=0.003, points_per_mm2=0.3)
    tested = adjust_with_tests(pruned(sim, "type3"), AdjustOptions(), SnoopingOptions(critical=0))
    assert tested.rejected_rows.size == 0 and not tested.rounds


def test_ce90_and_le90_match_the_normal_distribution():
    """For circular normal errors CE90 -> 2.146 sigma and LE90 -> 1.645 sigma (large sample, 1 % tolerance)."""
    from selfcal.stats import ce90, le90
    rng = np.random.default_rng(11)
    sigma = 0.04
    d = rng.normal(0.0, sigma, (200_000, 3))
    assert abs(ce90(d[:, :2]) / (sigma * np.sqrt(-2 * np.log(0.1))) - 1) < 0.01
    assert abs(le90(d[:, 2]) / (sigma * 1.6448536) - 1) < 0.01
    assert ce90(np.zeros((0, 2))) is None and le90(np.zeros(0)) is None
