"""Exports of a calibration, checked with the programs that read them: OpenCV (cv2) and COLMAP (pycolmap).

The half-pixel convention is the classic exporter bug: selfcal and COLMAP put the centre of the first
pixel at (0.5, 0.5), OpenCV at (0, 0). Every test here compares positions in one convention with
positions the other program computed in its own.
"""
import json

import cv2
import numpy as np
import pytest

from selfcal.ap import ImageFrame, create_ap
from selfcal.calibration import Calibration, fit_opencv, undistortion_maps

from conftest import run_cli

WIDTH, HEIGHT, PIXEL_MM, FOCAL_MM = 1500, 1000, 0.004, 6.0


def camera_entry(spec="brown", values=None, x0_mm=0.0, y0_mm=0.0, ap=None):
    """camera.json entry of a frame camera (as selfcal adjust writes it)."""
    frame = ImageFrame(WIDTH * PIXEL_MM, HEIGHT * PIXEL_MM, PIXEL_MM)
    ap = ap or create_ap(spec, frame)
    values = np.zeros(ap.n_params) if values is None else np.asarray(values, float)
    return {"model": "frame", "width_px": WIDTH, "height_px": HEIGHT, "pixel_size_mm": PIXEL_MM,
            "focal_mm": {"value": FOCAL_MM}, "x0_mm": {"value": x0_mm}, "y0_mm": {"value": y0_mm},
            "ap": {**ap.to_dict(), "coefficients": [{"name": n, "value_px": float(v), "active": True}
                                                    for n, v in zip(ap.parameter_names, values)]}}


def results_folder(path, entry):
    path.mkdir()
    (path / "camera.json").write_text(json.dumps({"cameras": {"cam1": entry}}))
    return path


def read_opencv_yaml(path):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K = storage.getNode("camera_matrix").mat()
    dist = storage.getNode("distortion_coefficients").mat().ravel()
    misfit = storage.getNode("misfit_max_px").real()
    model = storage.getNode("distortion_model").string()
    storage.release()
    return K, dist, misfit, model


def measured_and_rays(cal, n=400, seed=0):
    """Random measured positions over the image and 3-D points (OpenCV camera frame) seen there."""
    measured = np.random.default_rng(seed).uniform([0, 0], [cal.width_px, cal.height_px], (n, 2))
    normalised = cal.normalised_from_measured(measured)
    depth = np.random.default_rng(seed + 1).uniform(5, 50, n)
    return measured, np.column_stack([normalised * depth[:, None], depth])


# Brown with about 27 px of radial distortion at the corner and a little tangential distortion
BROWN = [-30.0, 3.0, 0.0, 0.1, -0.05, 0.0, 0.0]


def test_opencv_yaml_projects_like_selfcal(tmp_path, capsys):
    """OpenCV's projectPoints with the exported YAML lands within 0.01 px of selfcal's measured position."""
    folder = results_folder(tmp_path / "r", camera_entry("brown", BROWN, x0_mm=0.0, y0_mm=0.0))
    assert run_cli("export", "opencv", str(folder), "--out", str(tmp_path / "cam.yaml")) == 0
    assert "warning" not in capsys.readouterr().err
    K, dist, misfit, model = read_opencv_yaml(tmp_path / "cam.yaml")
    assert misfit <= 0.01 and model in ("opencv4", "plumb_bob", "rational", "thin_prism")
    cal = Calibration.from_camera_json("cam1", camera_entry("brown", BROWN))
    measured, points = measured_and_rays(cal)
    projected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, dist)
    miss = np.hypot(*(projected[:, 0] - (measured - 0.5)).T)       # OpenCV: first pixel centre at (0, 0)
    assert miss.max() < 0.01, miss.max()
    # the distortion is not small: a pinhole projection would be off by up to 30 px
    pinhole, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, np.zeros(5))
    assert np.max(np.hypot(*(pinhole[:, 0] - (measured - 0.5)).T)) > 20


def test_opencv_misfit_is_reported_as_measured(tmp_path, capsys):
    """A shear (b2) and a principal point off centre have no exact OpenCV form: the YAML's misfit is the
    largest difference OpenCV itself shows, and the CLI warns."""
    values = [-30.0, 3.0, 1.0, 0.15, -0.1, 0.0, 1.5]
    entry = camera_entry("brown", values, x0_mm=0.15, y0_mm=-0.1)
    folder = results_folder(tmp_path / "r", entry)
    assert run_cli("export", "opencv", str(folder), "--out", str(tmp_path / "cam.yaml")) == 0
    assert "warning" in capsys.readouterr().err
    K, dist, misfit, _ = read_opencv_yaml(tmp_path / "cam.yaml")
    cal = Calibration.from_camera_json("cam1", entry)
    col, row = np.meshgrid(np.linspace(0, WIDTH, 121), np.linspace(0, HEIGHT, 81))
    measured = np.column_stack([col.ravel(), row.ravel()])
    n = cal.normalised_from_measured(measured)
    projected, _ = cv2.projectPoints(np.column_stack([n, np.ones(len(n))]), np.zeros(3), np.zeros(3), K, dist)
    miss = np.hypot(*(projected[:, 0] - (measured - 0.5)).T)
    assert misfit > 0.1
    assert miss.max() == pytest.approx(misfit, rel=1e-6)


