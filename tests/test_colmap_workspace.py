"""`selfcal export colmap-workspace`, read back by COLMAP's own readers (pycolmap, `colmap model_analyzer`).

A small simulated block (10 images; the seed-000 camera scaled to 600 x 400 px of 59 µm, so that the
geometry in millimetres is the seed's) is adjusted with `brown` and with `wavelet:db4`, and exported with
three synthetic images. pycolmap reprojects every 3-D point into every image of its track with its own
camera and pose; that must be selfcal's projection of the adjusted point (computed here from the results
folder's files with selfcal's collinearity, Eq. (1) without Delta). Gaussian dots drawn where the camera
measured some tie points must sit, in the undistorted image, where the workspace puts their 2-D points.

Pixel convention: COLMAP and selfcal put the upper-left corner of the first pixel at (0, 0); OpenCV (the
image arrays here) puts the centre of the first pixel at (0, 0), hence the +-0.5 below.
"""
import csv
import json
import os
import re
import shutil
import subprocess
from dataclasses import replace

import cv2
import numpy as np
import pytest

from selfcal.geometry.rotation import matrix_from_opk
from selfcal.io.block_folder import write_block
from selfcal.io.results import read_results
from selfcal.sensors.frame import pixel_from_photo, project
from selfcal.simulate import simulate_uav

from conftest import run_cli

SCALE = 10                     # pixels 10 x larger, 10 x fewer: the seed's frame in mm, 600 x 400 px
EXPORTED = ("S1_01", "S1_02", "S1_03")
DOT_SIGMA_PX = 1.5


def _small_block():
    sim = simulate_uav(seed=2, distortion="brown", distortion_scale=15.0, points_per_mm2=0.6, n_strips=2,
                       images_per_strip=5)
    block = sim.blocks["type1"]
    cams = {k: replace(c, width_px=c.width_px // SCALE, height_px=c.height_px // SCALE,
                       pixel_size_mm=c.pixel_size_mm * SCALE) for k, c in block.cameras.items()}
    obs = block.observations
    return replace(block, cameras=cams, image_sigma_px=block.image_sigma_px / SCALE,
                   observations=replace(obs, pixel=obs.pixel / SCALE, sigma_px=obs.sigma_px / SCALE))


def _dots(measured_px, width, height):
    """An 8-bit grey image with Gaussian dots at measured positions (selfcal's convention)."""
    image = np.zeros((height, width))
    for col, row in measured_px - 0.5:                     # OpenCV's convention
        c0, r0 = int(round(col)), int(round(row))
        rows, cols = np.mgrid[r0 - 8:r0 + 9, c0 - 8:c0 + 9]
        image[r0 - 8:r0 + 9, c0 - 8:c0 + 9] += np.exp(-((cols - col) ** 2 + (rows - row) ** 2)
                                                      / (2 * DOT_SIGMA_PX ** 2))
    return np.clip(image * 250, 0, 255).round().astype(np.uint8)


def _spread(points_px, spacing_px, margin_px, width, height):
    """Indices of positions at least ``spacing_px`` apart and ``margin_px`` inside the frame."""
    chosen = []
    for k, p in enumerate(points_px):
        if not (margin_px < p[0] < width - margin_px and margin_px < p[1] < height - margin_px):
            continue
        if all(np.hypot(*(p - points_px[j])) > spacing_px for j in chosen):
            chosen.append(k)
    return np.array(chosen)


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    """The block folder, its `brown` and `wavelet:db4` results and an images folder (three images with dots
    at the measured positions of well-spread tie points, a stray file)."""
    base = tmp_path_factory.mktemp("workspace")
    block = _small_block()
    write_block(block, str(base / "block"))
    for ap in ("brown", "wavelet:db4"):
        assert run_cli("adjust", str(base / "block"), "--ap", ap, "--no-report",
                       "--out", str(base / ap.replace(":", "-"))) == 0
    cam = next(iter(block.cameras.values()))
    res = read_results(base / "brown").tables["residuals"]
    images = base / "images"
    images.mkdir()
    dots = {}
    for image_id in EXPORTED:
        rows = np.flatnonzero((res["image_id"] == image_id) & (res["rejected"] == 0)
                              & np.char.startswith(res["point_id"].astype(str), "T"))
        measured = np.column_stack([res["col_px"][rows], res["row_px"][rows]])
        pick = _spread(measured, 24.0, 20.0, cam.width_px, cam.height_px)
        dots[image_id] = dict(zip(res["point_id"][rows][pick], measured[pick]))
        cv2.imwrite(str(images / f"{image_id}.png"), _dots(measured[pick], cam.width_px, cam.height_px))
    (images / "flight_log.txt").write_text("not an image\n")
    return base, dots


