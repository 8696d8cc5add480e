"""The generic pushbroom sensor model and the M1-M7 self-calibration of seed 001, against the
simulated PRISM triplet (known focal lengths, attitude bias and drift, boresight misalignment)."""
import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, SensorOptions
from selfcal.errors import UsageError
from selfcal.sensors.pushbroom import (PARAMETER_NAMES, SENSOR_MODELS, ground_to_image, image_to_ground, intersect,
                                       line_images, photo_coordinates, sensor_model, track_frame)
from selfcal.workflows.seed001 import ATTITUDE_FREE_SIGMA, calibrate_focal, choose_gcps, run_case, with_focal
from selfcal.simulate.prism import (ATTITUDE_BIAS_RAD, ATTITUDE_DRIFT_RAD_S, NADIR_CENTRE_S, TRUE_FOCAL_MM,
                                    prism_block, simulate_prism)

PIXEL_M = 2.5          # ground sample distance of the simulated PRISM images


@pytest.fixture(scope="module")
def sim():
    return simulate_prism(seed=1)


@pytest.fixture(scope="module")
def data(sim):
    """The simulation as a block (5 GCPs with 0.1 m survey error, 23 check points)."""
    return prism_block(sim, seed=1)


@pytest.fixture(scope="module")
def calibrated(data, sim):
    """Step 1: focal lengths from M7 on the triplet with the 5 GCPs; the block with them."""
    focal, sigma = calibrate_focal(data)
    return focal, sigma, with_focal(data, focal)


def _case(block, dem, model, n_gcp, image_set, label=""):
    return run_case(block, model, choose_gcps(block, n_gcp), image_set, dem, label)


def test_triplet_sees_every_point_in_every_image(sim):
    assert np.bincount(sim.obs_image).tolist() == [28, 28, 28]
    # forward sees the scene first, about 45 s before nadir and backward after it
    t = sim.t_first_s
    assert 40 < t["N"] - t["F"] < 50 and 40 < t["B"] - t["N"] < 50


def test_ground_image_ground_round_trip(sim):
    """ground -> image -> ground within 1 mm, image -> ground -> image within 1e-4 px."""
    for image in sim.truth.images:
        row, col = ground_to_image(image, sim.points_ecef)
        back = image_to_ground(image, row, col, sim.dem, tolerance_m=1e-5)
        assert np.max(np.linalg.norm(back - sim.points_ecef, axis=1)) < 1e-3
        rng = np.random.default_rng(0)
        rows, cols = rng.uniform(0, image.rows, 50), rng.uniform(0, image.camera.columns, 50)
        ground = image_to_ground(image, rows, cols, 500.0, tolerance_m=1e-6)
        row2, col2 = ground_to_image(image, ground)
        assert np.max(np.abs(row2 - rows)) < 1e-4 and np.max(np.abs(col2 - cols)) < 1e-4


def test_jacobians_match_finite_differences(sim, data):
    image = line_images(data)[0]
    parameters = image.parameters.copy()
    parameters[[0, 1, 2, 3, 4, 5, 7, 8, 9]] = [2e-5, 1e-6, -3e-5, 2e-6, 4e-5, -1e-6, 1e-5, -2e-5, 3e-5]
    image = image.with_parameters(parameters)
    points = sim.points_ecef[:6]
    t = image.time_of_row(np.linspace(100, 13000, 6))
    _, d_par, d_pt = photo_coordinates(image, points, t, jacobians=True)
    steps = np.array([1e-7, 1e-8, 1e-7, 1e-8, 1e-7, 1e-8, 1e-3, 1e-7, 1e-7, 1e-7])
    for k, h in enumerate(steps):
        up, down = parameters.copy(), parameters.copy()
        up[k] += h
        down[k] -= h
        numeric = (photo_coordinates(image.with_parameters(up), points, t)
                   - photo_coordinates(image.with_parameters(down), points, t)) / (2 * h)
        np.testing.assert_allclose(d_par[:, :, k], numeric, rtol=1e-5, atol=1e-9 * np.abs(numeric).max() + 1e-12,
                                   err_msg=PARAMETER_NAMES[k])
    for a in range(3):
        e = np.zeros(3)
        e[a] = 0.01
        numeric = (photo_coordinates(image, points + e, t) - photo_coordinates(image, points - e, t)) / 0.02
        np.testing.assert_allclose(d_pt[:, :, a], numeric, rtol=1e-6, atol=1e-12)


