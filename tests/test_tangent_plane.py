"""Frame blocks in a projected CRS are adjusted in the local tangent plane at their centre and written back in the
CRS (DESIGN.md §2, issue 44 item 4): the plane's geometry against pyproj's own projection factors, and the seed-000
block placed in UTM far from the central meridian (k = 1.0004), ten times enlarged (9 x 5 km, 360 m of relief),
adjusted in the plane against the truth, and in the projection taken as Cartesian (the old path) against the
same truth."""
from dataclasses import replace

import numpy as np
import pytest

from selfcal.geometry.rotation import matrix_from_opk
from selfcal.geometry.tangent import TangentPlane

CRS = "EPSG:32633"                  # UTM 33N, central meridian 15 E
LON, LAT = 18.24, 45.1              # 255 km east of it: k = 1.0004, convergence 2.3 degrees


def _plane(height_m: float) -> TangentPlane:
    from pyproj import Transformer
    e, n = Transformer.from_crs("EPSG:4326", CRS, always_xy=True).transform(LON, LAT)
    return TangentPlane(CRS, (e, n, height_m))


@pytest.fixture(scope="module")
def plane():
    return _plane(400.0)


def test_plane_round_trip_and_the_projection_factors_of_pyproj(plane):
    """CRS -> plane -> CRS within 1e-8 m over 6 km; the Jacobian of the CRS's coordinates at an origin on the
    ellipsoid is k R(-gamma) in plan and 1 in height, k and gamma as PROJ's own factors give them, and 400 m
    above it k R / (R + h) in plan (6.3e-5 less: the elevation factor); the plane's up falls away from the
    ellipsoid by d^2 / 2R (0.71 m at 3 km)."""
    from pyproj import Proj
    rng = np.random.default_rng(1)
    xyz = np.array(plane.origin_crs) + rng.uniform(-3000, 3000, (50, 3))
    enu = plane.from_crs(xyz)
    assert np.abs(plane.to_crs(enu) - xyz).max() < 1e-8
    assert np.abs(plane.from_crs(np.array([plane.origin_crs]))).max() < 1e-8
    factors = Proj(CRS).get_factors(LON, LAT)
    k, gamma = factors.meridional_scale, np.radians(factors.meridian_convergence)
    assert 1.00035 < k < 1.00045 and 2.0 < np.degrees(gamma) < 2.5
    expected = np.array([[k * np.cos(gamma), -k * np.sin(gamma), 0.0],
                         [k * np.sin(gamma), k * np.cos(gamma), 0.0], [0.0, 0.0, 1.0]])
    J = _plane(0.0).jacobian(np.zeros((1, 3)))[0]
    np.testing.assert_allclose(J, expected, atol=2e-9)
    elevation = np.array([[6.3676e6 / (6.3676e6 + 400.0)] * 3, [6.3676e6 / (6.3676e6 + 400.0)] * 3, [1.0] * 3])
    J = plane.jacobian(np.zeros((1, 3)))[0]
    np.testing.assert_allclose(J, expected * elevation, atol=5e-7)
    R = plane.axes(np.zeros((1, 3)), J[None])[0]
    np.testing.assert_allclose(R, expected / np.array([[k], [k], [1.0]]), atol=2e-9)
    east = plane.to_crs(np.array([[3000.0, 0.0, 0.0]]))[0]
    assert abs(east[2] - 400.0 - 3000.0 ** 2 / (2 * 6.378e6)) < 0.01           # 0.706 m above the origin's height


def test_attitudes_against_the_crs_axes(plane):
    """A camera's rotation against the CRS's axes at its position and against the plane's agree as M_plane =
    M_crs R; there and back to 1e-15 rad; the angles' Jacobian equals central differences."""
    rng = np.random.default_rng(2)
    opk = np.column_stack([rng.normal(0, 0.05, 6), rng.normal(0, 0.05, 6), rng.uniform(-3, 3, 6)])
    at = rng.uniform(-3000, 3000, (6, 3))
    R = plane.axes(at)
    there = plane.attitudes_from_crs(opk, R)
    np.testing.assert_allclose(matrix_from_opk(there), matrix_from_opk(opk) @ R, atol=1e-14)
    back = plane.attitudes_to_crs(there, R)
    assert np.abs((back - opk + np.pi) % (2 * np.pi) - np.pi).max() < 1e-14
    A = TangentPlane.attitude_jacobian(opk, R)
    h = 1e-6
    numeric = np.stack([(plane.attitudes_from_crs(opk + h * e, R) - plane.attitudes_from_crs(opk - h * e, R)) / (2 * h)
                        for e in np.eye(3)], -1)
    np.testing.assert_allclose(A, numeric, atol=1e-8)
    # the kappa of a nadir image turns by the convergence
    assert abs(np.degrees(there[0, 2] - opk[0, 2]) - np.degrees(np.arctan2(R[0, 0, 1], R[0, 0, 0]))) < 0.05


