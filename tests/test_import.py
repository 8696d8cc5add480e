"""Importers: COLMAP (text and binary), ODM gcp_list.txt, conversion and georeference."""
import os

import numpy as np
import pytest

from selfcal.block import prune
from selfcal.convert import block_from_colmap
from selfcal.errors import BlockError
from selfcal.geometry.rotation import matrix_from_opk
from selfcal.io.colmap import read_colmap
from selfcal.io.odm import read_gcp_list

from conftest import SHARED_DATA, run_cli

COPR = os.path.join(SHARED_DATA, "copr")


def _require(path):
    assert os.path.exists(path), f"shared test data missing: {path} (see ../shared/data/README.md)"
    return path


@pytest.fixture(scope="module")
def models():
    return read_colmap(_require(os.path.join(COPR, "sparse"))), read_colmap(_require(os.path.join(COPR, "sparse_txt")))


def test_text_and_binary_models_are_identical(models):
    a, b = models
    assert a.cameras == b.cameras
    for field in ("image_ids", "image_names", "image_camera", "obs_image", "obs_point", "point_ids"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    for field in ("qvec", "tvec", "obs_xy", "point_xyz"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), rtol=0, atol=1e-9)
    # the numbers COLMAP reported for this model (SOURCE.txt)
    assert len(a.image_ids) == 38 and len(a.point_ids) == 65371 and len(a.obs_image) == 313672


def test_imported_blocks_are_identical(models):
    control = read_gcp_list(os.path.join(COPR, "gcp_list.txt"))
    blocks = [block_from_colmap(m, control, pixel_size_mm=0.0052)[0] for m in models]
    a, b = blocks
    np.testing.assert_array_equal(a.images.image_id, b.images.image_id)
    np.testing.assert_allclose(a.images.position_m, b.images.position_m, atol=1e-9)
    np.testing.assert_allclose(a.images.attitude_rad, b.images.attitude_rad, atol=1e-12)
    np.testing.assert_allclose(a.points.xyz_m, b.points.xyz_m, atol=1e-9)
    np.testing.assert_array_equal(a.observations.point_index, b.observations.point_index)


def test_conversion_reproduces_colmap_projection(models):
    """selfcal's collinearity with the converted orientation projects COLMAP's points where COLMAP does."""
    model = models[0]
    block, _ = block_from_colmap(model, None, pixel_size_mm=0.0052)
    cam = model.cameras[1]
    k = 7
    X = model.point_xyz[model.obs_point[model.obs_image == model.image_ids[k]]]
    M = matrix_from_opk(block.images.attitude_rad[k])
    u = (X - block.images.position_m[k]) @ M.T
    c = block.cameras["cam1"].focal_mm / 0.0052
    col = cam.params["cx"] - c * u[:, 0] / u[:, 2]
    row = cam.params["cy"] + c * u[:, 1] / u[:, 2]
    # COLMAP pinhole part (no distortion): x = fx X/Z + cx with the same camera
    from selfcal.geometry.rotation import matrix_from_quaternion
    R = matrix_from_quaternion(model.qvec[k])
    P = X @ R.T + model.tvec[k]
    f = 0.5 * (cam.params["fx"] + cam.params["fy"])
    np.testing.assert_allclose(col, f * P[:, 0] / P[:, 2] + cam.params["cx"], atol=1e-6)
    np.testing.assert_allclose(row, f * P[:, 1] / P[:, 2] + cam.params["cy"], atol=1e-6)