def test_colmap_cameras_txt_projects_like_selfcal(tmp_path):
    """pycolmap reads the exported camera and projects where selfcal measures (COLMAP's pixel convention)."""
    import pycolmap
    entry = camera_entry("brown", [-30.0, 3.0, 0.0, 0.05, -0.03, 0.0, 0.0], x0_mm=0.0, y0_mm=0.0)
    folder = results_folder(tmp_path / "r", entry)
    assert run_cli("export", "colmap", str(folder), "--out", str(tmp_path / "cameras.txt")) == 0
    fields = [line.split() for line in (tmp_path / "cameras.txt").read_text().splitlines()
              if not line.startswith("#")]
    assert len(fields) == 1 and fields[0][1] in ("OPENCV", "FULL_OPENCV")
    camera = pycolmap.Camera(model=fields[0][1], width=int(fields[0][2]), height=int(fields[0][3]),
                             params=[float(v) for v in fields[0][4:]])
    cal = Calibration.from_camera_json("cam1", entry)
    measured, points = measured_and_rays(cal)
    miss = np.hypot(*(camera.img_from_cam(points) - measured).T)
    assert miss.max() < 0.01, miss.max()


def test_half_pixel_convention_without_distortion(tmp_path):
    """No distortion, principal point at the frame centre: OpenCV's cx is W/2 - 0.5, COLMAP's W/2, and
    the undistortion maps are the identity."""
    folder = results_folder(tmp_path / "r", camera_entry("none"))
    assert run_cli("export", "opencv", str(folder), "--out", str(tmp_path / "cam.yaml")) == 0
    K, dist, misfit, _ = read_opencv_yaml(tmp_path / "cam.yaml")
    np.testing.assert_allclose(K[:2, 2], [WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5], atol=1e-9)
    np.testing.assert_allclose(K[0, 0], FOCAL_MM / PIXEL_MM, rtol=1e-12)
    np.testing.assert_allclose(dist, 0.0, atol=1e-12)
    assert run_cli("export", "colmap", str(folder), "--out", str(tmp_path / "cameras.txt")) == 0
    params = [float(v) for v in (tmp_path / "cameras.txt").read_text().splitlines()[-1].split()[4:8]]
    np.testing.assert_allclose(params, [1500, 1500, WIDTH / 2, HEIGHT / 2], atol=1e-9)
    assert run_cli("export", "undistort-map", str(folder), "--out", str(tmp_path / "maps.npz")) == 0
    with np.load(tmp_path / "maps.npz") as maps:
        u, v = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
        np.testing.assert_allclose(maps["map_x"], u, atol=1e-4)
        np.testing.assert_allclose(maps["map_y"], v, atol=1e-4)


@pytest.fixture(scope="module")
def wavelet_calibration():
    """A db4 WAP calibration with smooth random coefficients (a few pixels of local distortion)."""
    frame = ImageFrame(WIDTH * PIXEL_MM, HEIGHT * PIXEL_MM, PIXEL_MM)
    ap = create_ap("wavelet:db4", frame, grid=(9, 6))
    values = np.random.default_rng(3).normal(0.0, 1.5, ap.n_params)
    return camera_entry(ap=ap, values=values)