def test_attitude_from_quaternions_recovers_the_telemetry():
    """Noise-free telemetry: roll/pitch/yaw fitted from the quaternions are the true attitude minus
    the simulated bias and drift (Eqs. 2-5), and the position fit is exact."""
    quiet = simulate_prism(seed=3, ephemeris_sigma_m=0.0, attitude_sigma_rad=0.0)
    for image, true in zip(line_images(prism_block(quiet)), quiet.truth.images):
        t = image.time_of_row(np.linspace(0, image.rows, 11))
        expected = true.trajectory.attitude(t) - (ATTITUDE_BIAS_RAD + np.outer(t - NADIR_CENTRE_S, ATTITUDE_DRIFT_RAD_S))
        np.testing.assert_allclose(image.trajectory.attitude(t), expected, atol=1e-10)
        assert np.max(np.abs(image.trajectory.position(t) - true.trajectory.position(t))) < 1e-3
        assert np.all(image.trajectory.fit_rms["attitude_rad"] < 1e-10)


def test_focal_length_recovered_within_0_1_mm(calibrated):
    focal, sigma, _ = calibrated
    for camera, true in TRUE_FOCAL_MM.items():
        assert abs(focal[camera] - true) < 0.1, (camera, focal[camera], true)
        assert sigma[camera] < 0.05
    # the nominal 1939 mm is 0.8 - 2.3 mm off: the calibration is what brings it within 0.1 mm
    assert all(abs(1939.0 - true) > 0.7 for true in TRUE_FOCAL_MM.values())


def test_models_one_to_four_leave_the_drift_along_track(sim, data, calibrated):
    """Mono nadir, 4 GCPs: constant corrections (M1-M4) leave the simulated attitude drift as an
    along-track error above a pixel; constant + linear terms (M5-M7) bring X and Y below a pixel."""
    block = calibrated[2]
    rmse = {m: _case(block, sim.dem, m, 4, (1,)).rmse_m for m in SENSOR_MODELS}
    for m in ("M1", "M2", "M3", "M4"):
        assert rmse[m][1] > PIXEL_M and rmse[m][0] < PIXEL_M, (m, rmse[m])
    for m in ("M5", "M6", "M7"):
        assert np.all(rmse[m][:2] < 0.5 * PIXEL_M), (m, rmse[m])
        assert rmse[m][1] < 0.4 * rmse["M1"][1]


@pytest.mark.parametrize("image_set", [(0,), (1,), (2,)])
def test_m6_with_three_gcps_is_sub_pixel(sim, data, calibrated, image_set):
    """M6's parameter weights make three GCPs enough (M5 and M7 have no redundancy with three)."""
    block = calibrated[2]
    case = _case(block, sim.dem, "M6", 3, image_set)
    assert np.all(case.rmse_m[:2] < PIXEL_M), case.rmse_m
    assert _case(block, sim.dem, "M7", 3, image_set).rmse_m is None


def test_stereo_triplet_is_sub_pixel_and_as_precise_as_it_says(sim, data, calibrated):
    block = calibrated[2]
    case = _case(block, sim.dem, "M6", 4, (0, 1, 2), "F+N+B")
    assert case.n_check == 24 and np.all(case.rmse_m < PIXEL_M), case.rmse_m
    assert 0.7 < case.sigma0 < 1.3
    # the height error is what the a-posteriori precision predicts (base-to-height 0.88, 0.3 px)
    _, R = track_frame(line_images(block)[1])
    check_cov = case.result.point_covariance()[case.result.block.points.role == "chk"]
    sigma_z = np.sqrt(np.mean([(R @ c @ R.T)[2, 2] for c in check_cov]))
    assert 0.6 < case.rmse_m[2] / sigma_z < 1.5


def test_attitude_free_run_matches_the_given_attitude_within_ten_percent(sim):
    """Seed 001, Table 5: without the attitude telemetry, M6's corrections alone reach the same
    accuracy (the constant terms take the whole attitude)."""
    block = with_focal(prism_block(sim, seed=1), TRUE_FOCAL_MM)
    gcps = choose_gcps(block, 4)
    a = run_case(block, "M6", gcps, (1,), sim.dem).rmse_m
    b = run_case(block, "M6", gcps, (1,), sim.dem,
                 options=AdjustOptions(sensor=SensorOptions(attitude_telemetry=False, parameter_sigma=ATTITUDE_FREE_SIGMA))).rmse_m
    planimetric = np.hypot(*a[:2]), np.hypot(*b[:2])
    assert abs(planimetric[1] / planimetric[0] - 1.0) < 0.10, (a, b)
    assert planimetric[1] < PIXEL_M