def test_georeference_rejects_the_inconsistent_target(models):
    control = read_gcp_list(os.path.join(COPR, "gcp_list.txt"))
    assert control.crs == "EPSG:32611" and len(control.point_names) == 10 and len(control.obs_image) == 27
    block, notes = block_from_colmap(models[0], control, pixel_size_mm=0.0052)
    assert any("gcp04" in n and "do not intersect" in n for n in notes)
    rms = float(next(n for n in notes if "residual rms" in n).split("rms ")[1].split(" m")[0])
    assert rms < 3.0                                  # hand-held GPS: metre level
    # the cameras fly about 16 m above the beach (heights 0), looking down
    assert 10 < np.median(block.images.position_m[:, 2]) < 25
    assert np.all(np.abs(block.images.attitude_rad[:, :2]) < np.radians(30))
    pruned = prune(block)
    assert np.sum(pruned.points.role == "gcp") >= 9
    # gcp04's measurement in IMG_0031 misses the surveyed point by about 7000 px (its sigma allows about
    # 3000): a misidentified target, dropped; its two consistent measurements stay
    assert any("'gcp04' in image 'IMG_0031.jpg'" in n and "misidentified" in n for n in notes)
    gcp04 = list(block.points.point_id).index("gcp04")
    assert np.sum(block.observations.point_index == gcp04) == 2
    assert sum("misidentified" in n for n in notes) == 1


def _renamed_gcp_list(tmp_path, rename):
    """COPR's gcp_list.txt with its image names changed by ``rename``."""
    with open(os.path.join(COPR, "gcp_list.txt")) as handle:
        lines = handle.read().splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        f = line.split("\t")
        if len(f) >= 6:
            f[5] = rename(f[5])
        out.append("\t".join(f))
    path = tmp_path / "gcp_list.txt"
    path.write_text("\n".join(out) + "\n")
    return path


def test_gcp_list_image_names_joined_after_a_folder_prefix_and_case(models, tmp_path):
    """gcp_list.txt naming the images 'images/IMG_0037.JPG' where the model says 'IMG_0037.jpg': the measurements
    are joined to the model's images after removing the folder and ignoring case (said in a note), and the block
    is the one of the original file, number for number."""
    control = read_gcp_list(_renamed_gcp_list(tmp_path, lambda name: "images/" + name.upper()))
    original = read_gcp_list(os.path.join(COPR, "gcp_list.txt"))
    block, notes = block_from_colmap(models[0], control, pixel_size_mm=0.0052, control_sigma_m=(3.0, 5.0))
    want, want_notes = block_from_colmap(models[0], original, pixel_size_mm=0.0052, control_sigma_m=(3.0, 5.0))
    n = len(set(original.obs_image))
    assert (f"warning: image names matched after removing the prefix 'images/' of gcp_list.txt's labels and "
            f"ignoring case (gcp_list.txt to the model): {n} of {n} (images/IMG_0037.JPG = IMG_0037.jpg, ") in notes[1]
    assert notes[:1] + notes[2:] == want_notes
    for field in ("point_id", "role", "xyz_m", "sigma_m"):
        np.testing.assert_array_equal(getattr(block.points, field), getattr(want.points, field))
    np.testing.assert_array_equal(block.images.position_m, want.images.position_m)
    np.testing.assert_array_equal(block.observations.pixel, want.observations.pixel)
    np.testing.assert_array_equal(block.observations.point_index, want.observations.point_index)


def test_gcp_list_image_names_that_match_no_image_of_the_model(models, tmp_path):
    """A gcp_list.txt of other images ('DSC0037.jpg'): exit 2 naming the file, with the nearest image names of
    the model (before: "only 0 ground control points are seen", naming no file)."""
    path = _renamed_gcp_list(tmp_path, lambda name: name.replace("IMG_", "DSC"))
    with pytest.raises(BlockError) as info:
        block_from_colmap(models[0], read_gcp_list(path), pixel_size_mm=0.0052)
    n = len(set(read_gcp_list(path).obs_image))
    assert info.value.path == str(path)
    assert info.value.reason.startswith(f"none of its {n} image names matches one of the 38 labels of the model")
    assert "'DSC0037.jpg' (nearest there: 'IMG_0037.jpg'" in info.value.reason
    assert run_cli("import", "colmap", os.path.join(COPR, "sparse"), "--gcp", str(path), "--out",
                   str(tmp_path / "b")) == 2
    assert not os.path.exists(tmp_path / "b")