@pytest.fixture(scope="module")
def utm_sim():
    """The seed-000 block (few tie points) in UTM 33N at k = 1.0004, ten times enlarged, calibrated camera
    (interior orientation held at the truth), 0.02 px of image noise (1.2 cm on the ground), control and check points at their true
    coordinates (sigma 5 mm), GNSS/IMU without shift (sigma 1 cm, 0.001 deg)."""
    from selfcal.simulate import simulate_uav
    from selfcal.simulate.projected import place_in_crs
    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=0.05, image_sigma_px=0.02, gnss_shift_m=0.0,
                       gnss_drift_mm_s=0.0, imu_shift_deg=0.0, gnss_sigma_m=(0.001,) * 3, imu_sigma_deg=(1e-4,) * 3)
    placed, plane = place_in_crs(sim, CRS, LON, LAT, 400.0, scale=10.0)
    truth = placed.truth
    camera = replace(truth.camera, sigma_focal_mm=0.0, sigma_x0_mm=0.0, sigma_y0_mm=0.0)
    blocks = {}
    for name, block in placed.blocks.items():
        marks = block.points.role != "tie"
        points = replace(block.points, xyz_m=np.where(marks[:, None], truth.xyz, np.nan),
                         sigma_m=np.where(marks[:, None], np.full(truth.xyz.shape, 0.005), np.nan))
        blocks[name] = replace(block, points=points, cameras={camera.camera_id: camera})
    return blocks, truth, plane


def _errors(outcome, truth):
    """Check points' errors against the truth in the CRS (points.csv), and the images' (images.csv)."""
    header, columns, _ = outcome.files["points.csv"]
    c = dict(zip(header, columns))
    where = {p: k for k, p in enumerate(truth.point_id)}
    chk = np.flatnonzero(c["role"] == "chk")
    xyz = np.column_stack([c["X"], c["Y"], c["Z"]])[chk]
    d = xyz - truth.xyz[[where[p] for p in c["point_id"][chk]]]
    header, columns, _ = outcome.files["images.csv"]
    im = dict(zip(header, columns))
    names = ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")
    eop = np.column_stack([im[k] for k in names])
    e = eop - np.column_stack([truth.eop[:, :3], np.degrees(truth.eop[:, 3:])])
    e[:, 3:] = (e[:, 3:] + 180.0) % 360.0 - 180.0
    sigma = np.column_stack([im[k] for k in ("sigma_X0_m", "sigma_Y0_m", "sigma_Z0_m", "sigma_omega_deg",
                                             "sigma_phi_deg", "sigma_kappa_deg")])
    return d, e / sigma


