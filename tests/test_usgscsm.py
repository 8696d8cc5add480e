"""Conformance of the pushbroom model with USGS usgscsm's line scanner, on the ISDs of usgscsm's own tests
(../shared/data/pushbroom/usgscsm; expected values from tests/LineScanCameraTests.cpp, EXPECTED_VALUES.txt)."""
import json
import os

import numpy as np
import pytest

from selfcal.adjust import adjust, AdjustOptions, SensorOptions
from selfcal.block import Block, Images, Observations, Points, PushbroomCamera
from selfcal.errors import BlockError
from selfcal.io.usgscsm import read_usgscsm_isd
from selfcal.sensors.pushbroom import PARAMETER_NAMES, ground_to_image, photo_coordinates
from selfcal.sensors.usgscsm import line_scan_from_isd

from conftest import SHARED_DATA

DATA = os.path.join(SHARED_DATA, "pushbroom", "usgscsm")


def setup_module():
    assert os.path.isdir(DATA), f"shared test data missing: {DATA}"


def _isd_json(name):
    with open(os.path.join(DATA, name)) as handle:
        return json.load(handle)


def _model(name):
    return line_scan_from_isd(read_usgscsm_isd(os.path.join(DATA, name)))


def test_orbital_line_scan_reproduces_usgscsm_ground_points():
    """usgscsm: imageToGround((8.5, 8), 0) = (999999.67004351015, 0, -812.35021438796923) to 1e-9 m;
    at h = 100 the point lies 1000100 m from the centre. Measured here: 1.2e-10 m."""
    model = _model("orbitalLineScan.json")
    ground = model.image_to_ground(8.5, 8.0, 0.0)[0]
    np.testing.assert_allclose(ground, [999999.67004351015, 0.0, -812.35021438796923], rtol=0, atol=1e-6)
    assert abs(np.linalg.norm(model.image_to_ground(8.5, 8.0, 100.0)[0]) - 1000100.0) < 1e-6
    lines = np.arange(0.5, 16.0, 1.0)
    for height in (0.0, 100.0, 4900.0):
        row, col = model.ground_to_image(model.image_to_ground(lines, np.full(lines.size, 8.0), height))
        assert np.max(np.abs(row - lines)) < 1e-4 and np.max(np.abs(col - 8.0)) < 1e-4