def _workspace(base, model):
    ws = base / f"ws-{model}"
    if not ws.exists():
        assert run_cli("export", "colmap-workspace", str(base / model), "--images", str(base / "images"),
                       "--out", str(ws)) == 0
    return ws


def _selfcal_projection(results, point_id, image_id):
    """selfcal's ideal pixel position (Eq. (1) without Delta) of the adjusted point in the adjusted image."""
    r = read_results(results)
    cam = next(iter(r.camera["cameras"].values()))
    im, pt = r.tables["images"], r.tables["points"]
    i = {k: n for n, k in enumerate(im["image_id"])}
    p = {k: n for n, k in enumerate(pt["point_id"])}
    ii = np.array([i[k] for k in image_id])
    pp = np.array([p[k] for k in point_id])
    eop = np.column_stack([im["X0"][ii], im["Y0"][ii], im["Z0"][ii],
                           np.radians(np.column_stack([im["omega_deg"][ii], im["phi_deg"][ii], im["kappa_deg"][ii]]))])
    xyz = np.column_stack([pt["X"][pp], pt["Y"][pp], pt["Z"][pp]])
    photo = project(xyz, eop, np.array([cam["focal_mm"]["value"], cam["x0_mm"]["value"], cam["y0_mm"]["value"]]))
    return pixel_from_photo(photo, cam["width_px"], cam["height_px"], cam["pixel_size_mm"])


def _point_ids(ws):
    with open(ws / "sparse" / "selfcal_points.csv", newline="") as handle:
        return {int(row["point3D_id"]): row["point_id"] for row in csv.DictReader(handle)}


