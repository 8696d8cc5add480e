"""Strip-wise GNSS/IMU shift and drift (Eq. 12 of seed 000) recovered against the simulated truth."""
import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, adjust

from .conftest import pruned, simulation

AXES = {"GNSS": ("X", "Y", "Z"), "IMU": ("omega", "phi", "kappa")}


def estimates(result, sensor: str, order: int) -> tuple[np.ndarray, np.ndarray]:
    """(n_strips, 3) estimate and a-posteriori sigma of the D``order`` terms of ``sensor``."""
    names = result.theta_names
    value = dict(zip(names, result.problem.pack(result.state)))
    sigma = dict(zip(names, np.sqrt(result.variance_factor * np.diag(result.Q_theta))))
    keys = [[f"{sensor} S{s} D{order} {a}" for a in AXES[sensor]] for s in range(1, 5)]
    return (np.array([[value[k] for k in row] for row in keys]),
            np.array([[sigma[k] for k in row] for row in keys]))


@pytest.fixture(scope="module", params=["type2", "type4"])
def adjusted(request):
    sim = simulation(seed=3, distortion="brown", points_per_mm2=1.0)
    result = adjust(pruned(sim, request.param), AdjustOptions(ap="brown", gnss_drift=1, imu_drift=0))
    assert result.converged
    return sim, result


def test_gnss_shift_and_drift_within_three_sigma(adjusted):
    sim, result = adjusted
    for order, truth, bound in ((0, sim.truth.gnss_shift_m, 0.05), (1, sim.truth.gnss_drift_m_s, 0.002)):
        value, sigma = estimates(result, "GNSS", order)
        assert np.abs(truth).max() > 3 * sigma.max()                 # the simulated terms are resolvable ...
        assert sigma.max() < bound                                  # ... and determined to better than bound
        assert np.all(np.abs(value - truth) < 3 * sigma), (order, (value - truth) / sigma)


def test_imu_shift_within_three_sigma(adjusted):
    sim, result = adjusted
    value, sigma = estimates(result, "IMU", 0)
    assert sigma.max() < np.radians(0.01)
    assert np.all(np.abs(value - sim.truth.imu_shift_rad) < 3 * sigma), (value - sim.truth.imu_shift_rad) / sigma


def test_trajectory_data_improve_the_check_points():
    """As in the paper: Type 2 beats Type 1, Type 4 beats Type 3 (same block, GNSS/IMU added)."""
    sim = simulation(seed=3, distortion="brown", points_per_mm2=1.0)
    rmsd = {}
    for scenario in ("type1", "type2", "type3", "type4"):
        result = adjust(pruned(sim, scenario), AdjustOptions(ap="brown", gnss_drift=1, imu_drift=0))
        block = result.block
        lookup = {p: i for i, p in enumerate(sim.truth.point_id)}
        chk = np.flatnonzero(block.points.role == "chk")
        truth = sim.truth.xyz[[lookup[p] for p in block.points.point_id[chk]]]
        d = result.state.points[chk] - truth
        rmsd[scenario] = (np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)), np.sqrt(np.mean(d[:, 2] ** 2)))
    assert rmsd["type2"][1] < rmsd["type1"][1] and rmsd["type4"][1] < rmsd["type3"][1], rmsd
    assert rmsd["type4"][0] < rmsd["type3"][0], rmsd