def test_stereo_intersection_with_covariance(sim):
    """Error-free image points of the true images intersect at the true point; the covariance
    scales with the image sigma and is larger in height than across track for F+N."""
    images = sim.truth.images
    p = 7
    rows, cols, which = [], [], []
    for i, image in enumerate(images[:2]):
        r, c = ground_to_image(image, sim.points_ecef[p:p + 1])
        rows.append(r[0])
        cols.append(c[0])
        which.append(i)
    X, cov = intersect(images, np.array(which), np.array(rows), np.array(cols), sigma_px=0.3)
    assert np.linalg.norm(X - sim.points_ecef[p]) < 1e-3
    _, cov1 = intersect(images, np.array(which), np.array(rows), np.array(cols), sigma_px=1.0)
    np.testing.assert_allclose(cov1, cov / 0.09, rtol=1e-6)
    eigen = np.sqrt(np.linalg.eigvalsh(cov))
    assert eigen[-1] > 3 * eigen[0]            # the height, with base-to-height 0.44


def test_sensor_model_presets_are_those_of_seed_001():
    assert SENSOR_MODELS["M1"] == ("d_roll0", "d_pitch0")
    assert SENSOR_MODELS["M2"] == ("d_roll0", "d_pitch0", "d_yaw0")
    assert SENSOR_MODELS["M3"] == ("d_roll0", "d_pitch0", "focal")
    assert SENSOR_MODELS["M4"] == ("d_roll0", "d_pitch0", "d_yaw0", "focal")
    assert set(SENSOR_MODELS["M5"]) == {"d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1"}
    assert SENSOR_MODELS["M6"] == SENSOR_MODELS["M5"] and sensor_model("M6").prior_sigma
    assert not sensor_model("M5").prior_sigma
    assert set(SENSOR_MODELS["M7"]) == set(SENSOR_MODELS["M5"]) | {"focal"}
    custom = sensor_model("d_pitch0,boresight_roll")
    assert custom.free == ("d_pitch0", "boresight_roll")
    with pytest.raises(UsageError, match="unknown sensor model"):
        sensor_model("M8")


