"""Shared fixtures: simulated blocks with known truth (cached per test session)."""
from __future__ import annotations

import functools
import os
import sys

import numpy as np
import pytest

from selfcal.block import prune
from selfcal.simulate import simulate_uav

SHARED_DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data")


@functools.lru_cache(maxsize=None)
def simulation(seed: int = 1, distortion: str = "none", points_per_mm2: float = 3.5, blunder_rate: float = 0.0,
               image_sigma_px: float = 0.5, **trajectory):
    """A cached seed-000 simulation (the same arguments give the same object); ``trajectory`` passes
    gnss_shift_m, gnss_drift_mm_s, imu_shift_deg, lever_arm_m, boresight_deg (hashable values)."""
    return simulate_uav(seed=seed, distortion=distortion, points_per_mm2=points_per_mm2,
                        blunder_rate=blunder_rate, image_sigma_px=image_sigma_px, **trajectory)


def pruned(sim, scenario: str):
    return prune(sim.blocks[scenario])


def truth_index(sim, block) -> np.ndarray:
    """Index into the truth arrays of each point of ``block``."""
    lookup = {p: i for i, p in enumerate(sim.truth.point_id)}
    return np.array([lookup[p] for p in block.points.point_id])


def residual_vector(problem, state):
    """All whitened residuals l - f of a problem: image, control and parameter observations."""
    from selfcal.adjust.residuals import parameter_observations
    from selfcal.adjust.residuals.image import image_residuals
    r = (image_residuals(problem, state) / problem.obs_sigma).ravel()
    rc = np.einsum("nij,nj->ni", problem.control_weight,
                   problem.control_xyz - state.points[problem.control_index]).ravel()
    _, rx = parameter_observations(problem, state)
    return np.concatenate([r, rc, rx])


def unpack(problem, state, x):
    """``state`` moved by a vector over [theta | points]."""
    n_t = problem.n_theta
    return problem.apply(state, x[:n_t], x[n_t:].reshape(-1, 3))


def run_cli(*argv: str) -> int:
    from selfcal.cli.main import main
    return main(list(argv))


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture(scope="session")
def selfcal_exe():
    exe = os.path.join(os.path.dirname(sys.executable), "selfcal")
    assert os.path.exists(exe), "the selfcal console script is not installed in the test environment"
    return exe


#: the longest tests, with the seconds of their call in a full run of this suite (2026-12-07 08:42 UTC, `pytest -n 2
#: --durations=0` on the two cores, which other work shared: the figures give the order, not what a test may take).
#: pytest-xdist hands the tests out in their order, so these go first, longest first (the largest-first rule of
#: scheduling): the two workers do not end with one of them alone on a long test while the other has run out of
#: work. Before this list only four were moved, and the trajectory, CLI and jitter tests (20-80 s, their files late
#: in the alphabet) could start in the last minute. Only tests whose own call is long are listed: a test whose time
#: is its module's fixture stays beside the tests that share that fixture. xdist deals the first quarter of the
#: tests out in turn (even places to one worker, odd to the other), so two listed tests of one module with an
#: expensive fixture would build it on both workers: test_robust_real's two COPR tests (their fixture 40 s) are
#: left in place for that (they ran on one worker), and test_outcome's and test_import's tests (fixtures of 4 s)
#: too; test_cli's simulated block takes 2 s against its three listed tests' 107 s.
#: A name is the test's name (with its id where the parametrisations differ much), matched as a prefix.
def _quick_start_line() -> int:
    """The line of the README's quick start block (its opening fence), which its test's id names: listed by a fixed
    number, the entry matched no test once the README grew above it, and the quick start started late."""
    with open(os.path.join(os.path.dirname(__file__), "..", "README.md"), encoding="utf-8") as handle:
        lines = handle.read().splitlines()
    start = lines.index("## Quick start")
    return next(i + 1 for i in range(start, len(lines)) if lines[i].startswith("```sh"))


LONG_TESTS = {
    "test_snooping_with_waps_finds_the_blunders": 272,
    f"test_readme_block_runs_as_written[README.md:{_quick_start_line()}]": 233,      # the quick start
    "test_two_hundred_signals_leave_nothing_half_written": 199,
    "test_trajectory_data_improve_the_check_points": 81,
    "test_readme_block_runs_as_written": 58,                  # README.md's other blocks
    "test_screening_of_waps_on_the_brown_field": 51,
    "test_example_runs_as_written_and_prints_its_readme_tables": 46,
    "test_adjust_with_screening_and_variance_components": 42,
    "test_a_triplet_without_jitter_keeps_its_bias_and_drift": 39,
    "test_adjust_writes_the_results_contract": 36,
    "test_brown_reprojection_within_two_percent_of_pycolmap": 33,
    "test_adjust_auto_chooses_the_model_and_logs_the_candidates": 29,
    "test_screening_drops_no_real_trajectory_term": 26,
    "test_comparison_report_links_the_best_model_of_each_scenario": 24,
    "test_failed_comparison_keeps_earlier_results": 24,
    "test_the_correction_scatters_as_its_sigma_says": 18,
    "test_jitter_of_a_triplet_is_found_where_tie_points_see_it": 18,
    "test_auto_picks_a_model_within_ten_percent_of_the_best_it_cross_validates": 17,
}


def _expected_s(name: str) -> float:
    """The listed seconds of a test (the longest matching entry's prefix), 0 for a test not listed."""
    matches = [prefix for prefix in LONG_TESTS if name.startswith(prefix)]
    return LONG_TESTS[max(matches, key=len)] if matches else 0.0


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: -_expected_s(item.name))        # stable: the rest keep pytest's order
