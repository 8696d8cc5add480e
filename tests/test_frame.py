"""Frame collinearity (Eq. 1 of seed 000): conventions and analytic Jacobians."""
import numpy as np

from selfcal.sensors.frame import photo_from_pixel, pixel_from_photo, project, project_with_jacobians, rays


def _setup(n=50, seed=0):
    rng = np.random.default_rng(seed)
    eop = np.column_stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(200, 260, n),
                           rng.normal(0, 0.05, n), rng.normal(0, 0.05, n), rng.uniform(-np.pi, np.pi, n)])
    pts = np.column_stack([rng.uniform(-150, 150, n), rng.uniform(-100, 100, n), rng.uniform(0, 40, n)])
    iop = np.column_stack([rng.uniform(20, 22, n), rng.normal(0, 0.05, n), rng.normal(0, 0.05, n)])
    return pts, eop, iop


def test_pixel_photo_convention():
    # DESIGN.md §2: x = (col - W/2) p, y = (H/2 - row) p
    xy = photo_from_pixel(np.array([[0.0, 0.0], [6000.0, 4000.0], [3000.0, 2000.0]]), 6000, 4000, 0.0059)
    np.testing.assert_allclose(xy, [[-17.7, 11.8], [17.7, -11.8], [0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(pixel_from_photo(xy, 6000, 4000, 0.0059), [[0, 0], [6000, 4000], [3000, 2000]],
                               atol=1e-9)


def test_nadir_image_geometry():
    # omega = phi = kappa = 0: image x along object X, y along Y; a point east of the camera has x > 0
    eop = np.array([[0.0, 0.0, 100.0, 0.0, 0.0, 0.0]])
    xy = project(np.array([[10.0, 5.0, 0.0]]), eop, np.array([20.0, 0.0, 0.0]))
    np.testing.assert_allclose(xy, [[2.0, 1.0]], atol=1e-12)


def test_jacobians_match_finite_differences():
    pts, eop, iop = _setup()
    xy, j_eop, j_pt, j_iop = project_with_jacobians(pts, eop, iop)
    np.testing.assert_allclose(xy, project(pts, eop, iop), rtol=1e-14)
    for params, jac, step in ((eop, j_eop, np.array([1e-4] * 3 + [1e-7] * 3)), (pts, j_pt, np.full(3, 1e-4)),
                              (iop, j_iop, np.full(3, 1e-6))):
        for k in range(params.shape[1]):
            plus, minus = params.copy(), params.copy()
            plus[:, k] += step[k]
            minus[:, k] -= step[k]
            args_p = [plus if params is a else a for a in (pts, eop, iop)]
            args_m = [minus if params is a else a for a in (pts, eop, iop)]
            fd = (project(*args_p) - project(*args_m)) / (2 * step[k])
            scale = np.max(np.abs(fd)) + 1e-300
            err = np.max(np.abs(jac[:, :, k] - fd)) / scale
            assert err < 1e-6, (k, err)


def test_rays_point_at_the_object_point():
    pts, eop, iop = _setup()
    xy = project(pts, eop, iop)
    d = rays(xy, eop, iop)
    to_point = pts - eop[:, :3]
    to_point /= np.linalg.norm(to_point, axis=1, keepdims=True)
    np.testing.assert_allclose(d, to_point, atol=1e-12)


def test_compiled_projection_equals_vectorised():
    from selfcal.geometry import matrix_from_opk_with_derivatives
    from selfcal.sensors.frame import project_with_jacobians_indexed
    pts, eop, iop = _setup(40, seed=4)
    images = eop[:7]
    cams = iop[:3]
    img = np.arange(40) % 7
    cam = np.arange(40) % 3
    ref = project_with_jacobians(pts, images[img], cams[cam])
    got = project_with_jacobians_indexed(pts, images, cams, matrix_from_opk_with_derivatives(images[:, 3:]), img, cam)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
