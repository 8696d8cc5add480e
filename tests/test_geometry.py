"""Rotation convention of DESIGN.md §2 and its derivatives."""
import numpy as np
import pytest

from selfcal.geometry import matrix_from_opk, matrix_from_opk_with_derivatives, opk_from_matrix


def test_elements_follow_wolf():
    w, p, k = 0.1, -0.2, 0.3
    m = matrix_from_opk(np.array([w, p, k]))
    cw, sw, cp, sp, ck, sk = np.cos(w), np.sin(w), np.cos(p), np.sin(p), np.cos(k), np.sin(k)
    expected = np.array([
        [cp * ck, sw * sp * ck + cw * sk, -cw * sp * ck + sw * sk],
        [-cp * sk, -sw * sp * sk + cw * ck, cw * sp * sk + sw * ck],
        [sp, -sw * cp, cw * cp],
    ])
    np.testing.assert_allclose(m, expected, atol=1e-15)


def test_orthonormal_and_round_trip():
    rng = np.random.default_rng(3)
    opk = np.column_stack([rng.uniform(-3, 3, 200), rng.uniform(-1.5, 1.5, 200), rng.uniform(-3, 3, 200)])
    m = matrix_from_opk(opk)
    np.testing.assert_allclose(m @ m.transpose(0, 2, 1), np.broadcast_to(np.eye(3), m.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-14)
    np.testing.assert_allclose(matrix_from_opk(opk_from_matrix(m)), m, atol=1e-12)


def test_derivatives_match_finite_differences():
    opk = np.array([[0.3, -0.4, 2.0], [0.01, 0.02, -3.0]])
    _, dm = matrix_from_opk_with_derivatives(opk)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (matrix_from_opk(opk + e) - matrix_from_opk(opk - e)) / (2 * h)
        np.testing.assert_allclose(dm[:, k], fd, atol=1e-9)


def test_interpolated_earth_rotation_matches_the_direct_iau_2006_value():
    """Many instants (the lines of a pushbroom image) are interpolated between whole seconds: within 1e-12
    of the matrix elements (a few micrometres at the Earth's radius) of erfa.c2t06a at each instant."""
    from selfcal.geometry.earth import itrs_from_gcrs
    t = np.random.default_rng(0).uniform(-80.0, 120.0, 2000)
    fast = itrs_from_gcrs("2007-05-12T01:45:00Z", t)
    exact = itrs_from_gcrs("2007-05-12T01:45:00Z", t, exact=True)
    assert np.max(np.abs(fast - exact)) < 1e-12


def test_looking_at_points_the_axis_at_the_target():
    """The simulators' camera that looks at a point: a rotation (det +1), the target straight ahead on -z, the
    image's x axis perpendicular to the given up direction and y on its side."""
    from selfcal.geometry.rotation import looking_at
    rng = np.random.default_rng(3)
    for up in ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)):
        for _ in range(20):
            position, target = rng.normal(size=3) * 10, rng.normal(size=3)
            M = looking_at(position, target, up)
            assert np.allclose(M @ M.T, np.eye(3), atol=1e-12) and np.linalg.det(M) == pytest.approx(1.0)
            ahead = M @ (target - position)
            assert np.allclose(ahead / np.linalg.norm(ahead), [0.0, 0.0, -1.0], atol=1e-12)
            assert abs(M[0] @ np.array(up)) < 1e-12 and M[1] @ np.array(up) > 0