def test_a_utm_block_adjusted_in_its_tangent_plane_meets_the_truth_and_the_projection_does_not(utm_sim):
    """Type 1 (15 GCP, 24 CHK): in the plane the check points meet the truth in the CRS within 2 cm in plan and
    3 cm in height (the noise: 0.02 px is 1.2 cm on the ground), the images' positions and angles within 4.5 of
    their sigmas in the CRS (168 values; the RMS of error / sigma 0.5-1.5: the sigmas are honest); the
    projection taken as Cartesian (crs "local": the old path) is off by more than 5 cm in plan and 15 cm in
    height (the projection's scale k against the unscaled heights, and the curvature), and its sigma0 shows the
    misfit. The results say the plane, and the files are in the CRS."""
    from selfcal.workflows.api import bundle_adjust
    blocks, truth, plane = utm_sim
    block = blocks["type1"]
    new = bundle_adjust(block, "none", robust="none", snoop=0, control_loo=False)
    old = bundle_adjust(replace(block, crs="local"), "none", robust="none", snoop=0, control_loo=False)
    d_new, e_new = _errors(new, truth)
    d_old, _ = _errors(old, truth)
    rms = lambda d: (np.sqrt(np.mean(np.sum(d[:, :2] ** 2, 1))), np.sqrt(np.mean(d[:, 2] ** 2)))  # noqa: E731
    xy_new, z_new = rms(d_new)
    xy_old, z_old = rms(d_old)
    assert xy_new < 0.02 and z_new < 0.03, (xy_new, z_new)
    assert xy_old > 0.05 and z_old > 0.15, (xy_old, z_old)
    assert np.abs(e_new).max() < 4.5 and 0.5 < np.sqrt(np.mean(e_new ** 2)) < 1.5, np.sqrt(np.mean(e_new ** 2, 0))
    assert new.summary["sigma0_px"] < 0.025 < old.summary["sigma0_px"]
    s = new.summary
    assert s["crs"] == CRS and s["object_frame"]["heights"] == "ellipsoidal"
    assert abs(s["object_frame"]["origin_lat_deg"] - LAT) < 0.05
    # the summary's check-point figures are those of points.csv (reference = truth here)
    assert abs(s["rmsd_chk_z_m"] - z_new) < 1e-6 and abs(s["rmsd_chk_xy_m"] - xy_new) < 1e-6
    geo = new.files["check_points.geojson"]
    assert geo["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32633"
    first = geo["features"][0]
    k = list(truth.point_id).index(first["properties"]["point_id"])
    assert np.abs(np.array(first["geometry"]["coordinates"]) - truth.xyz[k]).max() < 1e-6
    ply = new.files["points.ply"]["vertices"]
    assert abs(ply["x"][k] - truth.xyz[k, 0]) < 0.05


def test_gnss_imu_and_the_control_validation_in_the_crs(utm_sim):
    """Type 2 (GNSS/IMU with a shift per strip): in the plane the trajectory's shifts come out in the CRS near
    zero (the truth) with their sigmas, the check points within the noise; the leave-one-out errors of the
    control are along the CRS's coordinates (each within 4 sigma: nothing is wrong with the control)."""
    from selfcal.workflows.api import bundle_adjust
    blocks, truth, _ = utm_sim
    out = bundle_adjust(blocks["type2"], "none", robust="none", snoop=0, gnss_drift=0, imu_drift=0)
    d, e = _errors(out, truth)
    assert np.sqrt(np.mean(np.sum(d[:, :2] ** 2, 1))) < 0.02 and np.sqrt(np.mean(d[:, 2] ** 2)) < 0.03
    header, columns, _ = out.files["trajectory.csv"]
    t = dict(zip(header, columns))
    gnss = t["sensor"] == "GNSS"
    assert np.all(np.abs(t["value"][gnss]) < 4 * t["sigma"][gnss] + 1e-3)
    assert np.all(np.isfinite(t["sigma"]))
    header, columns, _ = out.files["control_loo.csv"]
    loo = dict(zip(header, columns))
    assert len(loo["point_id"]) == 15 and np.nanmax(np.abs(np.column_stack([loo["w_X"], loo["w_Y"], loo["w_Z"]]))) < 4


def test_the_block_in_its_plane_weighs_control_along_the_crs(utm_sim):
    """The converted block: control weights diag(1 / sigma) J (J the CRS's coordinates by the plane's), GNSS
    sigmas turned into the plane, images and points at the plane's coordinates of the CRS's; a local block and
    a geographic one are refused or left alone as DESIGN-NOTES says."""
    from selfcal.adjust.residuals.control import control_weights
    from selfcal.errors import BlockError
    from selfcal.workflows.frames import tangent_plane_block
    blocks, truth, plane = utm_sim
    block = blocks["type2"]
    converted, found = tangent_plane_block(block)
    assert found.crs == CRS and found.heights == "ellipsoidal"
    assert np.allclose(found.origin_geodetic[:2], (LAT, LON), atol=0.05)      # (the block's centre)
    gcp = np.flatnonzero(block.points.role == "gcp")
    W = control_weights(converted, gcp, "block")
    J = found.jacobian(converted.points.xyz_m[gcp])
    np.testing.assert_allclose(W, J / 0.005, rtol=1e-12)
    np.testing.assert_allclose(found.to_crs(converted.images.position_m), block.images.position_m, atol=1e-8)
    assert converted.images.gnss_sigma_m.shape == (len(block.images), 3)
    np.testing.assert_allclose(converted.images.gnss_sigma_m, 0.01, rtol=1e-3)      # (equal sigmas: 1/k of them)
    same, none = tangent_plane_block(replace(block, crs="local"))
    assert none is None and same.points is block.points
    with pytest.raises(BlockError, match="not projected"):
        tangent_plane_block(replace(block, crs="EPSG:4326"))
    with pytest.raises(BlockError, match="pyproj knows"):
        tangent_plane_block(replace(block, crs="EPSG:999999"))
