"""Rolling-shutter cameras (issue 41): the readout recovered on simulated blocks against the truth, the check points
of a rolling-shutter block as good as the same block's with a global shutter, the readout screened out of a
global-shutter block (for its effect where its t-test would keep it), block.toml's keys checked, the import taking
the readout from the images' camera model, the dense workspace's 2-D points moved to the middle line. The Jacobians:
tests/test_sensor_contract.py (frame-rolling). Whole studies (10 seeds, corridor, WAPs, ODM's two-step correction,
cost): benchmarks/study_rolling_shutter.py."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from selfcal import bundle_adjust
from selfcal.errors import BlockError
from selfcal.io.block_folder import read_block, write_block
from selfcal.simulate import simulate_uav

TRUE_READOUT_MS = 33.0
FAST = {"robust": "none", "snoop": 0, "control_loo": False}


def _global(block):
    """The block with its camera declared a global shutter (today's model)."""
    camera = next(iter(block.cameras.values()))
    return replace(block, cameras={camera.camera_id: replace(camera, shutter=None, readout_ms=None,
                                                             sigma_readout_ms=None)})


def _readout(outcome) -> dict:
    return outcome.files["camera.json"]["cameras"]["ilce7m3"]["readout_ms"]


@pytest.fixture(scope="module")
def serpentine():
    """Seed 000's block flown serpentine with a fixed heading at 8 m/s, with a 33 ms rolling shutter and with a
    global one (the same images, points and noise), few points (0.3 per mm²)."""
    kw = dict(seed=4, distortion="none", flight="serpentine", speed_mps=8.0, points_per_mm2=0.3)
    return simulate_uav(rolling_shutter_ms=TRUE_READOUT_MS, **kw), simulate_uav(**kw)


def test_readout_and_check_points_recovered(serpentine):
    """GNSS and 15 GCP: the readout (prior 30 +- 30 ms) within 3 sigma of 33 ms with sigma below 1 ms, the check
    points within 1.15x of the global-shutter block's; today's model on the rolling-shutter block misses them by
    more than twice as much, and Brown + affinity does not take it up."""
    rolling, taken_global = serpentine
    model = bundle_adjust(rolling.blocks["type2"], ap="none", **FAST)
    reference = bundle_adjust(taken_global.blocks["type2"], ap="none", **FAST)
    blind = bundle_adjust(_global(rolling.blocks["type2"]), ap="none", **FAST)
    brown = bundle_adjust(_global(rolling.blocks["type2"]), ap="brown", **FAST)
    readout = _readout(model)
    print(f"readout {readout['value']:.3f} +- {readout['sigma']:.3f} ms")
    assert readout["estimated"] and readout["sigma"] < 1.0
    assert abs(readout["value"] - TRUE_READOUT_MS) < 3 * readout["sigma"]
    for axis in ("rmsd_chk_xy_m", "rmsd_chk_z_m"):
        ratio = model.summary[axis] / reference.summary[axis]
        print(axis, f"model/global-shutter {ratio:.3f}, without the model "
                    f"{blind.summary[axis] / reference.summary[axis]:.2f}, brown "
                    f"{brown.summary[axis] / reference.summary[axis]:.2f}")
        assert ratio < 1.15
    assert blind.summary["rmsd_chk_xy_m"] > 2 * reference.summary["rmsd_chk_xy_m"]
    assert brown.summary["rmsd_chk_xy_m"] > 1.5 * reference.summary["rmsd_chk_xy_m"]
    assert model.summary["sigma0_px"] < 1.05 * reference.summary["sigma0_px"] < 0.95 * blind.summary["sigma0_px"]
    # the results say how the rolling shutter was carried
    table = model.files["rolling_shutter.csv"]
    header, columns = table[0], table[1]
    velocity = np.column_stack([np.asarray(columns[header.index(f"v{a}_m_s")], float) for a in "xyz"])
    shear = np.asarray(columns[header.index("shear_col_px")], float)
    # the velocities from the GNSS positions against the true path's (a spline through the true positions)
    miss = np.linalg.norm(velocity - rolling.truth.velocity_m_s, axis=1)
    print(f"velocity from the strips' GNSS positions - truth: median {np.median(miss):.3f}, max {miss.max():.3f} m/s")
    assert np.median(miss) < 0.4 and abs(np.median(np.linalg.norm(velocity, axis=1)) - 8.0) < 0.2
    strips = np.asarray(columns[header.index("strip_id")], object)
    assert np.all(shear[strips == "S1"] < -3) and np.all(shear[strips == "S2"] > 3)   # opposite directions


def test_global_shutter_block_screens_the_readout_out(serpentine):
    """Without GNSS, a rolling-shutter model on a block taken with a global shutter: the readout is screened out
    (held at 0) and the adjustment is today's (check points and orientations within 1e-6 relative: the two take other
    iterations to the same solution)."""
    _, taken_global = serpentine
    declared = replace(taken_global.blocks["type1"], cameras=serpentine[0].blocks["type1"].cameras)
    model = bundle_adjust(declared, ap="none", screen=True, **FAST)
    today = bundle_adjust(_global(declared), ap="none", screen=True, **FAST)
    readout = _readout(model)
    assert not readout["estimated"] and readout["value"] == 0.0
    dropped = [d["name"] for d in model.files["screening.json"]["dropped"]]
    assert "readout" in dropped
    for key in ("rmsd_chk_xy_m", "rmsd_chk_z_m", "sigma0_px"):
        assert model.summary[key] == pytest.approx(today.summary[key], rel=1e-6)
    np.testing.assert_allclose(model.result.state.image, today.result.state.image, rtol=0, atol=1e-6)


def _readout_effect_px(result) -> float:
    """What holding the readout at 0 moves a sampled ray (px) or point (ground px) by (selfcal.stats.effect)."""
    from selfcal.stats.effect import effect_tracker
    from selfcal.stats.screening import _screenable
    owner, reference = _screenable(result.problem)
    i = next(k for k, o in owner.items() if o[2] == "readout")
    theta = result.problem.pack(result.state) - reference
    Q = np.asarray(result.Q_theta, float)
    return float(effect_tracker(result, Q).effects_px(np.array([i]), theta, np.diag(Q))[0])


def test_readout_without_practical_effect_is_dropped_first():
    """A global-shutter block whose readout passes the t-test (seed 26, GNSS + IMU: -0.63 ms at t 2.46, the false
    alarm of one block in 20 at 5 %) is a global shutter in practice: holding the readout at 0 moves no sampled ray
    or point by 0.1 px (0.04 px). Screening drops it for its effect, first (before the trajectory terms), and the
    screened adjustment is today's global-shutter one; held at 0 from the start it is the frame model bit for bit.
    On the rolling-shutter block (33 ms at 8 m/s: 0.26 m, 5 ground pixels, during the readout) its effect is about
    2 px, and it stays."""
    from selfcal.stats.screening import ScreeningOptions, screen_once
    kw = dict(seed=26, distortion="none", flight="serpentine", speed_mps=8.0, points_per_mm2=0.3)
    rolling = simulate_uav(rolling_shutter_ms=TRUE_READOUT_MS, **kw).blocks["type2"]
    taken_global = simulate_uav(**kw).blocks["type2"]
    declared = replace(taken_global, cameras=rolling.cameras)
    unscreened = bundle_adjust(declared, ap="none", **FAST)
    effect = _readout_effect_px(unscreened.result)
    readout = _readout(unscreened)
    t = abs(readout["value"]) / readout["sigma_adjustment"]
    print(f"global shutter: readout {readout['value']:+.3f} ms, t {t:.2f}, effect {effect:.3f} px")
    assert t > 1.96 and effect < 0.1
    model = bundle_adjust(declared, ap="none", screen=True, **FAST)
    today = bundle_adjust(_global(declared), ap="none", screen=True, **FAST)
    first = model.files["screening.json"]["dropped"][0]
    assert first["name"] == "readout" and first["round"] == 1 and first["t"] > 1.96
    assert first["reason"].startswith("its effect is 0.0") and "(< 0.1 px)" in first["reason"]
    assert not _readout(model)["estimated"] and _readout(model)["value"] == 0.0
    names = [d["name"] for d in model.files["screening.json"]["dropped"]][1:]
    assert names == [d["name"] for d in today.files["screening.json"]["dropped"]] and names
    for key in ("rmsd_chk_xy_m", "rmsd_chk_z_m", "sigma0_px"):
        assert model.summary[key] == pytest.approx(today.summary[key], rel=1e-9)
    np.testing.assert_allclose(model.result.state.image, today.result.state.image, rtol=0, atol=1e-9)
    # the readout held at 0 from the start: the frame model's arithmetic (AP none: the same sparse-free paths)
    camera = next(iter(rolling.cameras.values()))
    held = replace(declared, cameras={camera.camera_id: replace(camera, readout_ms=0.0, sigma_readout_ms=0.0)})
    a, b = bundle_adjust(held, ap="none", **FAST).result, bundle_adjust(_global(declared), ap="none", **FAST).result
    assert np.array_equal(a.state.image, b.state.image) and np.array_equal(a.state.points, b.state.points)
    # the rolling-shutter block keeps it
    outcome = bundle_adjust(rolling, ap="none", **FAST)
    effect = _readout_effect_px(outcome.result)
    print(f"rolling shutter: readout {_readout(outcome)['value']:.2f} ms, effect {effect:.2f} px")
    assert effect > 1.0
    assert screen_once(outcome.result, ScreeningOptions(), sensor_model=True)[1] == []


def _block_folder(tmp_path, rolling=True):
    sim = simulate_uav(seed=2, distortion="none", points_per_mm2=0.15, flight="serpentine",
                       rolling_shutter_ms=TRUE_READOUT_MS if rolling else 0.0)
    folder = tmp_path / "block"
    write_block(sim.blocks["type2"], folder)
    return folder


def _edit(folder, old: str, new: str, name: str = "block.toml") -> None:
    path = folder / name
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("old, new, key, reason", [
    ('shutter = "rolling"', 'shutter = "fast"', "cameras.ilce7m3.shutter", 'must be "global" or "rolling"'),
    ('shutter = "rolling"', 'shutter = "global"', "cameras.ilce7m3.readout_ms", 'give shutter = "rolling"'),
    ("sigma_readout_ms = 30.0", "sigma_readout_ms = -1.0", "cameras.ilce7m3.sigma_readout_ms", "must not be negative"),
    ("readout_ms = 30.0", 'readout_ms = 30.0\nreadout_direction = "sideways"', "cameras.ilce7m3.readout_direction",
     "down, up, right, left"),
])
def test_block_toml_keys_are_checked(tmp_path, old, new, key, reason):
    folder = _block_folder(tmp_path)
    _edit(folder, old, new)
    with pytest.raises(BlockError) as info:
        read_block(folder)
    assert info.value.column == key and reason in info.value.reason and info.value.line is not None


def test_rolling_images_need_times_and_positions(tmp_path, cli, capsys):
    folder = _block_folder(tmp_path)
    lines = (folder / "images.csv").read_text().splitlines()
    fields = lines[3].split(",")
    fields[3] = ""                                            # time_s of the third image
    lines[3] = ",".join(fields)
    (folder / "images.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(BlockError) as info:
        read_block(folder)
    assert info.value.line == 4 and info.value.column == "time_s" and 'shutter = "rolling"' in info.value.reason
    assert cli("adjust", str(folder), "--out", str(tmp_path / "r")) == 2
    assert "time_s" in capsys.readouterr().err
    # a global shutter needs neither
    _edit(folder, 'shutter = "rolling"\nreadout_ms = 30.0\nsigma_readout_ms = 30.0\n', "")
    assert read_block(folder).cameras["ilce7m3"].shutter is None


def test_simulate_cli_writes_the_truth(tmp_path, cli):
    out = tmp_path / "sim"
    assert cli("simulate", "uav", "--out", str(out), "--scenario", "type2", "--flight", "corridor",
               "--rolling-shutter-ms", "45", "--speed-mps", "11") == 0
    truth = json.loads((out / "truth" / "camera.json").read_text())
    assert truth["readout_ms"] == 45.0 and truth["shutter"] == "rolling" and truth["flight"] == "corridor"
    header = (out / "truth" / "images.csv").read_text().splitlines()[0].split(",")
    assert header[-3:] == ["vx_m_s", "vy_m_s", "vz_m_s"]
    block = read_block(out / "type2")
    assert block.cameras["ilce7m3"].shutter == "rolling" and len(set(block.images.strip_id)) == 2
    assert cli("simulate", "prism", "--out", str(tmp_path / "p"), "--rolling-shutter-ms", "5") == 2


def test_import_gnss_takes_the_readout_from_the_camera_model(tmp_path, cli, capsys):
    """The JPEGs name a DJI FC6310 (Phantom 4 Pro): 33 ms in OpenDroneMap's table, sigma 5 ms; another model: the
    wide prior 30 +- 30 ms; --readout-ms gives every camera's."""
    from PIL import Image
    from test_gnss_import import CRS, GPS_DAY, ORIGIN, _utm_block, geodetic, write_jpeg
    sim = simulate_uav(seed=2, distortion="none", points_per_mm2=0.15)
    block = _utm_block(sim.blocks["type1"])
    write_block(replace(block, images=replace(block.images, time_s=np.full(len(block.images), np.nan))),
                tmp_path / "block")
    geo = geodetic(block.images.position_m)
    for make, model, expect in (("DJI", "FC6310", (33.0, 5.0)), ("ACME", "Sky 1", (30.0, 30.0))):
        images = tmp_path / f"images-{model}"
        images.mkdir()
        for k, image_id in enumerate(block.images.image_id):
            path = images / f"{image_id}.JPG"
            write_jpeg(path, *geo[k], GPS_DAY + block.images.time_s[k])
            with Image.open(path) as image:
                exif = image.getexif()
                exif[0x010F], exif[0x0110] = make, model
                image.save(path, exif=exif)
        out = tmp_path / f"out-{model}"
        assert cli("import", "gnss", str(images), "--block", str(tmp_path / "block"), "--out", str(out),
                   "--rolling-shutter") == 0
        camera = read_block(out).cameras["ilce7m3"]
        assert (camera.shutter, camera.readout_ms, camera.sigma_readout_ms) == ("rolling", *expect)
        assert "readout" in capsys.readouterr().err
    assert cli("import", "gnss", str(images), "--block", str(tmp_path / "block"), "--out", str(tmp_path / "o2"),
               "--rolling-shutter", "--readout-ms", "41") == 0
    assert read_block(tmp_path / "o2").cameras["ilce7m3"].readout_ms == 41.0
    assert cli("import", "gnss", str(images), "--block", str(tmp_path / "block"), "--out", str(tmp_path / "o3"),
               "--readout-ms", "41") == 2
    assert block.crs == CRS and ORIGIN[0] > 0


def test_workspace_moves_2d_points_to_the_middle_line(serpentine):
    """The dense workspace's poses are the middle lines': its 2-D points, moved line by line, sit on the adjusted
    points' projections (mean error at the noise), where the measured ones miss them by the shear."""
    from selfcal.calibration import Calibration
    from selfcal.convert import colmap_workspace
    from selfcal.io.results import results_from_files
    from selfcal.workflows.export_workspace import rolling_shutters
    rolling, _ = serpentine
    outcome = bundle_adjust(rolling.blocks["type2"], ap="none", **FAST)
    results = results_from_files(outcome.files)
    cams = {c: Calibration.from_camera_json(c, e) for c, e in results.camera["cameras"].items()}
    names = {i: f"{i}.jpg" for i in results.tables["images"]["image_id"]}
    shutters = rolling_shutters(results, cams)
    assert shutters is not None and shutters.largest_shear_px > 3.0
    errors = []
    for given in (shutters, None):
        ws = colmap_workspace(cams, results.tables["images"], results.tables["points"], results.tables["residuals"],
                              names, rolling=given)
        errors.append(float(np.sqrt(np.mean(ws.model.point_error ** 2))))
    print(f"2-D points against the middle line's projection: {errors[0]:.3f} px moved, {errors[1]:.3f} px as measured")
    assert errors[0] < 0.6 < 1.0 < errors[1]


def test_images_spread_of_the_readout_against_known_velocity_errors(serpentine, monkeypatch):
    """The velocities are data: with the true ones the images agree on the readout (chi^2 / dof about 1, sigma
    hardly more than the adjustment's
    (the spread's estimate at none: a few tenths of a ms, its sampling noise); with each image's velocity scaled
    by a known 1 + a_i (a_i of sd 8 %) each image sees a readout a_i tau off:
    the images' deviations follow a_i tau (each with its noise and some of its neighbours'), their spread is
    the draws' (8 % of 33 ms, 6.7 % in the 28 draws), and camera.json's sigma adds it. Each
    image's share h_i in the estimate is what moving that image's velocity does to the readout re-adjusted (2 %:
    the linear response; 20 % would also weigh the image 1.44x)."""
    import selfcal.sensors.rolling as rolling
    from selfcal.stats.image_spread import image_spread
    sim, _ = serpentine
    block = sim.blocks["type2"]
    index = {i: k for k, i in enumerate(sim.truth.image_id)}
    truth = sim.truth.velocity_m_s[[index[i] for i in block.images.image_id]]
    scale = np.ones(len(truth))

    def given(time_s, values, groups, unwrap=False):
        return truth * scale[:, None], []
    monkeypatch.setattr(rolling, "strip_rates", given)
    exact = bundle_adjust(block, ap="none", **FAST)
    spread = image_spread(exact.result, 0, 3)
    print(f"true velocities: chi2 {spread.chi2:.1f} / {spread.dof}, spread {spread.spread:.3f} ms, "
          f"sum of shares {spread.share.sum():.4f}")
    assert 0.5 < spread.chi2 / spread.dof < 1.6 and spread.sigma_total < 1.2 * spread.sigma_adjustment
    assert 0.99 < spread.share.sum() <= 1.0
    # the share of one image: its velocity 2 % faster moves the readout by - h_i x 2 % x tau
    k = int(np.argmax(spread.share))
    scale[k] = 1.02
    moved = _readout(bundle_adjust(block, ap="none", **FAST))["value"] - _readout(exact)["value"]
    predicted = -spread.share[k] * 0.02 * _readout(exact)["value"]
    print(f"image {k}: readout moved {moved:.4f} ms, predicted {predicted:.4f} ms")
    assert moved == pytest.approx(predicted, rel=0.05)
    # every velocity off by a known share
    a = np.random.default_rng(7).normal(0.0, 0.08, len(truth))
    scale[:] = 1.0 + a
    off = bundle_adjust(block, ap="none", **FAST)
    spread = image_spread(off.result, 0, 3)
    readout = _readout(off)
    realised = TRUE_READOUT_MS * a.std()                    # 2.22 ms: these 28 draws' spread
    print(f"velocities 8 % off: spread {spread.spread:.3f} ms (the draws': {realised:.3f}), chi2 {spread.chi2:.1f} / "
          f"{spread.dof}, sigma {readout['sigma_adjustment']:.3f} -> {readout['sigma']:.3f} ms, corr(deviation, "
          f"-a tau) {np.corrcoef(spread.deviation, -a)[0, 1]:.3f}")
    assert 0.75 * realised < spread.spread < 1.3 * realised
    assert np.corrcoef(spread.deviation, -a)[0, 1] > 0.5
    assert readout["sigma"] == pytest.approx(np.hypot(readout["sigma_adjustment"],
                                                      spread.spread * np.linalg.norm(spread.share)), rel=1e-9)
    # the readout moves by what the images' shares make of their errors (linearly: -tau sum h_i a_i / (1 + a_i))
    shifted = -TRUE_READOUT_MS * float(spread.share @ (a / (1.0 + a)))
    print(f"readout {readout['value']:.3f} ms: {readout['value'] - TRUE_READOUT_MS:+.3f} off, the shares' "
          f"{shifted:+.3f}")
    assert abs(readout["value"] - TRUE_READOUT_MS - shifted) < 2 * readout["sigma_adjustment"]


def _jpegs(folder, names, times, make=None, model=None):
    """Tiny JPEGs with GPS time stamps (seconds after GPS_DAY) and, where given, EXIF Make and Model."""
    from PIL import Image
    from test_gnss_import import GPS_DAY, write_jpeg
    folder.mkdir()
    for k, (name, t) in enumerate(zip(names, times)):
        path = folder / name
        write_jpeg(path, 9.0 + 1e-5 * k, 47.0, 500.0, GPS_DAY + t)
        if make:
            with Image.open(path) as image:
                exif = image.getexif()
                exif[0x010F], exif[0x0110] = make, model
                image.save(path, exif=exif)


def test_import_colmap_takes_times_and_readout_from_the_images(tmp_path, cli, capsys):
    """COLMAP's files hold no exposure times: ``--images`` brings them from the JPEGs' EXIF with the camera model
    (a DJI FC330, Phantom 4: 33 +- 5 ms); without it the error says how to give them; an image without a JPEG is
    named."""
    from front_door import write_colmap
    sparse, images, out = tmp_path / "sparse", tmp_path / "images", tmp_path / "block"
    write_colmap(str(sparse), binary=False)
    names = [f"img{k}.jpg" for k in range(1, 5)]
    _jpegs(images, names, [0.0, 2.1, 4.0, 6.2], "DJI", "FC330")
    argv = ["import", "colmap", str(sparse), "--pixel-size-mm", "0.005", "--rolling-shutter"]
    assert cli(*argv, "--images", str(images), "--out", str(out)) == 0
    assert "dji fc330" in capsys.readouterr().err
    block = read_block(out)
    camera = block.cameras["cam1"]
    assert (camera.shutter, camera.readout_ms, camera.sigma_readout_ms) == ("rolling", 33.0, 5.0)
    np.testing.assert_allclose(block.images.time_s, [0.0, 2.1, 4.0, 6.2], atol=1e-3)
    assert list(block.images.strip_id) == ["S1"] * 4
    assert cli(*argv, "--out", str(tmp_path / "b2")) == 2
    err = capsys.readouterr().err
    assert "exposure time" in err and "--images DIR" in err and "selfcal import gnss" in err
    (images / "img3.jpg").unlink()
    assert cli(*argv, "--images", str(images), "--out", str(tmp_path / "b3")) == 2
    err = capsys.readouterr().err
    assert str(images) in err and "img3.jpg" in err
    assert cli("import", "colmap", str(sparse), "--images", str(images), "--out", str(tmp_path / "b4")) == 2
    assert "give --rolling-shutter" in capsys.readouterr().err
    for wrong in (tmp_path / "no-such-folder", images / "img1.jpg"):        # refused before the import's work
        assert cli(*argv, "--images", str(wrong), "--out", str(tmp_path / "b5")) == 2
        assert f"{wrong}: not a folder" in capsys.readouterr().err
    assert not any((tmp_path / b).exists() for b in ("b2", "b3", "b4", "b5"))


def test_import_pix4d_maps_its_camera_name_to_the_readout(tmp_path, cli, capsys):
    """Pix4D names the camera in the BINGO headers (``FC6310_8.8_5472x3648``: the Phantom 4 Pro's model, 33 ms in
    OpenDroneMap's table); the JPEGs give the times, the strips follow from them and the positions (the
    simulator's two strips), and an EXIF model, where the JPEGs have one, comes first (an FC220, Mavic Pro: 64 ms)."""
    from test_import_uav import write_pix4d
    sim = simulate_uav(seed=5, distortion="none", n_strips=2, images_per_strip=3, points_per_mm2=0.1)
    project = tmp_path / "project"
    _, gcp = write_pix4d(str(project), sim)
    bingo = project / "1_initial" / "params" / "proj_tp_bingo.txt"
    bingo.write_text(bingo.read_text().replace("ilce7m3_20.96_35.4", "FC6310_8.8_5472x3648"))
    images = sim.blocks["type1"].images
    argv = ["import", "pix4d", str(project), "--gcp", gcp, "--rolling-shutter"]
    for folder, exif, expect in (("plain", (None, None), (33.0, 5.0)), ("exif", ("DJI", "FC220"), (64.0, 9.6))):
        _jpegs(tmp_path / folder, [f"{i}.JPG" for i in images.image_id], images.time_s, *exif)
        out = tmp_path / f"block-{folder}"
        assert cli(*argv, "--images", str(tmp_path / folder), "--out", str(out)) == 0
        block = read_block(out)
        camera = block.cameras["pix4d"]
        assert (camera.shutter, camera.readout_ms, camera.sigma_readout_ms) == ("rolling", *expect)
        order = [list(images.image_id).index(i) for i in block.images.image_id]
        np.testing.assert_allclose(block.images.time_s, images.time_s[order] - images.time_s.min(), atol=1e-3)
        pairs = {(a, b) for a, b in zip(block.images.strip_id, images.strip_id[order])}
        assert len(pairs) == len(set(images.strip_id)) == len(set(block.images.strip_id)) == 2
    assert "fc6310" in capsys.readouterr().err
    assert cli(*argv, "--out", str(tmp_path / "none")) == 2
    assert "Pix4D's params folder" in capsys.readouterr().err