def test_colmap_distortion_becomes_initial_brown_values(models):
    """selfcal's Delta is a function of the measured position, COLMAP's of the ideal one: the Brown values
    the import writes take a measured pixel to COLMAP's ideal position within 0.2 px over the image."""
    from selfcal.ap import ImageFrame, create_ap
    from selfcal.convert import colmap_undistort
    from selfcal.sensors.frame import photo_from_pixel

    block, notes = block_from_colmap(models[0], None, pixel_size_mm=0.0052)
    camera = block.cameras["cam1"]
    assert camera.initial_ap.spec == "brown" and camera.initial_ap.names[0] == "k1"
    assert any("initial value of the brown APs" in n for n in notes)
    cam = models[0].cameras[1]
    rng = np.random.default_rng(0)
    pixel = rng.uniform([0, 0], [cam.width, cam.height], (500, 2))
    xy = photo_from_pixel(pixel, cam.width, cam.height, 0.0052)
    brown = create_ap("brown", ImageFrame(camera.width_mm, camera.height_mm, 0.0052))
    dx, dy = brown.displacement_px(xy[:, 0], xy[:, 1], np.array(camera.initial_ap.values_px))
    ideal_mm = xy - 0.0052 * np.column_stack([dx, dy])
    n = colmap_undistort(cam, pixel)
    expected_mm = np.column_stack([camera.x0_mm + camera.focal_mm * n[:, 0], camera.y0_mm - camera.focal_mm * n[:, 1]])
    miss_px = np.hypot(*(ideal_mm - expected_mm).T) / 0.0052
    assert miss_px.max() < 0.2, miss_px.max()
    # the distortion is large: 80 px at the corners (k1 = -0.156)
    assert np.max(np.hypot(dx, dy)) > 40


def test_initial_ap_values_carry_over_to_other_families(tmp_path):
    """block.toml [cameras.ID.initial_ap]: written and read back; another AP family starts from its
    least-squares fit of the same field; unknown coefficient names are errors naming the key."""
    from dataclasses import replace

    from selfcal.adjust import AdjustOptions, APOptions
    from selfcal.adjust.problem import build_problem
    from selfcal.ap import ImageFrame, create_ap, frame_nodes_mm
    from selfcal.block import InitialAP
    from selfcal.io import read_block, write_block

    from conftest import simulation

    block = simulation(seed=1, distortion="none", points_per_mm2=0.2).blocks["type3"]
    cam = block.cameras["ilce7m3"]
    initial = InitialAP("brown", ("k1", "k2", "p1"), (-30.0, 4.0, 1.5))
    block = replace(block, cameras={cam.camera_id: replace(cam, initial_ap=initial)})
    write_block(block, tmp_path / "b")
    assert "[cameras.ilce7m3.initial_ap]" in (tmp_path / "b" / "block.toml").read_text()
    again = read_block(tmp_path / "b")
    assert again.cameras["ilce7m3"].initial_ap == initial
    frame = ImageFrame(cam.width_mm, cam.height_mm, cam.pixel_size_mm)
    x, y = frame_nodes_mm(frame)
    brown = create_ap("brown", frame)
    full = np.zeros(brown.n_params)
    full[[0, 1, 3]] = initial.values_px
    bx, by = brown.displacement_px(x, y, full)
    problem = build_problem(prune(again), AdjustOptions(ap=APOptions("brown")))
    np.testing.assert_array_equal(problem.cameras[0].prior_value[3:], full)
    # legendre leaves shift, scale, rotation and the projective fields to the orientation: compared
    # modulo those six fields
    problem = build_problem(prune(again), AdjustOptions(ap=APOptions("legendre")))
    lx, ly = problem.cameras[0].ap.displacement_px(x, y, problem.cameras[0].prior_value[3:])
    s = 1.0 / x.max()
    u, v = s * x, s * y
    low = np.vstack([np.column_stack([np.ones_like(x), 0 * x, u, v, u * u, u * v]),
                     np.column_stack([0 * x, np.ones_like(x), v, -u, u * v, v * v])])
    diff = np.concatenate([lx - bx, ly - by])
    rest = diff - low @ np.linalg.lstsq(low, diff, rcond=None)[0]
    assert np.sqrt(np.mean(rest ** 2)) < 0.01 * np.sqrt(np.mean(bx ** 2 + by ** 2)), np.sqrt(np.mean(rest ** 2))
    text = (tmp_path / "b" / "block.toml").read_text().replace("k2 = 4.0", "k9 = 4.0")
    (tmp_path / "b" / "block.toml").write_text(text)
    with pytest.raises(BlockError) as info:
        build_problem(prune(read_block(tmp_path / "b")), AdjustOptions(ap=APOptions("brown")))
    assert info.value.column == "cameras.ilce7m3.initial_ap.k9" and "k1, k2" in info.value.reason