@pytest.mark.parametrize("model", ["brown", "wavelet-db4"])
def test_pycolmap_reprojects_like_selfcal(adjusted, model):
    """Every track element: pycolmap's projection (its PINHOLE camera, its pose, the 3-D point plus nothing)
    equals selfcal's projection of the adjusted point within 0.05 px (measured: below 1e-6 px), and the
    2-D point plus selfcal's residual v is that projection too (v = adjusted - observed, y up)."""
    import pycolmap
    base, _ = adjusted
    ws = _workspace(base, model)
    rec = pycolmap.Reconstruction(str(ws / "sparse"))
    names = {im.image_id: os.path.splitext(im.name)[0] for im in rec.images.values()}
    assert sorted(names.values()) == sorted(EXPORTED)
    assert sorted(os.listdir(ws / "images")) == sorted(f"{i}.png" for i in EXPORTED)
    ids = _point_ids(ws)
    assert len(rec.points3D) == len(ids) > 300
    meta = json.loads((ws / "sparse" / "selfcal_origin.json").read_text())
    origin = np.array(meta["origin_m"])
    assert meta["crs"] == "local" and meta["cameras"] == {"1": "ilce7m3"}
    res = read_results(base / model).tables["residuals"]
    v_of = {(i, p): (vx, -vy) for i, p, vx, vy in zip(res["image_id"], res["point_id"], res["vx_px"],
                                                          res["vy_px"])}
    colmap_px, point2d, v, which = [], [], [], []
    for point3d_id, point in rec.points3D.items():
        for el in point.track.elements:
            image = rec.images[el.image_id]
            cam_xyz = image.cam_from_world() * point.xyz
            colmap_px.append(rec.cameras[image.camera_id].img_from_cam(cam_xyz))
            point2d.append(image.points2D[el.point2D_idx].xy)
            assert image.points2D[el.point2D_idx].point3D_id == point3d_id
            which.append((names[el.image_id], ids[point3d_id]))
            v.append(v_of[which[-1]])
    colmap_px, point2d, v = np.array(colmap_px), np.array(point2d), np.array(v)
    selfcal_px = _selfcal_projection(base / model, [w[1] for w in which], [w[0] for w in which])
    miss = np.hypot(*(colmap_px - selfcal_px).T)
    print(f"{model}: {len(miss)} observations, pycolmap - selfcal projection RMS {np.sqrt(np.mean(miss ** 2)):.2e} px,"
          f" max {miss.max():.2e} px")
    assert miss.max() < 0.05                               # the acceptance bound; measured ~1e-9 px
    assert miss.max() < 1e-4
    # the 2-D points are the observations undistorted at their adjusted coordinates: 2-D point + v = projection
    # (files round v to 1e-4 px; the adjustment evaluated the APs where its last move put them, which the final
    # iterations moved by a fraction of v: measured 3.2e-3 px at most; with the correction at the measured
    # coordinates 9.0e-3 px)
    assert np.max(np.abs(point2d + v - selfcal_px)) < 5e-3
    # the points sit at the adjusted coordinates minus the origin written beside them
    pt = read_results(base / model).tables["points"]
    where = {p: k for k, p in enumerate(pt["point_id"])}
    for point3d_id, point in list(rec.points3D.items())[:50]:
        k = where[ids[point3d_id]]
        np.testing.assert_allclose(point.xyz + origin, [pt["X"][k], pt["Y"][k], pt["Z"][k]], atol=1e-6)
    # the pose: perspective centre and viewing direction (COLMAP +z = selfcal -z)
    im = read_results(base / model).tables["images"]
    k = list(im["image_id"]).index("S1_02")
    image = next(i for i in rec.images.values() if i.name == "S1_02.png")
    np.testing.assert_allclose(image.projection_center() + origin, [im["X0"][k], im["Y0"][k], im["Z0"][k]],
                               atol=1e-6)
    M = matrix_from_opk(np.radians([im["omega_deg"][k], im["phi_deg"][k], im["kappa_deg"][k]]))
    np.testing.assert_allclose(image.viewing_direction(), -M[2], atol=1e-9)


def test_undistorted_dots_sit_on_their_2d_points(adjusted):
    """The dots drawn at measured (distorted) positions are, in the workspace's undistorted images, at the
    ideal 2-D points of the model: centroid within 0.07 px, no bias above 0.01 px (cv2.remap quantises
    to 1/32 px), while the dots moved by more than 2 px for some (a WAP model, db4)."""
    import pycolmap
    base, dots = adjusted
    ws = _workspace(base, "wavelet-db4")
    rec = pycolmap.Reconstruction(str(ws / "sparse"))
    ids = _point_ids(ws)
    error, moved = [], []
    for image in rec.images.values():
        wanted = dots[os.path.splitext(image.name)[0]]
        out = cv2.imread(str(ws / "images" / image.name), cv2.IMREAD_UNCHANGED).astype(float)
        assert out.ndim == 2
        for p2 in image.points2D:
            pid = ids.get(p2.point3D_id)
            if pid not in wanted:
                continue
            tx, ty = p2.xy - 0.5                           # OpenCV's convention
            r0, c0 = int(round(ty)), int(round(tx))
            win = out[r0 - 6:r0 + 7, c0 - 6:c0 + 7]
            gy, gx = np.mgrid[r0 - 6:r0 + 7, c0 - 6:c0 + 7]
            error.append(np.array([np.sum(gx * win), np.sum(gy * win)]) / np.sum(win) - [tx, ty])
            moved.append(np.hypot(*(p2.xy - wanted[pid])))
    error, moved = np.array(error), np.array(moved)
    print(f"{len(error)} dots: centroid - 2-D point mean {error.mean(axis=0)} px, max {np.abs(error).max():.3f} px; "
          f"moved by up to {moved.max():.1f} px")
    assert len(error) > 30
    assert np.all(np.abs(error.mean(axis=0)) < 0.01) and np.abs(error).max() < 0.07, error
    assert moved.max() > 2.0


