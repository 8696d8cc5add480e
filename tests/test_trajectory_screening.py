"""Issue 25: GNSS/IMU trajectory errors drawn independently of the model, and a screening of their
shift/drift terms that never drops one that is really there."""
import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, adjust
from selfcal.adjust.normal import _mounted_sensor, _wrap
from selfcal.geometry.rotation import matrix_from_opk, matrix_from_rotation_vector, opk_from_matrix
from selfcal.simulate import simulate_uav
from selfcal.simulate.trajectory import TrajectoryErrors, noise_free_terms
from selfcal.stats.screening import ScreeningOptions
from selfcal.stats.workflow import adjust_with_tests

from conftest import pruned

GNSS_DECLARED_M = (0.05, 0.05, 0.10)
IMU_DECLARED_DEG = (0.01, 0.01, 0.02)


def independent(seed: int, origin: str = "first", composition: str = "opk", lever_arm_m=(0.0, 0.0, 0.0),
                points_per_mm2: float = 0.5, distortion: str = "brown"):
    """The issue-25 simulation: strips of 12 s, errors independent of the model, noise below the declared."""
    return simulate_uav(seed=seed, distortion=distortion, points_per_mm2=points_per_mm2,
                        gnss_sigma_m=GNSS_DECLARED_M, imu_sigma_deg=IMU_DECLARED_DEG,
                        trajectory_errors=TrajectoryErrors(drift_origin=origin, imu_composition=composition),
                        exposure_interval_s=2.0, lever_arm_m=lever_arm_m, declare_mounting=any(lever_arm_m))


def true_terms(sim, result) -> dict[str, tuple[float, bool]]:
    """name -> (true value in the adjustment's own parametrisation, truly zero) of every shift/drift term."""
    truth = sim.truth
    lookup = {i: k for k, i in enumerate(truth.image_id)}
    out, full = {}, 0
    for t in result.problem.trajectory:
        img = np.array([lookup[i] for i in result.block.images.image_id[t.index]])
        values = result.state.extra[full:full + t.n_params]
        full += t.n_params
        p0 = _mounted_sensor(t, truth.eop[img], t.mounting_of(values))[0]
        clean = truth.trajectory.gnss_noise_free_m[img] if t.offset == 0 else truth.trajectory.imu_noise_free_rad[img]
        systematic = _wrap(clean - p0) if t.wrap else clean - p0
        terms = noise_free_terms(systematic, t.strip_of, t.dt, t.order)
        drift = truth.trajectory.gnss_drift_m_s if t.offset == 0 else truth.trajectory.imu_drift_rad_s
        for i, name in enumerate(t.names[:t.n_strip_params]):
            s, rest = divmod(i, 3 * (t.order + 1))
            k, a = divmod(rest, 3)
            out[name] = (float(terms[s, k, a]), bool(k >= 1 and np.all(drift[int(t.strips[s][1:]) - 1] == 0)))
    return out


def tie_point_rms_xy(sim, result) -> float:
    lookup = {p: i for i, p in enumerate(sim.truth.point_id)}
    points = result.block.points
    tie = np.flatnonzero(points.role == "tie")
    d = result.state.points[tie] - sim.truth.xyz[[lookup[p] for p in points.point_id[tie]]]
    return float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)))


# --- the simulation ------------------------------------------------------------------------------------

def test_default_trajectory_is_eq12_as_modelled():
    """Without TrajectoryErrors the errors are Eq. (12) from the strip's first exposure, noise as declared."""
    sim = simulate_uav(seed=4, distortion="none", points_per_mm2=0.3)
    truth, images = sim.truth, sim.blocks["type2"].images
    strip = np.array([int(s[1:]) - 1 for s in images.strip_id])
    first = np.array([images.time_s[strip == s].min() for s in range(4)])
    expected = truth.eop[:, :3] + truth.gnss_shift_m[strip] + truth.gnss_drift_m_s[strip] * (images.time_s - first[strip])[:, None]
    np.testing.assert_allclose(truth.trajectory.gnss_noise_free_m, expected, atol=1e-9)
    np.testing.assert_allclose(truth.trajectory.imu_noise_free_rad, truth.eop[:, 3:] + truth.imu_shift_rad[strip], atol=1e-12)
    noise = images.position_m - truth.trajectory.gnss_noise_free_m
    assert np.all(np.abs(noise.std(axis=0) / np.array([0.05, 0.05, 0.10]) - 1) < 0.45), noise.std(axis=0)