def test_malformed_inputs_name_the_line(tmp_path):
    bad = tmp_path / "gcp_list.txt"
    bad.write_text("EPSG:32611\n235269.88 3811198.11 0.0 3609.4 2293.8 IMG_0037.jpg gcp02\n"
                   "235269.88 abc 0.0 3609.4 2293.8 IMG_0043.jpg gcp02\n")
    with pytest.raises(BlockError) as info:
        read_gcp_list(bad)
    assert info.value.line == 3 and info.value.column == "geo_y"
    bad.write_text("not a crs at all\n1 2 3 4 5 a.jpg\n")
    with pytest.raises(BlockError) as info:
        read_gcp_list(bad)
    assert info.value.line == 1
    folder = tmp_path / "sparse"
    folder.mkdir()
    (folder / "cameras.txt").write_text("1 OPENCV 100 80 50 50 40 40\n")
    (folder / "images.txt").write_text("")
    (folder / "points3D.txt").write_text("")
    with pytest.raises(BlockError) as info:
        read_colmap(folder)
    assert info.value.line == 1 and "OPENCV has 8 parameters" in info.value.reason
    assert run_cli("import", "colmap", str(folder), "--out", str(tmp_path / "b")) == 2


def test_bal_import_reproduces_the_initial_cost(tmp_path, capsys):
    """BAL import through a block folder: the cost at the file's values is the reference cost exactly."""
    import json

    from selfcal.adjust.initial import initial_state
    from selfcal.adjust.schur import evaluate_cost
    from selfcal.adjust.problem import build_problem
    from selfcal.io import read_block

    bal_dir = os.path.join(SHARED_DATA, "bal")
    with open(_require(os.path.join(bal_dir, "reference_costs_scipy.json"))) as handle:
        reference = json.load(handle)
    out = tmp_path / "ladybug"
    assert run_cli("import", "bal", os.path.join(bal_dir, "problem-49-7776-pre.txt"), "--out", str(out)) == 0
    # 31 observations of 10 points start behind their camera (cheirality), and the import says so
    assert "31 observations of 10 points lie behind their camera" in capsys.readouterr().err
    block = read_block(out)
    assert len(block.images) == 49 and len(block.points) == 7776 and len(block.observations) == 31843
    problem = build_problem(block)
    state, _ = initial_state(problem, block)
    cost = evaluate_cost(problem, state)
    # exact up to the 10 significant digits the block folder stores
    assert cost == pytest.approx(reference["problem-49-7776-pre.txt"]["initial_cost_half_sum_sq"], rel=1e-7)