@pytest.mark.slow
def test_cli_simulate_adjust_and_compare(tmp_path, capsys):
    """Through the files: simulate the triplet, adjust the nadir image with M6 and 4 GCPs after the
    focal-length step, recover the simulated attitude bias and drift, and tabulate M1 against M6."""
    import csv
    import json

    from conftest import run_cli

    assert run_cli("simulate", "prism", "--out", str(tmp_path / "sim"), "--seed", "2") == 0
    block = str(tmp_path / "sim" / "triplet")
    assert run_cli("adjust", block, "--out", str(tmp_path / "res"), "--sensor-model", "M6", "--images", "N",
                   "--gcps", "4") == 0
    summary = json.loads((tmp_path / "res" / "summary.json").read_text())
    assert summary["n_gcp_used"] == 4 and summary["n_chk_used"] == 24 and summary["n_obs_rejected"] == 0
    # the results schema of every sensor (DESIGN.md §4): the common keys, residuals.csv with w and rejected,
    # points.csv with its role column; the check-point RMSD in east/north/up beside across/along/up
    assert summary["schema_version"] == 2 and summary["sensors"] == ["pushbroom"]
    assert np.isclose(summary["rmsd_chk_xy_m"], np.hypot(summary["rmse_chk_across_m"], summary["rmse_chk_along_m"]),
                      rtol=1e-3) and np.isclose(summary["rmsd_chk_z_m"], summary["rmse_chk_up_m"], rtol=1e-3)
    residuals = (tmp_path / "res" / "residuals.csv").read_text().splitlines()
    assert residuals[0].startswith("image_id,point_id,vx_px,vy_px,w_test,rejected") and len(residuals) == 1 + 4
    assert (tmp_path / "res" / "points.csv").read_text().startswith("point_id,role,X,Y,Z,")
    assert summary["rmse_chk_across_m"] < PIXEL_M and summary["rmse_chk_along_m"] < PIXEL_M
    for camera, true in TRUE_FOCAL_MM.items():
        assert abs(summary["calibrated_focal_mm"][camera]["value"] - true) < 0.1
    with open(tmp_path / "res" / "parameters.csv") as handle:
        estimated = {row["parameter"]: (float(row["value"]), float(row["sigma"])) for row in csv.DictReader(handle)
                     if row["owner"] == "N" and row["active"] == "1"}
    # the nadir scene is centred on the reference time of the simulated attitude error
    truth = {"d_roll0": ATTITUDE_BIAS_RAD[0], "d_pitch0": ATTITUDE_BIAS_RAD[1],
             "d_roll1": ATTITUDE_DRIFT_RAD_S[0], "d_pitch1": ATTITUDE_DRIFT_RAD_S[1]}
    for name, value in truth.items():
        got, sigma = estimated[name]
        assert abs(got - np.degrees(value)) < 4 * sigma, (name, got, np.degrees(value), sigma)
    html = (tmp_path / "res" / "report.html").read_text()
    assert "Calibration parameters" in html and 'id="check-points"' in html and html.count("<img") >= 3
    assert run_cli("report", str(tmp_path / "res")) == 0
    # screening through the files: the triplet with M5, the dropped parameters listed in order
    assert run_cli("adjust", block, "--out", str(tmp_path / "scr"), "--sensor-model", "M5", "--gcps", "4",
                   "--screen", "--no-report") == 0
    screening = json.loads((tmp_path / "scr" / "screening.json").read_text())
    with open(tmp_path / "scr" / "parameters.csv") as handle:
        kept = [row for row in csv.DictReader(handle) if row["active"] == "1"]
    assert screening["n_parameters_initial"] == 18 and screening["n_parameters_kept"] == len(kept)
    assert len(screening["dropped"]) == 18 - len(kept) > 0
    assert all(d["t"] < 1.96 or d["reason"].startswith("correlated") for d in screening["dropped"])
    capsys.readouterr()
    assert run_cli("compare", block, "--out", str(tmp_path / "cmp"), "--sensor-models", "M1,M6", "--gcps", "4") == 0
    table = (tmp_path / "cmp" / "comparison.md").read_text()
    assert "| M1 |" in table and "| M6 |" in table and "## F+N+B" in table


def test_cli_pushbroom_input_errors(tmp_path, capsys):
    from conftest import run_cli

    assert run_cli("simulate", "prism", "--out", str(tmp_path / "sim")) == 0
    block = tmp_path / "sim" / "triplet"
    capsys.readouterr()
    assert run_cli("adjust", str(block), "--out", str(tmp_path / "r"), "--images", "X") == 2
    assert "--images X" in capsys.readouterr().err
    text = (block / "block.toml").read_text().replace('dem = "dem.tif"\n', "")
    (block / "block.toml").write_text(text)
    assert run_cli("adjust", str(block), "--out", str(tmp_path / "r"), "--images", "N") == 2
    assert "give --dem" in capsys.readouterr().err
    lines = (block / "attitude.csv").read_text().splitlines()
    fields = lines[5].split(",")
    fields[2] = "0.5"
    lines[5] = ",".join(fields)
    (block / "attitude.csv").write_text("\n".join(lines) + "\n")
    assert run_cli("adjust", str(block), "--out", str(tmp_path / "r")) == 2
    err = capsys.readouterr().err
    assert "attitude.csv" in err and "line 6" in err and "unit quaternion" in err
    assert not (tmp_path / "r").exists()


