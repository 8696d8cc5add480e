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


#: tests of a minute or more: started first, so that the two workers do not end with one of them alone on a long
#: test (pytest-xdist hands the tests out in their order)
LONG_TESTS = ("test_readme_block_runs_as_written", "test_two_hundred_signals", "test_snooping_with_waps",
              "test_example_runs_as_written")


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: not item.name.startswith(LONG_TESTS))