def test_colmap_model_analyzer_reads_the_workspace(adjusted):
    """COLMAP's own reader (Debian's colmap 3.8) counts the images, points and observations that the results
    folder says the workspace must hold: the exported images' observations that the adjustment kept, of tie
    and control points seen in at least two of them."""
    exe = shutil.which("colmap")
    assert exe, "Debian's colmap is needed for this test; `make test` installs it (make colmap)"
    base, _ = adjusted
    ws = _workspace(base, "brown")
    out = subprocess.run([exe, "model_analyzer", "--path", str(ws / "sparse")], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    text = out.stdout + out.stderr
    numbers = {k: float(v) for k, v in re.findall(r"^(Images|Points|Observations|Mean reprojection error):"
                                                  r"\s*([0-9.]+)", text, re.M)}
    r = read_results(base / "brown")
    res, pt = r.tables["residuals"], r.tables["points"]
    role = dict(zip(pt["point_id"], pt["role"]))
    keep = (res["rejected"] == 0) & np.isin(res["image_id"], EXPORTED) \
        & np.array([role.get(p) in ("tie", "gcp") for p in res["point_id"]])
    points, count = np.unique(res["point_id"][keep], return_counts=True)
    assert numbers["Images"] == len(EXPORTED)
    assert numbers["Points"] == np.sum(count >= 2)
    assert numbers["Observations"] == np.sum(count[count >= 2])
    # the mean distance of the 2-D points to the projections is the size of the residuals (noise 0.05 px)
    assert 0.02 < numbers["Mean reprojection error"] < 0.1


def test_workspace_bad_input_exits_with_two(adjusted, tmp_path, capsys):
    """A missing images folder, an images folder without the block's images, --out inside RESULTS, results
    without a frame camera: exit 2 with the reason, nothing written."""
    base, _ = adjusted
    results = str(base / "brown")
    out = tmp_path / "ws"
    assert run_cli("export", "colmap-workspace", results, "--images", str(tmp_path / "nowhere"),
                   "--out", str(out)) == 2
    assert "nowhere" in capsys.readouterr().err
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.png").write_bytes(b"")
    assert run_cli("export", "colmap-workspace", results, "--images", str(tmp_path / "other"),
                   "--out", str(out)) == 2
    assert "none of the block's 10 images" in capsys.readouterr().err
    assert run_cli("export", "colmap-workspace", results, "--images", str(base / "images"),
                   "--out", os.path.join(results, "ws")) == 2
    assert "inside the input" in capsys.readouterr().err
    # a results folder whose only camera is not a frame camera
    pushbroom = tmp_path / "pushbroom"
    shutil.copytree(results, pushbroom)
    camera = json.loads((pushbroom / "camera.json").read_text())
    for entry in camera["cameras"].values():
        entry["model"] = "pushbroom"
    (pushbroom / "camera.json").write_text(json.dumps(camera))
    assert run_cli("export", "colmap-workspace", str(pushbroom), "--images", str(base / "images"),
                   "--out", str(out)) == 2
    assert "no frame camera" in capsys.readouterr().err
    assert not out.exists() and not os.path.exists(os.path.join(results, "ws"))


# ---- point colours (issue 45 item 8) ----------------------------------------------------------------------------

DISC_RADIUS_PX = 4
BACKGROUND = (90, 90, 90)


def _colour_of(point_id, image_index):
    """The colour (R, G, B) drawn for a tie point in the exported image ``image_index``: the point's own colour
    (from its id) plus an offset of the image, so that a point's expected colour is the mean over its images."""
    rng = np.random.default_rng(int(point_id.lstrip("T")) if point_id.lstrip("T").isdigit() else len(point_id))
    base = rng.integers(60, 190, 3)
    return base + np.array([12, -12, 6]) * (image_index - 1)


@pytest.fixture(scope="module")
def coloured(adjusted, tmp_path_factory):
    """Colour images of the three exported images (BGR PNG, grey background) with a filled disc of radius 4 px
    at the measured position of each of a set of tie points spread 16 px apart in every exported image that
    sees them; the disc's colour is the point's colour plus the image's offset (:func:`_colour_of`). Returns
    the `brown` workspace exported from them, its stderr lines and counts, the expected colour of each drawn
    point, and the points that lie 3 px or more outside every disc and 8 px inside the frame in all their images
    (the background's; nearer the edge, the undistorted image's black border bleeds in)."""
    base, _ = adjusted
    res = read_results(base / "brown").tables["residuals"]
    cam = read_results(base / "brown").camera["cameras"]["ilce7m3"]
    width, height = cam["width_px"], cam["height_px"]
    keep = (res["rejected"] == 0) & np.isin(res["image_id"], EXPORTED) \
        & np.char.startswith(res["point_id"].astype(str), "T")
    at = {}                                          # point id -> {image id: measured px}
    for i, p, c, r in zip(res["image_id"][keep], res["point_id"][keep], res["col_px"][keep], res["row_px"][keep]):
        at.setdefault(p, {})[i] = np.array([c, r])
    chosen: dict[str, dict] = {}
    for p, where in at.items():
        if len(where) < 2:
            continue
        if not all(15 < xy[0] < width - 15 and 15 < xy[1] < height - 15 for xy in where.values()):
            continue
        if all(np.hypot(*(xy - q[i])) > 16 for i, xy in where.items() for q in chosen.values() if i in q):
            chosen[p] = where
    folder = tmp_path_factory.mktemp("colour-images")
    for k, image_id in enumerate(EXPORTED):
        image = np.empty((height, width, 3), np.uint8)
        image[:] = BACKGROUND
        for p, where in chosen.items():
            if image_id in where:
                col, row = where[image_id] - 0.5                      # OpenCV's convention
                r, g, b = _colour_of(p, k)
                cv2.circle(image, (int(round(col)), int(round(row))), DISC_RADIUS_PX, (int(b), int(g), int(r)), -1)
        cv2.imwrite(str(folder / f"{image_id}.png"), image)
    expected = {p: np.mean([_colour_of(p, EXPORTED.index(i)) for i in where], axis=0) for p, where in chosen.items()}
    background = {p for p, where in at.items() if p not in chosen
                  and all(8 < xy[0] < width - 8 and 8 < xy[1] < height - 8 for xy in where.values())
                  and all(np.hypot(*(xy - q[i])) > DISC_RADIUS_PX + 3 for i, xy in where.items()
                          for q in chosen.values() if i in q)}
    ws = base / "ws-colour"
    from selfcal.workflows.export_workspace import export_workspace
    from selfcal.cli.calibrations import calibrations, maps_of
    notes = []
    done = export_workspace(str(base / "brown"), calibrations(str(base / "brown")), str(folder), str(ws),
                            say=notes.append, maps=maps_of)
    return ws, notes, done, expected, background


def test_point_colours_are_the_images_colours_at_their_2d_points(coloured):
    """Each drawn point's colour in points3D (read by pycolmap) is the mean over its images of the disc colours
    drawn there, within 2 DN (bicubic undistortion of a flat disc, rounding); the colour differs between images
    (+-12 DN), so the mean over images is what is tested, not one image's colour. Exactly the points whose 2-D
    points all lie outside their undistorted images (near the frame's edge; 4 here) are grey 128, and the
    export's stderr line counts them."""
    import pycolmap
    ws, notes, done, expected, background = coloured
    rec = pycolmap.Reconstruction(str(ws / "sparse"))
    ids = _point_ids(ws)
    by_selfcal = {ids[k]: np.array(p.color, float) for k, p in rec.points3D.items()}
    drawn = [p for p in expected if p in by_selfcal]
    assert len(drawn) > 40
    error = np.array([by_selfcal[p] - expected[p] for p in drawn])
    print(f"{len(drawn)} coloured points: colour - truth max {np.abs(error).max():.1f} DN, "
          f"mean {error.mean(axis=0)} DN")
    assert np.abs(error).max() <= 2.0, error
    # the points not drawn, 3 px or more outside every disc and 8 px inside the frame in all their images: background
    far = [p for p in by_selfcal if p not in expected and p in background]
    assert len(far) > 50
    assert max(np.abs(by_selfcal[p] - BACKGROUND).max() for p in far) <= 1.0
    # the fallback: points none of whose 2-D points lies within the pixel centres of its (undistorted) image
    width, height = rec.cameras[1].width, rec.cameras[1].height
    outside = [k for k, p in rec.points3D.items()
               if not any(0.5 <= xy[0] <= width - 0.5 and 0.5 <= xy[1] <= height - 0.5
                          for xy in (rec.images[el.image_id].points2D[el.point2D_idx].xy for el in p.track.elements))]
    assert done["grey_points"] == len(outside) < 20
    assert all(tuple(rec.points3D[k].color) == (128, 128, 128) for k in outside)
    line = next(n for n in notes if n.startswith("colours:"))
    assert (f"{len(rec.points3D) - len(outside)} point(s) from the undistorted images" in line
            and f"{len(outside)} grey" in line)


def test_colour_sampling_is_bilinear_and_points_outside_stay_grey():
    """image_rgb_at on a linear ramp is the ramp at the position (bilinear is exact there), channel order BGR ->
    RGB, 16-bit scaled to 8-bit; PointColours averages over images and leaves a point grey (128) and counted
    when none of its 2-D points lies within the pixel centres of its image."""
    from selfcal.convert import FALLBACK_GREY, PointColours, image_rgb_at
    from selfcal.io.colmap import ColmapCamera, ColmapModel
    rows, cols = np.mgrid[0:10, 0:20]
    bgr = np.dstack([2 * cols, 5 * rows, 3 * cols + 4 * rows]).astype(np.uint8)
    xy = np.array([[3.7, 2.2], [10.5, 8.9], [0.5, 0.5], [19.5, 9.5], [0.2, 5.0], [5.0, 9.8]])
    rgb, inside = image_rgb_at(bgr, xy)
    c, r = xy[:, 0] - 0.5, xy[:, 1] - 0.5
    truth = np.column_stack([3 * c + 4 * r, 5 * r, 2 * c])
    assert inside.tolist() == [True, True, True, True, False, False]
    np.testing.assert_allclose(rgb[inside], truth[inside], atol=1e-9)
    grey16, _ = image_rgb_at((bgr[:, :, 0].astype(np.uint16) * 257), xy[:2])
    np.testing.assert_allclose(grey16, np.repeat(2 * c[:2, None], 3, axis=1), atol=1e-9)
    cam = ColmapCamera(1, "PINHOLE", 20, 10, {"fx": 10.0, "fy": 10.0, "cx": 10.0, "cy": 5.0})
    model = ColmapModel({1: cam}, np.array([1, 2]), np.array(["a.png", "b.png"], object), np.array([1, 1]),
                        np.tile([1.0, 0, 0, 0], (2, 1)), np.zeros((2, 3)),
                        obs_image=np.array([1, 2, 1, 2]), obs_xy=np.array([[4.5, 2.5], [6.5, 2.5], [-3, 5], [25, 5]]),
                        obs_point=np.array([7, 7, 9, 9]), point_ids=np.array([7, 9]), point_xyz=np.zeros((2, 3)),
                        point_error=np.zeros(2))
    colours = PointColours(model)
    colours.add(1, bgr)
    colours.add(2, bgr[:, ::-1].copy())          # the second image mirrored: col 4 -> 19 - 4
    out, grey = colours.rgb()
    first, second = np.array([3 * 4 + 4 * 2, 5 * 2, 2 * 4]), np.array([3 * 13 + 4 * 2, 5 * 2, 2 * 13])
    assert out[0].tolist() == np.round((first + second) / 2).astype(int).tolist()
    assert out[1].tolist() == [FALLBACK_GREY] * 3 and grey == 1


# ---- colmap point_triangulator (issue 45 item 8) ----------------------------------------------------------------

def test_colmap_point_triangulator_takes_the_workspace(adjusted, tmp_path):
    """Debian's COLMAP 3.8 `point_triangulator` runs on the workspace's database.db and
    sparse/triangulator_input (poses fixed, no 3-D points given) and triangulates the tracks again: it exits 0;
    with COLMAP's defaults it triangulates exactly the tracks of three or more images (it ignores two-view
    tracks: Mapper.tri_ignore_two_view_tracks), with that option off nearly every 3-D point of sparse/ (>= 95 %);
    each of its tracks is one of selfcal's, and its points lie at selfcal's adjusted points within 0.1 m RMS,
    0.5 m at most (the ground pixel is 0.6 m: 213 m / 355 px; COLMAP intersects the ideal 2-D points of three
    images, selfcal adjusted ten; measured 0.04 m RMS) and reproject onto the 2-D points within 0.1 px RMS.
    pycolmap 4's triangulate_points takes the same files (its database migrated) and finds the same tracks."""
    import pycolmap
    exe = shutil.which("colmap")
    assert exe, "Debian's colmap is needed for this test; `make test` installs it (make colmap)"
    base, _ = adjusted
    ws = _workspace(base, "brown")
    given = pycolmap.Reconstruction(str(ws / "sparse"))
    ids = _point_ids(ws)
    meta = json.loads((ws / "sparse" / "selfcal_origin.json").read_text())
    pt = read_results(base / "brown").tables["points"]
    where = {p: k for k, p in enumerate(pt["point_id"])}
    n_multi = sum(p.track.length() >= 3 for p in given.points3D.values())
    for two_view, wanted in (("1", n_multi), ("0", None)):
        out_dir = tmp_path / f"triangulated-{two_view}"
        out_dir.mkdir()
        run = subprocess.run([exe, "point_triangulator", "--database_path", str(ws / "database.db"),
                              "--image_path", str(ws / "images"),
                              "--input_path", str(ws / "sparse" / "triangulator_input"), "--output_path", str(out_dir),
                              "--Mapper.tri_ignore_two_view_tracks", two_view], capture_output=True, text=True,
                             timeout=120)
        assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
        found = pycolmap.Reconstruction(str(out_dir))
        miss, reprojection, matched = [], [], set()
        for point in found.points3D.values():
            owners = {given.images[el.image_id].points2D[el.point2D_idx].point3D_id for el in point.track.elements}
            assert len(owners) == 1                    # a track of COLMAP's is one track of selfcal's
            pid = ids[owners.pop()]
            matched.add(pid)
            k = where[pid]
            miss.append(np.hypot.reduce(point.xyz + meta["origin_m"] - [pt["X"][k], pt["Y"][k], pt["Z"][k]]))
            for el in point.track.elements:
                image = found.images[el.image_id]
                xy = found.cameras[image.camera_id].img_from_cam(image.cam_from_world() * point.xyz)
                reprojection.append(np.hypot(*(xy - given.images[el.image_id].points2D[el.point2D_idx].xy)))
        miss, reprojection = np.array(miss), np.array(reprojection)
        print(f"point_triangulator (tri_ignore_two_view_tracks {two_view}): {len(found.points3D)} of "
              f"{len(given.points3D)} points ({n_multi} seen in 3 images), distance to selfcal's RMS "
              f"{np.sqrt(np.mean(miss ** 2)):.3f} m, max {miss.max():.3f} m; reprojection RMS "
              f"{np.sqrt(np.mean(reprojection ** 2)):.3f} px")
        if wanted is not None:
            assert len(matched) == wanted
        else:
            assert len(matched) >= 0.95 * len(given.points3D)
        assert np.sqrt(np.mean(miss ** 2)) < 0.1 and miss.max() < 0.5
        assert np.sqrt(np.mean(reprojection ** 2)) < 0.1
    # COLMAP 4 (pycolmap's triangulate_points, the same step) migrates the 3.8 database (a copy: it rewrites it)
    # and triangulates the same tracks
    shutil.copy(ws / "database.db", tmp_path / "database.db")
    (tmp_path / "pycolmap").mkdir()
    newer = pycolmap.triangulate_points(pycolmap.Reconstruction(str(ws / "sparse" / "triangulator_input")),
                                        str(tmp_path / "database.db"), str(ws / "images"), str(tmp_path / "pycolmap"))
    assert len(newer.points3D) == n_multi