@pytest.mark.slow
def test_undistortion_maps_invert_a_wavelet_calibration(wavelet_calibration):
    """At every node and between nodes, the ideal position of the map's source pixel is the target pixel
    within 0.01 px (the model's Delta reproduced by the map)."""
    cal = Calibration.from_camera_json("cam1", wavelet_calibration)
    map_x, map_y, K = undistortion_maps(cal)
    rng = np.random.default_rng(4)
    nodes = np.column_stack([np.arange(0, WIDTH, 4)[rng.integers(0, WIDTH // 4, 2000)],
                             np.arange(0, HEIGHT, 4)[rng.integers(0, HEIGHT // 4, 2000)]])
    between = np.column_stack([rng.integers(0, WIDTH, 5000), rng.integers(0, HEIGHT, 5000)])
    for pixels, bound in ((nodes, 1e-4), (between, 0.01)):          # float32 maps: 1e-4 px at the nodes
        u, v = pixels.T
        source = np.column_stack([map_x[v, u], map_y[v, u]]).astype(float) + 0.5
        assert np.max(np.abs(cal.delta_px(source))) > 3                # the field is not small
        miss = np.hypot(*(cal.ideal_from_measured(source) - (pixels + 0.5)).T)
        assert miss.max() < bound, (bound, miss.max())
    # the ideal camera: the calibration's principal distance and principal point, OpenCV convention
    np.testing.assert_allclose(K[0, 0], FOCAL_MM / PIXEL_MM)
    np.testing.assert_allclose(K[:2, 2], [WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5])
    # a WAP field is local: the polynomial OpenCV models cannot follow it, and say so
    assert fit_opencv(cal).misfit_max_px > 0.1


@pytest.mark.slow
def test_undistort_moves_image_features_to_their_ideal_positions(tmp_path, wavelet_calibration):
    """Render Gaussian dots where the camera measures known ideal positions; after `selfcal undistort` the
    dots' centroids are at their ideal positions (OpenCV convention): no bias above 0.01 px, none off by more
    than 0.07 px (cv2.remap quantises source positions to 1/32 px and its cubic kernel adds a little)."""
    folder = results_folder(tmp_path / "r", wavelet_calibration)
    cal = Calibration.from_camera_json("cam1", wavelet_calibration)
    u, v = np.meshgrid(np.linspace(60, WIDTH - 60, 12), np.linspace(60, HEIGHT - 60, 8))
    ideal = np.column_stack([u.ravel(), v.ravel()]) + 0.5 + 0.37           # off the pixel grid
    measured = cal.measured_from_ideal(ideal) - 0.5                         # OpenCV convention
    cols, rows = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    image = np.zeros((HEIGHT, WIDTH))
    for mx, my in measured:
        image += np.exp(-((cols - mx) ** 2 + (rows - my) ** 2) / (2 * 2.0 ** 2))
    cv2.imwrite(str(tmp_path / "dots.tif"), (image * 60000).astype(np.uint16))
    assert run_cli("undistort", str(folder), str(tmp_path / "dots.tif"), "--out", str(tmp_path / "u")) == 0
    out = cv2.imread(str(tmp_path / "u" / "dots.tif"), cv2.IMREAD_UNCHANGED).astype(float)
    assert (tmp_path / "u" / "ideal_camera.yaml").exists()
    error = []
    for tx, ty in ideal - 0.5:
        r0, c0 = int(round(ty)), int(round(tx))
        win = out[r0 - 8:r0 + 9, c0 - 8:c0 + 9]
        gy, gx = np.mgrid[r0 - 8:r0 + 9, c0 - 8:c0 + 9]
        error.append(np.array([np.sum(gx * win), np.sum(gy * win)]) / np.sum(win) - [tx, ty])
    error = np.array(error)
    assert np.all(np.abs(error.mean(axis=0)) < 0.01) and np.abs(error).max() < 0.07, error
    # the dots moved: measured and ideal positions differ by more than a pixel for some
    assert np.max(np.hypot(*(measured - (ideal - 0.5)).T)) > 1
    # an image of another size is refused with exit code 2 and nothing is written
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((10, 10), np.uint8))
    assert run_cli("undistort", str(folder), str(tmp_path / "small.png"), "--out", str(tmp_path / "u2")) == 2
    assert not (tmp_path / "u2").exists()


def test_export_errors_exit_with_two(tmp_path, capsys):
    """No results folder, no camera.json, two cameras without --camera, an unknown model: exit 2, no file."""
    out = tmp_path / "cam.yaml"
    assert run_cli("export", "opencv", str(tmp_path / "nothing"), "--out", str(out)) == 2
    (tmp_path / "empty").mkdir()
    assert run_cli("export", "opencv", str(tmp_path / "empty"), "--out", str(out)) == 2
    assert "camera.json" in capsys.readouterr().err
    two = tmp_path / "two"
    two.mkdir()
    (two / "camera.json").write_text(json.dumps({"cameras": {"a": camera_entry(), "b": camera_entry()}}))
    assert run_cli("export", "opencv", str(two), "--out", str(out)) == 2
    assert "--camera" in capsys.readouterr().err
    assert run_cli("export", "opencv", str(two), "--camera", "b", "--opencv-model", "fisheye",
                   "--out", str(out)) == 2
    assert not out.exists()
    assert run_cli("export", "colmap", str(two), "--out", str(tmp_path / "cameras.txt")) == 0
    assert len([line for line in (tmp_path / "cameras.txt").read_text().splitlines()
                if not line.startswith("#")]) == 2