def test_constant_velocity_line_scan_reproduces_usgscsm():
    """The fly-by case: the centre point, the sensor position at line 8.5, the point of a line of sight
    that misses the 10 m sphere (usgscsm's nearest point) and the inversion at (8.5, 8)."""
    model = _model("constVelocityLineScan.json")
    np.testing.assert_allclose(model.image_to_ground(8.0, 8.0, 0.0)[0], [9.99999500000, 0.0, 0.00999999500],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(model.sensor_position(8.5)[0], [1000.0, 0.0, 0.0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(model.image_to_ground(0.0, 4.0, 0.0)[0], [0.04799688020, -7.99961602495,
                                                                         16.00004799688], rtol=0, atol=1e-8)
    row, col = model.ground_to_image(model.image_to_ground(8.5, 8.0, 0.0))
    assert abs(row[0] - 8.5) < 1e-4 and abs(col[0] - 8.0) < 1e-4


def test_flipped_orbital_line_scan_round_trip():
    model = _model("flippedOrbitalLineScan.json")
    row, col = model.ground_to_image(model.image_to_ground(8.7, 8.0, 0.0))
    assert abs(row[0] - 8.7) < 1e-4 and abs(col[0] - 8.0) < 1e-4


@pytest.mark.parametrize("name, height", [("toughLroNacLineScan.json", 2307.5), ("ctxLineScan.json", 0.0)])
def test_real_line_scanners_round_trip(name, height):
    """LRO NAC (2x2 summing, lrolrocnac distortion) and MRO CTX (radial distortion): every 100th pixel
    + 0.3 px to the ground at the height and back, as usgscsm's test tool does (measured: < 3e-10 px)."""
    model = _model(name)
    image = model.image
    lines, samples = np.meshgrid(np.arange(0, image.rows, 100) + 0.3, np.arange(0, image.camera.columns, 100) + 0.3)
    lines, samples = lines.ravel(), samples.ravel()
    ground = model.image_to_ground(lines, samples, height)
    radius = np.linalg.norm(ground, axis=1)
    if model.semi_major_m == model.semi_minor_m:
        np.testing.assert_allclose(radius, model.semi_major_m + height, rtol=0, atol=1e-4)
    row, col = model.ground_to_image(ground)
    assert np.max(np.abs(row - lines)) < 1e-4 and np.max(np.abs(col - samples)) < 1e-4
    assert model.focal_plane_misfit_mm < 1e-9


def test_isd_camera_jacobians_and_self_calibration():
    """The ISD camera is a selfcal pushbroom camera: its analytic Jacobians match finite differences, and
    the seed-001 adjustment recovers an attitude bias and drift put into it (truth) from 40 GCPs
    (0.1 m, image points with 0.1 px noise)."""
    model = _model("toughLroNacLineScan.json")
    image = model.image
    rng = np.random.default_rng(3)
    lines = rng.uniform(200, image.rows - 200, 40)
    samples = rng.uniform(50, image.camera.columns - 50, 40)
    truth = image.parameters.copy()
    truth[[0, 1, 2, 3]] = [2e-5, 1e-7, -3e-5, -2e-7]           # rad, rad/s
    true_image = image.with_parameters(truth)
    ground = model.image_to_ground(lines, samples, 1000.0)
    row, col = ground_to_image(true_image, ground)
    t = image.time_of_row(row)
    xy, d_par, d_pt = photo_coordinates(image, ground, t, jacobians=True)
    for k in (0, 3, 6):
        step = 1e-7 if k != 6 else 1e-3
        p = image.parameters.copy()
        p[k] += step
        fd = (photo_coordinates(image.with_parameters(p), ground, t) - xy) / step
        np.testing.assert_allclose(d_par[:, :, k], fd, rtol=1e-4, atol=1e-9 * np.abs(fd).max())
    noise = rng.normal(0, 0.1, (2, row.size))
    n = row.size
    cam = image.camera
    camera = PushbroomCamera("NAC", cam.columns, image.rows, cam.center_col, cam.pixel_size_mm, cam.focal_mm,
                             cam.line_period_s, "", "ECEF")
    nan3 = np.full((1, 3), np.nan)
    block = Block("lro-nac", "body-fixed", {"NAC": camera},
                  Images(np.array(["L"], object), np.array(["NAC"], object), np.array([""], object),
                         np.array([image.t_first_s]), nan3, nan3, np.array([2])),
                  Points(np.array([f"p{k}" for k in range(n)], object), np.full(n, "gcp", object), ground,
                         np.full((n, 3), 0.1), np.arange(n)),
                  Observations(np.zeros(n, np.int64), np.arange(n), np.column_stack([col + noise[1], row + noise[0]]),
                               np.full(n, 0.1), np.arange(n)),
                  0.1, image_models={"L": image})
    result = adjust(block, AdjustOptions(sensor=SensorOptions(model="d_roll0,d_roll1,d_pitch0,d_pitch1")))
    assert result.converged and 0.7 < np.sqrt(result.variance_factor) < 1.3
    sigma = result.image_sigma()[0]
    for k in np.flatnonzero(result.problem.image_free[0]):
        name, value = PARAMETER_NAMES[k], result.state.image[0, k]
        assert abs(value - truth[k]) < 4 * sigma[k], (name, value, truth[k], sigma[k])


def test_isd_reader_errors_name_the_file_and_key(tmp_path):
    isd = _isd_json("orbitalLineScan.json")
    del isd["focal2pixel_lines"]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(isd))
    with pytest.raises(BlockError, match=r"bad\.json: missing key 'focal2pixel_lines'"):
        read_usgscsm_isd(path)
    isd = _isd_json("orbitalLineScan.json")
    isd["instrument_pointing"]["quaternions"][3] = [0.5, 0.0, 0.0, 0.0]
    path.write_text(json.dumps(isd))
    with pytest.raises(BlockError, match=r"instrument_pointing\.quaternions' #3 is not a unit quaternion"):
        read_usgscsm_isd(path)
    isd = _isd_json("orbitalLineScan.json")
    isd["name_model"] = "USGS_ASTRO_FRAME_SENSOR_MODEL"
    path.write_text(json.dumps(isd))
    with pytest.raises(BlockError, match="only USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"):
        read_usgscsm_isd(path)


def _lro_truth(tmp_path, settings, truth_of, seed=7, heights_m=500.0):
    """The LRO NAC pair's ISDs (ISIS's tests) with known image parameters (``truth_of(rng, shape)``, the held
    entries zero), 60 GCPs per image (0.01 m, heights within +/- ``heights_m``) where the true cameras see
    random pixels, observed with 0.1 px noise, adjusted: (truth, result)."""
    from dataclasses import replace

    from selfcal.adjust.initial import initial_state
    from selfcal.adjust.problem import build_problem
    from selfcal.convert import block_from_isis
    from selfcal.io import read_block
    from selfcal.io.block_folder import write_block
    from selfcal.io.isis import read_control_network, read_image_folder

    folder = os.path.join(SHARED_DATA, "isis", "lro_nac_pair")
    block, _ = block_from_isis(read_control_network(os.path.join(folder, "observationPair.net")),
                               read_image_folder(folder), 0.1, "lro", settings)
    write_block(block, tmp_path / "lro")
    block = read_block(tmp_path / "lro")
    problem = build_problem(block)
    state, _ = initial_state(problem, block)
    rng = np.random.default_rng(seed)
    truth = truth_of(rng, state.image.shape) * problem.image_free
    state.image[:] = truth
    (slot,) = problem.sensors
    context = slot.bound.context(state, False)
    n = 60
    img = np.repeat([0, 1], n)
    rows = np.concatenate([rng.uniform(100, 52124, n) for _ in range(2)])
    cols = rng.uniform(20, 5044, 2 * n)
    ground = slot.bound.ground(context, img, np.column_stack([cols, rows]), rng.uniform(-heights_m, heights_m, 2 * n))
    pixel = slot.bound.pixels(context, img, ground) + rng.normal(0, 0.1, (2 * n, 2))
    points = replace(block.points, point_id=np.array([f"g{k}" for k in range(2 * n)], object),
                     role=np.full(2 * n, "gcp", object), xyz_m=ground, sigma_m=np.full((2 * n, 3), 0.01),
                     line=np.arange(2 * n))
    observations = replace(block.observations, image_index=img, point_index=np.arange(2 * n), pixel=pixel,
                           sigma_px=np.full(2 * n, 0.1), line=np.arange(2 * n), row=None)
    result = adjust(replace(block, points=points, observations=observations))
    assert result.converged and 0.7 < np.sqrt(result.variance_factor) < 1.3
    return truth, result


def test_line_scan_isd_attitude_polynomials_of_degree_3_are_recovered(tmp_path):
    """Truth for the usgscsm-line sensor of block folders: RA, DEC and TWIST corrections of degree 3 put into both
    LRO NAC images (truth, up to 30 urad, some 3 px at the ends): every coefficient within 4 sigma of its true
    value, sigma0 within 30 % of 1 (measured: every coefficient within 1.9 sigma)."""
    truth, result = _lro_truth(tmp_path, {"attitude_degree": 3},
                               lambda rng, shape: rng.uniform(-3e-5, 3e-5, shape))
    assert np.all(result.problem.image_free[:, :12]) and not result.problem.image_free[:, 12:].any()
    sigma = result.image_sigma()[:, :12]
    error = np.abs(result.state.image[:, :12] - truth[:, :12]) / sigma
    assert np.all(error < 4), (error.max(), np.unravel_index(error.argmax(), error.shape))
    # determined, not just consistent: RA and DEC to 1 urad (0.1 px); TWIST, about the line of sight, moves the
    # ends of the 5064-px line by 2500 px x angle, so 0.1 px leaves it some 10 urad (measured 12 - 71)
    assert np.all(sigma[:, :8] < 1e-6) and np.all(sigma[:, 8:] < 1e-4)


def test_line_scan_isd_position_offsets_are_recovered(tmp_path):
    """position_offsets = true (jigsaw's spsolve=position): a J2000 offset of each image's trajectory (truth up to
    100 m) besides RA/DEC/TWIST biases; the GCPs' heights (+/- 2 km) tell an offset from a turn of the pointing
    (the same ground shift at another height differs by h / range): every offset within 4 sigma of its truth,
    determined to better than 10 m (measured: within 0.7 sigma, sigma 1.5 - 1.8 m)."""
    def truth_of(rng, shape):
        out = np.zeros(shape)
        out[:, [0, 4, 8]] = rng.uniform(-3e-5, 3e-5, (shape[0], 3))
        out[:, 12:] = rng.uniform(-100, 100, (shape[0], 3))
        return out
    truth, result = _lro_truth(tmp_path, {"attitude_degree": 0, "position_offsets": True}, truth_of, 3, 2000.0)
    assert result.problem.image_free[:, 12:].all()
    sigma = result.image_sigma()
    free = result.problem.image_free
    error = np.abs(result.state.image - truth)[free] / sigma[free]
    assert np.all(error < 4), error
    assert np.all(sigma[:, 12:] < 10.0)