@pytest.mark.parametrize("model, params", [
    ("SIMPLE_PINHOLE", {"f": 3000.0, "cx": 1000.0, "cy": 750.0}),
    ("SIMPLE_RADIAL", {"f": 3000.0, "cx": 1000.0, "cy": 750.0, "k": -0.08}),
    ("RADIAL", {"f": 3000.0, "cx": 1000.0, "cy": 750.0, "k1": -0.08, "k2": 0.02}),
    ("OPENCV", {"fx": 3000.0, "fy": 3001.0, "cx": 1010.0, "cy": 745.0, "k1": -0.08, "k2": 0.02,
                "p1": 2e-4, "p2": -1e-4}),
    ("FULL_OPENCV", {"fx": 3000.0, "fy": 3000.0, "cx": 1000.0, "cy": 750.0, "k1": -0.08, "k2": 0.02,
                     "p1": 0.0, "p2": 0.0, "k3": 0.001, "k4": 0.01, "k5": 0.0, "k6": 0.0}),
])
def test_every_perspective_model_becomes_brown_initial_values(model, params):
    """Each COLMAP perspective model: principal distance and point from f/fx/fy/cx/cy, and its distortion
    as brown values that take measured pixels to COLMAP's ideal positions within 0.05 px (0 for pinholes;
    0.15 px for the OPENCV case, whose principal point is 11 px off centre: selfcal's Brown terms are
    centred on the frame, COLMAP's on the principal point)."""
    from selfcal.ap import ImageFrame, create_ap
    from selfcal.block import FrameCamera
    from selfcal.convert import colmap_distortion_as_brown, colmap_undistort
    from selfcal.io.colmap import ColmapCamera
    from selfcal.sensors.frame import photo_from_pixel

    cam = ColmapCamera(1, model, 2000, 1500, params)
    p = 0.004
    f = params.get("f", 0.5 * (params.get("fx", 0) + params.get("fy", 0)))
    camera = FrameCamera("c", 2000, 1500, p, f * p, (params["cx"] - 1000) * p, (750 - params["cy"]) * p)
    initial, misfit = colmap_distortion_as_brown(cam, camera)
    if model == "SIMPLE_PINHOLE":
        assert initial is None and misfit == 0.0
        return
    bound = 0.15 if model == "OPENCV" else 0.05
    assert misfit < bound, misfit
    pixel = np.random.default_rng(1).uniform([0, 0], [2000, 1500], (300, 2))
    xy = photo_from_pixel(pixel, 2000, 1500, p)
    brown = create_ap("brown", ImageFrame(2000 * p, 1500 * p, p))
    dx, dy = brown.displacement_px(xy[:, 0], xy[:, 1], np.array(initial.values_px))
    n = colmap_undistort(cam, pixel)
    ideal = np.column_stack([camera.x0_mm + camera.focal_mm * n[:, 0], camera.y0_mm - camera.focal_mm * n[:, 1]])
    miss = np.hypot(*((xy - p * np.column_stack([dx, dy])) - ideal).T) / p
    assert miss.max() < bound and np.max(np.hypot(dx, dy)) > 10


def test_the_defaults_the_files_cannot_give_are_printed_with_their_value(models, tmp_path, capsys):
    """COLMAP works in pixels and gcp_list.txt has no accuracy column: the pixel size (0.005 mm) and the control
    sigma (3 m / 5 m) an import assumes are warnings naming the value and the option; given, nothing is said.
    The CLI says the same on stderr, and a lone --gcp-sigma-xy says which height sigma it assumed."""
    control = read_gcp_list(os.path.join(COPR, "gcp_list.txt"))
    _, notes = block_from_colmap(models[0], control)
    pixel = [n for n in notes if "pixel size" in n]
    sigma = [n for n in notes if "control sigma" in n]
    assert len(pixel) == 1 and "0.005 mm assumed" in pixel[0] and "--pixel-size-mm" in pixel[0]
    assert len(sigma) == 1 and "3 m in plan, 5 m in height" in sigma[0] and "--gcp-sigma-xy" in sigma[0]
    given, notes = block_from_colmap(models[0], control, pixel_size_mm=0.005, control_sigma_m=(3.0, 5.0))
    assert not [n for n in notes if "pixel size" in n or "control sigma" in n]
    default, _ = block_from_colmap(models[0], control)
    np.testing.assert_array_equal(default.images.position_m, given.images.position_m)
    _, notes = block_from_colmap(models[0], None)
    assert not [n for n in notes if "control sigma" in n]          # no control, no sigma to assume

    capsys.readouterr()
    assert run_cli("import", "colmap", os.path.join(COPR, "sparse"), "--gcp", os.path.join(COPR, "gcp_list.txt"),
                   "--gcp-sigma-xy", "0.5", "--out", str(tmp_path / "blk")) == 0
    err = capsys.readouterr().err
    assert "--gcp-sigma-z not given: 5 m assumed" in err and "0.005 mm assumed" in err
    assert "no control sigma given" not in err