def test_data_snooping_finds_a_blunder_in_the_triplet(sim):
    """A 4 px blunder in one image point (13 sigma): the largest |w| is that point's; snooping rejects it
    alone and the check points come back to the blunder-free accuracy."""
    import dataclasses

    from selfcal.stats.snooping import SnoopingOptions

    clean = with_focal(prism_block(sim, seed=1), TRUE_FOCAL_MM)
    obs = clean.observations
    k = int(np.flatnonzero((obs.image_index == 0) & (obs.point_index == 10))[0])
    pixel = obs.pixel.copy()
    pixel[k, 0] += 4.0
    spoiled = dataclasses.replace(clean, observations=dataclasses.replace(obs, pixel=pixel))
    gcps = choose_gcps(clean, 4)
    reference = run_case(clean, "M6", gcps, (0, 1, 2), sim.dem, "F+N+B")
    plain = run_case(spoiled, "M6", gcps, (0, 1, 2), sim.dem, "F+N+B")
    snooped = run_case(spoiled, "M6", gcps, (0, 1, 2), sim.dem, "F+N+B", snooping=SnoopingOptions())
    w = np.abs(plain.tested.tests.image_w)          # the triplet keeps every observation in the block's order
    assert np.argmax(w.max(axis=1)) == k
    assert list(snooped.tested.rejected_rows) == [k] and snooped.tested.rejected_w[0] > 8
    assert np.abs(plain.rmse_m[0] - reference.rmse_m[0]) > 0.2
    np.testing.assert_allclose(snooped.rmse_m, reference.rmse_m, rtol=0.1)
    # every image coordinate is controlled and none is fully redundant
    r = reference.tested.tests.image_redundancy
    assert np.all((r > 0) & (r < 1))


def test_chip_offsets_of_the_virtual_array_are_modelled(sim, tmp_path):
    """The simulated chips are displaced by up to 0.7 px: with their offsets (block.toml chip_starts,
    chip_offsets_px) the triplet fits to the image noise; without them sigma0 and the check points suffer.
    The offsets also survive the block folder."""
    import dataclasses

    from selfcal.io import read_block
    from selfcal.io.block_folder import write_block

    block = prism_block(sim, seed=1)
    folder = tmp_path / "triplet"
    write_block(dataclasses.replace(block, dem_path=None, terrain_height_m=500.0), folder)
    again = read_block(folder)
    assert again.cameras["N"].chip_offsets_px == block.cameras["N"].chip_offsets_px
    assert again.cameras["N"].chip_starts == (4832, 9664)
    ideal = dataclasses.replace(block, cameras={k: dataclasses.replace(c, chip_starts=None, chip_offsets_px=None)
                                                for k, c in block.cameras.items()})
    cases = [_case(with_focal(b, TRUE_FOCAL_MM), sim.dem, "M6", 4, (0, 1, 2)) for b in (block, ideal)]
    modelled, ignored = cases
    assert 0.7 < modelled.sigma0 < 1.3 and ignored.sigma0 > 1.3 * modelled.sigma0
    assert np.hypot(*ignored.rmse_m[:2]) > np.hypot(*modelled.rmse_m[:2])


def test_screening_drops_the_parameters_that_are_zero_in_truth():
    """Attitude error without yaw and without roll drift: screening M5 on the nadir image (no boresight
    misalignment) drops only parameters whose true value is zero, keeps the roll and pitch bias and the
    pitch drift, and leaves the check points as accurate as the full model (within 10 %). On the
    triplet with M7 started at the true focal lengths, every focal length is found insignificant."""
    from selfcal.stats.screening import ScreeningOptions

    sim = simulate_prism(seed=2, attitude_bias_rad=(3e-5, -4e-5, 0.0), attitude_drift_rad_s=(0.0, 3e-6, 0.0))
    data = with_focal(prism_block(sim, seed=2), TRUE_FOCAL_MM)
    gcps = choose_gcps(data, 5)
    full = run_case(data, "M5", gcps, (1,), sim.dem, "N")
    screened = run_case(data, "M5", gcps, (1,), sim.dem, "N", screening=ScreeningOptions())
    decisions = [d for _, d in screened.tested.screening_log]
    dropped = {d.name for d in decisions}
    assert dropped and dropped <= {"d_roll1", "d_yaw0", "d_yaw1"}, decisions
    assert "d_yaw1" in dropped
    problem = screened.result.problem
    assert [n for n, f in zip(problem.image_names[0], problem.image_free[0]) if f] == [
        n for n in SENSOR_MODELS["M5"] if n not in dropped]
    joint = screened.tested.screening_rounds[-1][1]
    assert joint.f_statistic < joint.f_critical
    np.testing.assert_allclose(np.hypot(*screened.rmse_m[:2]), np.hypot(*full.rmse_m[:2]), rtol=0.1)
    triplet = run_case(data, "M7", choose_gcps(data, 4), (0, 1, 2), sim.dem, "F+N+B", screening=ScreeningOptions())
    assert {(d.camera_id, d.name) for _, d in triplet.tested.screening_log} >= {("F", "focal"), ("N", "focal"),
                                                                               ("B", "focal")}
    assert not any(cam.free[0] for cam in triplet.result.problem.cameras)