@pytest.mark.parametrize("origin", ["first", "middle"])
def test_independent_errors_as_drawn(origin):
    """Shift magnitudes in their ranges, half the strips without drift, the drift counted from the strip's first
    exposure or its middle, the IMU error as a rotation of the body frame; noise at the true (not declared) level."""
    sim = independent(seed=7, origin=origin, composition="rotation", points_per_mm2=0.3)
    truth, tr = sim.truth, sim.truth.trajectory
    images = sim.blocks["type2"].images
    strip = np.array([int(s[1:]) - 1 for s in images.strip_id])
    assert np.all((np.abs(tr.gnss_shift_m) >= 0.10) & (np.abs(tr.gnss_shift_m) <= 0.45))
    assert np.all(np.abs(tr.gnss_drift_m_s) <= 0.02) and np.all(np.abs(np.degrees(tr.imu_drift_rad_s)) <= 0.005)
    assert np.all(np.abs(np.degrees(tr.imu_shift_rad)) <= 0.13)
    first = np.array([images.time_s[strip == s].min() for s in range(4)])
    last = np.array([images.time_s[strip == s].max() for s in range(4)])
    assert np.allclose(last - first, 12.0)
    origin_s = first if origin == "first" else 0.5 * (first + last)
    np.testing.assert_allclose(tr.origin_s, origin_s)
    dt = images.time_s - origin_s[strip]
    np.testing.assert_allclose(tr.gnss_noise_free_m,
                               truth.eop[:, :3] + tr.gnss_shift_m[strip] + tr.gnss_drift_m_s[strip] * dt[:, None], atol=1e-9)
    e = tr.imu_shift_rad[strip] + tr.imu_drift_rad_s[strip] * dt[:, None]
    rotated = opk_from_matrix(matrix_from_rotation_vector(e) @ matrix_from_opk(truth.eop[:, 3:]))
    np.testing.assert_allclose(_wrap(tr.imu_noise_free_rad - rotated), 0.0, atol=1e-12)
    # a rotation of the body frame is not an angle shift: omega and phi change by about -e on eastbound strips (an
    # active rotation against passive angles) and by +e on westbound ones (kappa near 180 deg), within the
    # kappa jitter of 1.5 deg
    west = np.abs(np.abs(truth.eop[:, 5]) - np.pi) < 0.2
    sign = np.where(west, 1.0, -1.0)[:, None]
    added = _wrap(tr.imu_noise_free_rad - truth.eop[:, 3:])
    assert np.all(np.abs(added[:, :2] - sign * e[:, :2]) <= 0.06 * np.abs(e).max(axis=1, keepdims=True) + 1e-6)
    assert west.any() and (~west).any()
    noise = images.position_m - tr.gnss_noise_free_m
    assert np.all(np.abs(noise.std(axis=0) / np.array([0.03, 0.03, 0.05]) - 1) < 0.45), noise.std(axis=0)
    assert sim.blocks["type2"].gnss_sigma_m == GNSS_DECLARED_M


def test_strips_without_drift():
    """drift_share: about half the (sensor, strip) pairs do not drift; their drift terms are truly zero."""
    zero = []
    for seed in range(1, 9):
        tr = independent(seed=seed, points_per_mm2=0.2).truth.trajectory
        zero += [np.all(tr.gnss_drift_m_s == 0, axis=1), np.all(tr.imu_drift_rad_s == 0, axis=1)]
    share = np.mean(np.concatenate(zero))
    assert 0.3 < share < 0.7, share
