"""The UAV tools' calibration formats, out and in: Metashape XML, OpenSfM cameras.json, OpenCV FileStorage
(YAML, XML, JSON) and Kalibr camchain.yaml.

Truth first: a camera with a known Brown distortion (and one with a WAP, whose misfit must be reported) and a
known covariance of its parameters. Every written file is read by the other tool's reader where one installs
here (cv2.FileStorage, cv2.projectPoints), else by the tool's DOCUMENTED projection implemented here
independently of selfcal's (each cites its source), and must project a grid of measured positions within
the misfit the export printed. The sigmas written are checked against a finite-difference propagation
(refitting with each selfcal parameter moved). Round trip: export, import into a block, and the block's
initial camera projects like the original. ``--fixed`` holds the values through ``selfcal adjust``.
"""
import json
import shutil
import re
import xml.etree.ElementTree as ElementTree
from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml

from selfcal.ap import ImageFrame, ap_from_dict, create_ap
from selfcal.calibration import Calibration
from selfcal.calibration_models import MODELS, fit_camera_model

from conftest import run_cli

WIDTH, HEIGHT, PIXEL_MM, FOCAL_MM = 1500, 1000, 0.004, 6.0
CAMERA_ID = 'Canon "EOS" 450D'
# Brown (selfcal's, px at the frame corner): about 27 px of radial distortion at the corner, some decentering
BROWN = [-30.0, 3.0, 0.0, 0.1, -0.05, 0.0, 0.0]
THETA = ["c", "x0", "y0", "k1", "k2", "k3", "p1", "p2", "b1", "b2"]


def known_covariance():
    """A covariance of (c, x0, y0 in mm; the seven Brown coefficients in px) with strong correlations, as a
    self-calibration gives: sigma c 2 um, x0 and y0 1 um, APs 0.02-0.2 px."""
    sigma = np.array([0.002, 0.001, 0.001, 0.2, 0.1, 0.05, 0.02, 0.02, 0.03, 0.03])
    rng = np.random.default_rng(7)
    a = rng.normal(size=(10, 10))
    rho = a @ a.T + 3 * np.eye(10)
    d = 1 / np.sqrt(np.diag(rho))
    rho = rho * d[:, None] * d[None, :]
    return rho * sigma[:, None] * sigma[None, :]


def camera_entry(values=BROWN, spec="brown", x0_mm=0.01, y0_mm=-0.02, covariance=None, ap=None,
                 width=WIDTH, height=HEIGHT, pixel_mm=PIXEL_MM, focal_mm=FOCAL_MM):
    """camera.json entry of a frame camera, as selfcal adjust writes it (with the covariance block)."""
    frame = ImageFrame(width * pixel_mm, height * pixel_mm, pixel_mm)
    ap = ap or create_ap(spec, frame)
    entry = {"model": "frame", "width_px": width, "height_px": height, "pixel_size_mm": pixel_mm,
             "focal_mm": {"value": focal_mm}, "x0_mm": {"value": x0_mm}, "y0_mm": {"value": y0_mm},
             "ap": {**ap.to_dict(), "coefficients": [{"name": n, "value_px": float(v), "active": True}
                                                     for n, v in zip(ap.parameter_names, values)]}}
    if covariance is not None:
        entry["covariance"] = {"parameters": ["c", "x0", "y0"] + list(ap.parameter_names),
                               "matrix": np.asarray(covariance).tolist()}
    return entry


def results_folder(path, entry, camera_id=CAMERA_ID):
    path.mkdir()
    (path / "camera.json").write_text(json.dumps({"cameras": {camera_id: entry}}))
    return path


def grid(cal, n=25):
    """Measured positions on a grid over the whole image, corners included, and their ideal normalised
    coordinates (OpenCV's camera frame: x right, y down) from selfcal's model."""
    u, v = np.meshgrid(np.linspace(0, cal.width_px, n), np.linspace(0, cal.height_px, n))
    measured = np.column_stack([u.ravel(), v.ravel()])
    return measured, cal.normalised_from_measured(measured)


def printed_misfit(err):
    rms, worst = re.search(r"misfit to selfcal's model ([\d.]+) px rms, ([\d.]+) px max", err).groups()
    return float(rms), float(worst)


# --- the tools' documented projections, written here from their manuals (not from selfcal's code) ----------

def metashape_project(n, c, w, h):
    """Metashape user manual (Professional Edition 1.5-2.1), Appendix C "Camera models", Frame cameras:
    x' = x(1 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + (P1(r^2 + 2x^2) + 2 P2 x y),
    y' = y(1 + K1 r^2 + ... ) + (P2(r^2 + 2y^2) + 2 P1 x y), u = w 0.5 + cx + x' f + x' B1 + y' B2,
    v = h 0.5 + cy + y' f; pixel coordinates with the centre of the top-left pixel at (0.5, 0.5)."""
    x, y = n.T
    r2 = x**2 + y**2
    radial = 1 + c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3 + c["k4"] * r2**4
    xs = x * radial + (c["p1"] * (r2 + 2 * x**2) + 2 * c["p2"] * x * y)
    ys = y * radial + (c["p2"] * (r2 + 2 * y**2) + 2 * c["p1"] * x * y)
    return np.column_stack([w * 0.5 + c["cx"] + xs * c["f"] + xs * c["b1"] + ys * c["b2"],
                            h * 0.5 + c["cy"] + ys * c["f"]])


def opensfm_project(n, c, w, h):
    """OpenSfM docs, "Geometric models" (doc/source/geometry.rst): the brown / perspective camera maps x/z,
    y/z to normalised image coordinates (origin at the image centre, larger side 1); pixel coordinates
    (OpenCV's, the centre of the first pixel at 0) are max(w, h) u + (w - 1)/2. Returned in the corner
    convention (+ 0.5) to compare with selfcal."""
    x, y = n.T
    r2 = x**2 + y**2
    if c["projection_type"] == "brown":
        dr = 1 + c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3
        u = c["focal_x"] * (dr * x + 2 * c["p1"] * x * y + c["p2"] * (r2 + 2 * x**2)) + c["c_x"]
        v = c["focal_y"] * (dr * y + 2 * c["p2"] * x * y + c["p1"] * (r2 + 2 * y**2)) + c["c_y"]
    else:                                          # perspective
        d = 1 + c["k1"] * r2 + c["k2"] * r2**2
        u, v = c["focal"] * d * x, c["focal"] * d * y
    s = max(w, h)
    return np.column_stack([s * u + (w - 1) / 2 + 0.5, s * v + (h - 1) / 2 + 0.5])


def kalibr_project(n, cam):
    """Kalibr wiki, "Supported models": pinhole projection [fu, fv, pu, pv]; radtan distortion [k1, k2, r1, r2]
    (OpenCV's plumb_bob without k3); equidistant [k1..k4] (theta_d = theta(1 + k1 theta^2 + ... + k4 theta^8),
    OpenCV's fisheye). Pixel centres at integers (OpenCV), returned + 0.5."""
    fu, fv, pu, pv = cam["intrinsics"]
    k = cam["distortion_coeffs"]
    x, y = n.T
    r2 = x**2 + y**2
    if cam["distortion_model"] == "radtan":
        radial = 1 + k[0] * r2 + k[1] * r2**2
        xd = x * radial + 2 * k[2] * x * y + k[3] * (r2 + 2 * x**2)
        yd = y * radial + k[2] * (r2 + 2 * y**2) + 2 * k[3] * x * y
    else:
        r = np.sqrt(r2)
        t = np.arctan(r)
        td = t * (1 + k[0] * t**2 + k[1] * t**4 + k[2] * t**6 + k[3] * t**8)
        xd, yd = td / r * x, td / r * y
    return np.column_stack([fu * xd + pu + 0.5, fv * yd + pv + 0.5])


# --- OUT ---------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def brown(tmp_path_factory):
    folder = results_folder(tmp_path_factory.mktemp("brown") / "r", camera_entry(covariance=known_covariance()))
    return folder, Calibration.from_camera_json(CAMERA_ID, camera_entry(covariance=known_covariance()))


def finite_difference_covariance(cal, model, start, covariance):
    """Sigma_q = L Sigma L^T with L from refitting the tool's model with each selfcal parameter moved by +-h."""
    columns = []
    for j, name in enumerate(cal.theta_names):
        h = 2e-4 if j < 3 else 2e-3
        fits = []
        for s in (h, -h):
            if j < 3:
                moved = replace(cal, **{("focal_mm", "x0_mm", "y0_mm")[j]: getattr(cal, ("focal_mm", "x0_mm",
                                                                                          "y0_mm")[j]) + s})
            else:
                a = cal.coefficients_px.copy()
                a[j - 3] += s
                moved = replace(cal, coefficients_px=a)
            fits.append(fit_camera_model(moved, model, start=start).values)
        columns.append((fits[0] - fits[1]) / (2 * h))
    L = np.column_stack(columns)
    return L @ covariance @ L.T


def test_metashape_xml_projects_like_selfcal_with_propagated_covariance(brown, tmp_path, capsys):
    folder, cal = brown
    out = tmp_path / "cal.xml"
    assert run_cli("export", "metashape", str(folder), "--out", str(out), "--tolerance-px", "0.05") == 0
    err = capsys.readouterr().err
    rms, worst = printed_misfit(err)
    assert "warning" not in err and worst < 0.05
    root = ElementTree.parse(out).getroot()
    assert root.tag == "calibration" and root.findtext("projection") == "frame"
    w, h = int(root.findtext("width")), int(root.findtext("height"))
    assert (w, h) == (WIDTH, HEIGHT)
    c = {tag: float(root.findtext(tag)) for tag in ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2")}
    # Metashape's conventions: f in px, cx/cy offsets from the image centre in px
    assert c["f"] == pytest.approx(FOCAL_MM / PIXEL_MM, abs=0.05)
    assert c["cx"] == pytest.approx(0.01 / PIXEL_MM, abs=0.05) and c["cy"] == pytest.approx(0.02 / PIXEL_MM, abs=0.05)
    measured, n = grid(cal)
    miss = np.hypot(*(metashape_project(n, c, w, h) - measured).T)
    assert miss.max() <= worst + 1e-3, (miss.max(), worst)
    # P1/P2 are swapped against OpenCV's p1/p2: OpenCV's plumb_bob fit of the same camera has p2 = Metashape's P1
    plumb = fit_camera_model(cal, MODELS["opencv", "plumb_bob"]).values
    assert c["p1"] == pytest.approx(plumb[7], rel=0.05) and c["p2"] == pytest.approx(plumb[6], rel=0.05)
    # the covariance block, in Metashape's parameter names, against a finite-difference propagation
    names = root.findtext("covariance/params").split()
    coeffs = np.array(root.findtext("covariance/coeffs").split(), float).reshape(len(names), len(names))
    assert names == ["f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2"]
    fitted = fit_camera_model(cal, MODELS["metashape", "frame"])
    reference = finite_difference_covariance(cal, fitted.model, fitted.values, known_covariance())
    # Gauss-Newton linearisation (the misfit's curvature left out) against refits: 0.1 % for f, cx, cy, 2.2 % for
    # k4, the worst-determined coefficient
    np.testing.assert_allclose(np.sqrt(np.diag(coeffs))[:3], np.sqrt(np.diag(reference))[:3], rtol=0.002)
    np.testing.assert_allclose(np.sqrt(np.diag(coeffs)), np.sqrt(np.diag(reference)), rtol=0.03)
    # sigma f comes from sigma c (2 um = 0.5 px) and the correlations: it is not zero, and not just sigma c
    assert 0.1 < np.sqrt(coeffs[0, 0]) < 2.0


@pytest.mark.parametrize("ext", [".yaml", ".xml", ".json"])
def test_opencv_filestorage_in_every_format_with_sigma(brown, tmp_path, capsys, ext):
    """cv2.FileStorage reads all three formats back; cv2.projectPoints with them lands within the printed
    misfit; the camera id with quotes and a space survives; sigma matches a finite-difference propagation."""
    folder, cal = brown
    out = tmp_path / f"cam{ext}"
    assert run_cli("export", "opencv", str(folder), "--out", str(out), "--opencv-model", "plumb_bob",
                   "--tolerance-px", "0.05") == 0
    _, worst = printed_misfit(capsys.readouterr().err)
    storage = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    K = storage.getNode("camera_matrix").mat()
    dist = storage.getNode("distortion_coefficients").mat().ravel()
    assert storage.getNode("camera_id").string() == CAMERA_ID
    assert storage.getNode("distortion_model").string() == "plumb_bob"
    assert int(storage.getNode("image_width").real()) == WIDTH
    sigma = storage.getNode("parameter_sigma").mat().ravel()
    cov = storage.getNode("parameter_covariance").mat()
    names = storage.getNode("parameter_names").string().split()
    storage.release()
    assert names == ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
    measured, n = grid(cal)
    projected, _ = cv2.projectPoints(np.column_stack([n, np.ones(len(n))]), np.zeros(3), np.zeros(3), K, dist)
    miss = np.hypot(*(projected[:, 0] + 0.5 - measured).T)           # OpenCV: first pixel centre at (0, 0)
    assert miss.max() <= worst + 1e-3
    np.testing.assert_allclose(sigma, np.sqrt(np.diag(cov)))
    if ext == ".yaml":                                   # the finite differences once (the same numbers in all)
        fitted = fit_camera_model(cal, MODELS["opencv", "plumb_bob"])
        reference = finite_difference_covariance(cal, fitted.model, fitted.values, known_covariance())
        np.testing.assert_allclose(sigma, np.sqrt(np.diag(reference)), rtol=0.03)


def test_opensfm_and_kalibr_project_like_selfcal(brown, tmp_path, capsys):
    folder, cal = brown
    measured, n = grid(cal)
    assert run_cli("export", "opensfm", str(folder), "--out", str(tmp_path / "cameras.json")) == 0
    _, worst = printed_misfit(capsys.readouterr().err)
    cameras = json.loads((tmp_path / "cameras.json").read_text())
    (entry,) = cameras.values()
    assert entry["projection_type"] == "brown"          # perspective has no principal point off centre
    assert entry["focal_x"] == pytest.approx(FOCAL_MM / PIXEL_MM / WIDTH, rel=1e-3)
    miss = np.hypot(*(opensfm_project(n, entry, entry["width"], entry["height"]) - measured).T)
    assert miss.max() <= worst + 1e-3 and worst < 0.05

    for model in ("radtan", "equidistant"):
        out = tmp_path / f"camchain-{model}.yaml"
        assert run_cli("export", "kalibr", str(folder), "--out", str(out), "--model", model) == 0
        _, worst = printed_misfit(capsys.readouterr().err)
        cam = yaml.safe_load(out.read_text())["cam0"]
        assert cam["camera_model"] == "pinhole" and cam["distortion_model"] == model
        assert cam["resolution"] == [WIDTH, HEIGHT]
        miss = np.hypot(*(kalibr_project(n, cam) - measured).T)
        assert miss.max() <= worst + 1e-3 and worst < 0.5


def test_wap_misfit_is_reported_and_warned(tmp_path, capsys):
    """A db4 WAP field has no form in any of the tools: each export prints the misfit its own documented
    projection really shows, and warns."""
    frame = ImageFrame(WIDTH * PIXEL_MM, HEIGHT * PIXEL_MM, PIXEL_MM)
    ap = create_ap("wavelet:db4", frame, grid=(5, 4))
    values = np.random.default_rng(3).normal(0.0, 1.5, ap.n_params)
    folder = results_folder(tmp_path / "r", camera_entry(values, ap=ap))
    cal = Calibration.from_camera_json(CAMERA_ID, camera_entry(values, ap=ap))
    measured, n = grid(cal, 61)
    assert run_cli("export", "metashape", str(folder), "--out", str(tmp_path / "w.xml")) == 0
    err = capsys.readouterr().err
    rms, worst = printed_misfit(err)
    assert "warning" in err and worst > 0.5
    root = ElementTree.parse(tmp_path / "w.xml").getroot()
    c = {e.tag: float(e.text) for e in root if e.tag not in ("projection", "width", "height", "covariance")}
    miss = np.hypot(*(metashape_project(n, c, WIDTH, HEIGHT) - measured).T)
    # the stated misfit is the real one (measured on the export's 121-node grid, this grid's nodes fall between)
    assert 0.9 * worst < miss.max() <= 1.01 * worst
    assert root.find("covariance") is None and "no covariance" in err


def test_wap_calibration_reads_back_the_functions_it_left_out():
    """The dependent WAP functions were chosen by a pivoted QR among functions whose residual norms tie up to
    rounding, so a file from another machine or an older version may have left out others: camera.json names
    those it left out and a calibration read back keeps exactly the others, in the order of its coefficients.
    Told another set (as another machine's choice), the model keeps that set; coefficients whose names do not
    match the rebuilt model, and an unknown function, are errors. A file from before left_out was written keeps
    the functions its coefficients name."""
    frame = ImageFrame(WIDTH * PIXEL_MM, HEIGHT * PIXEL_MM, PIXEL_MM)
    ap = create_ap("wavelet:db4", frame, grid=(5, 4))
    written = ap.to_dict()
    assert len(written["left_out"]) == written["n_dependent"] > 0
    values = np.random.default_rng(5).normal(0.0, 1.0, ap.n_params)
    cal = Calibration.from_camera_json(CAMERA_ID, camera_entry(values, ap=ap))
    assert cal.ap.parameter_names == ap.parameter_names and np.array_equal(cal.coefficients_px, values)
    # another machine's choice: its first kept function left out instead of the first one left out here
    other = dict(written, left_out=[ap.parameter_names[0]] + written["left_out"][1:])
    theirs = ap_from_dict(other, frame)
    assert written["left_out"][0] in theirs.parameter_names and ap.parameter_names[0] not in theirs.parameter_names
    entry = camera_entry(values, ap=ap)
    entry["ap"]["left_out"] = other["left_out"]                  # the names of the coefficients no longer match
    with pytest.raises(ValueError, match="AP coefficient 1 is"):
        Calibration.from_camera_json(CAMERA_ID, entry)
    with pytest.raises(ValueError, match="unknown function 'ax\\[\\+99"):
        ap_from_dict(dict(written, left_out=["ax[+99,+0]"]), frame)
    # a file from before left_out was written, by the other machine: its coefficients' names say what it kept
    entry = camera_entry(values, ap=theirs)
    del entry["ap"]["left_out"]
    cal = Calibration.from_camera_json(CAMERA_ID, entry)
    assert cal.ap.parameter_names == theirs.parameter_names and np.array_equal(cal.coefficients_px, values)
    # and without the names, the model chooses again
    for coefficient in entry["ap"]["coefficients"]:
        del coefficient["name"]
    assert Calibration.from_camera_json(CAMERA_ID, entry).ap.parameter_names == ap.parameter_names


# --- IN ----------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_block(tmp_path_factory):
    """A 10-image simulated block with a Brown distortion, its camera and the true calibration as a
    camera.json entry (selfcal's brown, about the frame centre, fitted to the simulation's field about the
    principal point: within 0.02 px, far below the 0.5 px noise)."""
    from selfcal.ap import fit_displacement, frame_nodes_mm
    from selfcal.io import write_block
    from selfcal.simulate import simulate_uav
    sim = simulate_uav(seed=3, distortion="brown", points_per_mm2=0.05, n_strips=2, images_per_strip=5)
    block = sim.blocks["type3"]
    path = tmp_path_factory.mktemp("block") / "block"
    write_block(block, path)
    (camera,) = block.cameras.values()
    true = sim.truth.camera
    frame = ImageFrame(true.width_mm, true.height_mm, true.pixel_size_mm)
    x, y = frame_nodes_mm(frame)
    ap = create_ap("brown", frame)
    values, misfit = fit_displacement(ap, x, y, *sim.truth.distortion.displacement_px(x, y))
    assert np.abs(misfit).max() < 0.02
    truth = camera_entry(values, width=true.width_px, height=true.height_px, pixel_mm=true.pixel_size_mm,
                         focal_mm=true.focal_mm, x0_mm=true.x0_mm, y0_mm=true.y0_mm)
    return path, camera, truth


def block_calibration(folder):
    """The initial calibration of the only camera of a block folder, as selfcal would start from it."""
    from selfcal.io import read_block
    block = read_block(folder)
    (cam,) = block.cameras.values()
    frame = ImageFrame(cam.width_mm, cam.height_mm, cam.pixel_size_mm)
    ap = create_ap(cam.initial_ap.spec, frame)
    values = dict(zip(cam.initial_ap.names, cam.initial_ap.values_px))
    return cam, Calibration(cam.camera_id, cam.width_px, cam.height_px, cam.pixel_size_mm, cam.focal_mm, cam.x0_mm,
                            cam.y0_mm, ap, np.array([values[n] for n in ap.parameter_names]))


EXPORTS = [("metashape", "cal.xml", ()), ("opensfm", "cameras.json", ()), ("opencv", "cam.yaml", ()),
           ("opencv", "cam.xml", ()), ("opencv", "cam.json", ()), ("kalibr", "camchain.yaml", ())]


@pytest.mark.parametrize("tool,name,options", EXPORTS)
def test_round_trip_export_import(small_block, tmp_path, capsys, tool, name, options):
    """Export, import into the block: the block's initial camera projects like the original calibration."""
    path, camera, _ = small_block
    entry = camera_entry([v * 0.5 for v in BROWN], width=camera.width_px, height=camera.height_px,
                         pixel_mm=camera.pixel_size_mm, focal_mm=camera.focal_mm, x0_mm=0.02, y0_mm=-0.01)
    folder = results_folder(tmp_path / "r", entry, camera.camera_id)
    original = Calibration.from_camera_json(camera.camera_id, entry)
    assert run_cli("export", tool, str(folder), "--out", str(tmp_path / name), *options) == 0
    _, exported = printed_misfit(capsys.readouterr().err)
    assert run_cli("import", "calibration", str(tmp_path / name), "--block", str(path),
                   "--out", str(tmp_path / "b2")) == 0
    assert "brown APs reproduce its distortion" in capsys.readouterr().err
    cam, imported = block_calibration(tmp_path / "b2")
    assert cam.sigma_focal_mm is None and cam.initial_ap.sigma_px is None
    u, v = np.meshgrid(np.linspace(0, camera.width_px, 31), np.linspace(0, camera.height_px, 31))
    measured = np.column_stack([u.ravel(), v.ravel()])
    # the same ray (ideal normalised coordinates) from the original and from the imported camera
    miss = np.hypot(*((imported.normalised_from_measured(measured) - original.normalised_from_measured(measured))
                      * original.focal_px).T)
    print(f"round trip {tool} {name}: export misfit {exported:.4f} px, imported camera off by {miss.max():.4f} px")
    assert miss.max() < exported + 0.005, (miss.max(), exported)      # measured: 0.0005-0.0036 px


def test_fixed_calibration_is_held_through_adjust(small_block, tmp_path, capsys):
    """The true calibration, exported to Metashape, imported with --fixed: ``selfcal adjust`` (asked for
    ebner APs) keeps c, x0, y0 and the brown APs exactly as imported, and they are used: sigma0 is the
    simulated noise (0.5 px), where the same block without its 11 px of distortion modelled is far off."""
    path, camera, truth = small_block
    folder = results_folder(tmp_path / "r", truth, camera.camera_id)
    assert run_cli("export", "metashape", str(folder), "--out", str(tmp_path / "cal.xml")) == 0
    assert run_cli("import", "calibration", str(tmp_path / "cal.xml"), "--block", str(path), "--fixed",
                   "--out", str(tmp_path / "b2")) == 0
    cam, _ = block_calibration(tmp_path / "b2")
    assert cam.sigma_focal_mm == 0 and cam.sigma_x0_mm == 0 and cam.sigma_y0_mm == 0
    assert cam.initial_ap.sigma_px == 0
    assert run_cli("adjust", str(tmp_path / "b2"), "--out", str(tmp_path / "res"), "--ap", "ebner",
                   "--no-report", "--quiet") == 0
    adjusted = json.loads((tmp_path / "res" / "camera.json").read_text())["cameras"][camera.camera_id]
    assert adjusted["focal_mm"]["value"] == cam.focal_mm and adjusted["focal_mm"]["estimated"] is False
    assert adjusted["x0_mm"]["value"] == cam.x0_mm and adjusted["y0_mm"]["value"] == cam.y0_mm
    assert adjusted["ap"]["spec"] == "brown"
    values = {c["name"]: c["value_px"] for c in adjusted["ap"]["coefficients"]}
    assert values == dict(zip(cam.initial_ap.names, cam.initial_ap.values_px))
    assert all(c["held"] and not c["active"] for c in adjusted["ap"]["coefficients"])
    sigma0 = json.loads((tmp_path / "res" / "summary.json").read_text())["sigma0_px"]
    assert 0.4 < sigma0 < 0.6, sigma0
    # and an export of those results carries the held APs (not zeros)
    held = Calibration.from_camera_json(camera.camera_id, adjusted)
    np.testing.assert_array_equal(held.coefficients_px, [values[n] for n in held.ap.parameter_names])


def test_weighted_calibration_is_a_prior_of_the_given_sigma(small_block, tmp_path):
    """``[cameras.ID.initial_ap] sigma_px`` > 0 weights the imported APs: a tight sigma keeps them at the
    imported (here: wrong, half the true) values, a loose one lets the adjustment take them to the truth."""
    path, camera, truth = small_block
    truth_ap = {c["name"]: c["value_px"] for c in truth["ap"]["coefficients"]}
    wrong = json.loads(json.dumps(truth))
    for c in wrong["ap"]["coefficients"]:
        c["value_px"] *= 0.5
    folder = results_folder(tmp_path / "r", wrong, camera.camera_id)
    assert run_cli("export", "metashape", str(folder), "--out", str(tmp_path / "cal.xml")) == 0
    assert run_cli("import", "calibration", str(tmp_path / "cal.xml"), "--block", str(path),
                   "--out", str(tmp_path / "b")) == 0
    cam, _ = block_calibration(tmp_path / "b")
    imported = dict(zip(cam.initial_ap.names, cam.initial_ap.values_px))
    toml = (tmp_path / "b" / "block.toml").read_text()
    out = {}
    for sigma in (1e-4, 1e3):
        folder_b = tmp_path / f"b{sigma:g}"
        shutil.copytree(tmp_path / "b", folder_b)
        (folder_b / "block.toml").write_text(toml.replace('model = "brown"', f'model = "brown"\nsigma_px = {sigma!r}', 1))
        assert run_cli("adjust", str(folder_b), "--out", str(tmp_path / f"res{sigma:g}"), "--ap", "brown",
                       "--snoop", "0", "--no-report", "--quiet") == 0
        adjusted = json.loads((tmp_path / f"res{sigma:g}" / "camera.json").read_text())["cameras"][camera.camera_id]
        out[sigma] = {c["name"]: (c["value_px"], c["sigma_px"]) for c in adjusted["ap"]["coefficients"]}
    k1 = "k1" if "k1" in truth_ap else next(iter(truth_ap))
    assert abs(truth_ap[k1]) > 5                                          # the tested coefficient matters
    tight, loose = out[1e-4][k1], out[1e3][k1]
    # held by its prior (a-posteriori sigma: the prior's, times sigma0 / the a-priori image sigma)
    assert abs(tight[0] - imported[k1]) < 5e-4 and tight[1] < 1.5e-4
    assert abs(loose[0] - truth_ap[k1]) < 4 * loose[1] + 0.05 * abs(truth_ap[k1])   # free to reach the truth
    assert abs(loose[0] - imported[k1]) > 3 * loose[1]                    # and it did move


def test_import_errors_exit_with_two(small_block, tmp_path, capsys):
    path, camera, _ = small_block
    other = camera_entry(width=camera.width_px + 2, height=camera.height_px, pixel_mm=camera.pixel_size_mm)
    folder = results_folder(tmp_path / "r", other, camera.camera_id)
    assert run_cli("export", "kalibr", str(folder), "--out", str(tmp_path / "camchain.yaml")) == 0
    capsys.readouterr()
    assert run_cli("import", "calibration", str(tmp_path / "camchain.yaml"), "--block", str(path),
                   "--out", str(tmp_path / "b2")) == 2
    err = capsys.readouterr().err
    assert "camchain.yaml" in err and f"{camera.width_px + 2} x {camera.height_px} px" in err
    junk = tmp_path / "notes.txt"
    junk.write_text("f = 3000\n")
    assert run_cli("import", "calibration", str(junk), "--block", str(path), "--out", str(tmp_path / "b3")) == 2
    err = capsys.readouterr().err
    assert "notes.txt" in err and "not a calibration file" in err
    bad = tmp_path / "bad.xml"
    bad.write_text("<calibration><projection>frame</projection><width>10</width></calibration>")
    assert run_cli("import", "calibration", str(bad), "--block", str(path), "--out", str(tmp_path / "b4")) == 2
    assert "bad.xml" in capsys.readouterr().err
    assert not (tmp_path / "b2").exists() and not (tmp_path / "b3").exists()


def test_adjusted_camera_json_carries_the_covariance_the_export_propagates(small_block, tmp_path, capsys):
    """After a real adjustment, camera.json's covariance block has the sigmas camera.json states on its
    diagonal, and the Metashape export of those results propagates it (sigma f from sigma c: f = c / p)."""
    path, camera, truth = small_block
    assert run_cli("adjust", str(path), "--out", str(tmp_path / "res"), "--ap", "brown", "--no-report",
                   "--quiet") == 0
    entry = json.loads((tmp_path / "res" / "camera.json").read_text())["cameras"][camera.camera_id]
    cov = entry["covariance"]
    sigma = dict(zip(cov["parameters"], np.sqrt(np.diag(np.array(cov["matrix"])))))
    assert cov["parameters"][:3] == ["c", "x0", "y0"]
    assert sigma["c"] == pytest.approx(entry["focal_mm"]["sigma"], rel=1e-9)
    assert sigma["y0"] == pytest.approx(entry["y0_mm"]["sigma"], rel=1e-9)
    for c in entry["ap"]["coefficients"]:
        assert sigma[c["name"]] == pytest.approx(c["sigma_px"], rel=1e-9)
    assert run_cli("export", "metashape", str(tmp_path / "res"), "--out", str(tmp_path / "cal.xml"),
                   "--tolerance-px", "0.1") == 0
    root = ElementTree.parse(tmp_path / "cal.xml").getroot()
    coeffs = np.array(root.findtext("covariance/coeffs").split(), float).reshape(11, 11)
    # f moves with c (1/p px per mm) and hardly with anything else: its sigma is sigma_c / p within 5 %
    assert np.sqrt(coeffs[0, 0]) == pytest.approx(sigma["c"] / camera.pixel_size_mm, rel=0.05)


def test_metashape_document_sensor_is_read_like_its_calibration_file(tmp_path):
    """A Metashape cameras export (<document>: sensor/calibration with <resolution>, as Metashape writes its
    project's cameras) gives the same calibration and covariance as the calibration file."""
    from selfcal.io.calibration_files import read_calibration_file
    c = {"f": 1940.44, "cx": 13.17, "cy": 9.91, "k1": -0.1057, "k2": 0.1813, "k3": -0.0593, "p1": 0.00206,
         "p2": 0.00047}
    cov = np.diag([2.07, 2.90, 3.62, 1e-6, 1e-5, 1e-5, 1e-8, 1e-8])
    tags = "".join(f"<{k}>{v}</{k}>" for k, v in c.items())
    (tmp_path / "cameras.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<document version="1.5.0"><chunk label="Chunk 1"><sensors>'
        '<sensor id="0" label="unknown" type="frame"><resolution width="2256" height="1504"/>'
        f'<calibration type="frame" class="adjusted"><resolution width="2256" height="1504"/>{tags}</calibration>'
        f'<covariance><params>f cx cy k1 k2 k3 p1 p2</params><coeffs>{" ".join(map(str, cov.ravel()))}</coeffs>'
        '</covariance></sensor></sensors></chunk></document>\n')
    (tmp_path / "cal.xml").write_text(f"<calibration><projection>frame</projection><width>2256</width>"
                                      f"<height>1504</height>{tags}</calibration>")
    doc, single = read_calibration_file(tmp_path / "cameras.xml"), read_calibration_file(tmp_path / "cal.xml")
    assert (doc.width_px, doc.height_px) == (2256, 1504) and doc.values == single.values
    assert doc.values["b1"] == 0.0 and doc.values["k1"] == -0.1057
    assert doc.covariance_names == ("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2")
    np.testing.assert_array_equal(doc.covariance, cov)


def _written_as_the_tool_documents(tool, path, w, h, f):
    """A calibration file of each tool, written here as its documentation describes it (not by selfcal), and its
    projection of normalised coordinates (corner pixel convention)."""
    if tool == "metashape":
        c = {"f": f, "cx": 12.5, "cy": -7.25, "b1": 3.0, "b2": -1.5, "k1": -0.03, "k2": 0.01, "k3": -0.002,
             "k4": 0.0, "p1": 2e-4, "p2": -1e-4}
        path.write_text("<calibration><projection>frame</projection>" + f"<width>{w}</width><height>{h}</height>"
                        + "".join(f"<{k}>{v!r}</{k}>" for k, v in c.items()) + "</calibration>")
        return lambda n: metashape_project(n, c, w, h)
    if tool == "opensfm":
        s = max(w, h)
        c = {"projection_type": "brown", "width": w, "height": h, "focal_x": f / s, "focal_y": 1.001 * f / s,
             "c_x": 0.002, "c_y": -0.001, "k1": -0.03, "k2": 0.01, "k3": -0.002, "p1": 2e-4, "p2": -1e-4}
        path.write_text(json.dumps({"v2 dji fc6310 5472 3648 brown 0.6666": c}))
        return lambda n: opensfm_project(n, c, w, h)
    if tool == "kalibr":
        cam = {"camera_model": "pinhole", "intrinsics": [f, 1.001 * f, w / 2 + 10.0, h / 2 - 5.0],
               "distortion_model": "radtan", "distortion_coeffs": [-0.03, 0.01, 2e-4, -1e-4], "resolution": [w, h],
               "rostopic": "/cam0/image_raw"}
        path.write_text(yaml.safe_dump({"cam0": cam}))
        return lambda n: kalibr_project(n, cam)
    K = np.array([[f, 0, w / 2 + 10.0], [0, 1.001 * f, h / 2 - 5.0], [0, 0, 1]])    # OpenCV's own writer
    dist = np.array([[-0.03, 0.01, 2e-4, -1e-4, -0.002]])
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", w)
    storage.write("image_height", h)
    storage.write("camera_matrix", K)
    storage.write("distortion_coefficients", dist)
    storage.release()

    def project(n):
        p, _ = cv2.projectPoints(np.column_stack([n, np.ones(len(n))]), np.zeros(3), np.zeros(3), K, dist)
        return p[:, 0] + 0.5
    return project


@pytest.mark.parametrize("tool,name", [("metashape", "cal.xml"), ("opensfm", "cameras.json"),
                                       ("kalibr", "camchain.yaml"), ("opencv", "cam.xml")])
def test_import_of_files_written_as_each_tool_documents(small_block, tmp_path, capsys, tool, name):
    """IN, truth first: a file written here as the tool documents it (affinity, skew, principal point off
    centre, radial and tangential terms) becomes a block camera that measures every ray where the tool's own
    projection puts it, within the brown fit's stated misfit."""
    path, camera, _ = small_block
    w, h = camera.width_px, camera.height_px
    project = _written_as_the_tool_documents(tool, tmp_path / name, w, h, camera.focal_mm / camera.pixel_size_mm)
    assert run_cli("import", "calibration", str(tmp_path / name), "--block", str(path),
                   "--out", str(tmp_path / "b2")) == 0
    err = capsys.readouterr().err
    stated = float(re.search(r"within ([\d.]+) px over the image", err).group(1))
    assert ("warning" in err) == (stated > 0.05)
    _, imported = block_calibration(tmp_path / "b2")
    u, v = np.meshgrid(np.linspace(0, w, 31), np.linspace(0, h, 31))
    measured = np.column_stack([u.ravel(), v.ravel()])
    miss = np.hypot(*(project(imported.normalised_from_measured(measured)) - measured).T)
    print(f"{tool}: brown fit stated {stated:.4f} px, measured {miss.max():.4f} px")
    # the stated misfit is the real one: 0.5-0.95 px here, a principal point 10-15 px off the frame centre
    # with 50 px of radial distortion (selfcal's Brown terms are centred on the frame)
    assert 0.9 * stated <= miss.max() <= stated + 1e-3 and stated < 1.0, (miss.max(), stated)
    # not a trivial pass: the pinhole part alone misses by pixels
    pinhole = replace(imported, coefficients_px=np.zeros_like(imported.coefficients_px))
    assert np.hypot(*(project(pinhole.normalised_from_measured(measured)) - measured).T).max() > 20


def lens_project(n, c):
    """The older PhotoScan / Agisoft Lens camera (Agisoft Lens user manual 0.4.0, "Camera model", as quoted on
    Agisoft's forum, topic 6437): x' = x(1 + K1 r^2 + K2 r^4 + K3 r^6) + P2 (r^2 + 2x^2) + 2 P1 x y,
    y' = y(1 + K1 r^2 + K2 r^4 + K3 r^6) + P1 (r^2 + 2y^2) + 2 P2 x y, u = cx + x' fx + y' skew, v = cy + y' fy."""
    x, y = n.T
    r2 = x**2 + y**2
    radial = 1 + c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3
    xs = x * radial + c["p2"] * (r2 + 2 * x**2) + 2 * c["p1"] * x * y
    ys = y * radial + c["p1"] * (r2 + 2 * y**2) + 2 * c["p2"] * x * y
    return np.column_stack([c["cx"] + xs * c["fx"] + ys * c["skew"], c["cy"] + ys * c["fy"]])


def test_old_photoscan_calibration_gives_the_camera_of_the_newer_file(small_block, tmp_path, capsys):
    """PhotoScan's older calibration XML (fx, fy, cx and cy of the principal point, skew, as Agisoft Lens wrote it)
    and the newer one of the same camera (f, cx, cy from the centre, b1, b2; converted here by Agisoft's own rule
    F = Fy, B1 = Fx - Fy, B2 = skew) project alike by their documented models, read as the same values (the
    covariance carried by J C J^T) and import as the same block camera."""
    from selfcal.io.calibration_files import read_calibration_file
    path, camera, _ = small_block
    w, h = camera.width_px, camera.height_px
    f = camera.focal_mm / camera.pixel_size_mm
    old = {"fx": f * 1.0004, "fy": f, "cx": w / 2 + 11.5, "cy": h / 2 - 6.25, "skew": -0.8, "k1": -0.03,
           "k2": 0.01, "k3": -0.002, "p1": 2e-4, "p2": -1e-4}
    new = {"f": old["fy"], "cx": old["cx"] - w / 2, "cy": old["cy"] - h / 2, "b1": old["fx"] - old["fy"],
           "b2": old["skew"], "k1": old["k1"], "k2": old["k2"], "k3": old["k3"], "k4": 0.0, "p1": old["p2"],
           "p2": old["p1"]}
    n = np.column_stack([g.ravel() for g in np.meshgrid(np.linspace(-0.4, 0.4, 9), np.linspace(-0.3, 0.3, 7))])
    np.testing.assert_allclose(lens_project(n, old), metashape_project(n, new, w, h), rtol=0, atol=1e-9)
    cov_old = np.diag([4.0, 1.0, 2.0, 3.0, 0.25])
    cov_old[0, 1] = cov_old[1, 0] = 1.5                                       # fx and fy correlated
    (tmp_path / "old.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<calibration>\n  <projection>frame</projection>\n'
        f"  <width>{w}</width>\n  <height>{h}</height>\n"
        + "".join(f"  <{k}>{v!r}</{k}>\n" for k, v in old.items())
        + "  <covariance>\n    <params>fx fy cx cy skew</params>\n"
        + f"    <coeffs>{' '.join(str(float(v)) for v in cov_old.ravel())}</coeffs>\n  </covariance>\n"
        + "  <date>2014-05-12T09:41:07Z</date>\n</calibration>\n")
    (tmp_path / "new.xml").write_text(
        "<calibration><projection>frame</projection>" + f"<width>{w}</width><height>{h}</height>"
        + "".join(f"<{k}>{v!r}</{k}>" for k, v in new.items()) + "</calibration>")
    read_old, read_new = read_calibration_file(tmp_path / "old.xml"), read_calibration_file(tmp_path / "new.xml")
    assert read_old.values == pytest.approx(read_new.values, rel=1e-15, abs=1e-12)
    assert read_old.covariance_names == ("f", "cx", "cy", "b1", "b2")
    # b1 = fx - fy: var 4 + 1 - 2 * 1.5; cov(f, b1) = cov(fy, fx) - var(fy) = 1.5 - 1
    assert read_old.covariance[3, 3] == pytest.approx(2.0) and read_old.covariance[0, 3] == pytest.approx(0.5)
    assert read_old.covariance[1, 1] == 2.0 and read_old.covariance[4, 4] == 0.25
    cameras = []
    for name in ("old", "new"):
        assert run_cli("import", "calibration", str(tmp_path / f"{name}.xml"), "--block", str(path),
                       "--out", str(tmp_path / f"b_{name}")) == 0
        cameras.append(block_calibration(tmp_path / f"b_{name}")[0])
    a, b = cameras
    assert (a.focal_mm, a.x0_mm, a.y0_mm) == pytest.approx((b.focal_mm, b.x0_mm, b.y0_mm), rel=1e-12)
    np.testing.assert_allclose(a.initial_ap.values_px, b.initial_ap.values_px, rtol=1e-9, atol=1e-9)
    assert a.initial_ap.names == b.initial_ap.names


# --- Kalibr: its camchain reader's checks, the model chosen from the lens ------------------------------------

class KalibrConfigError(RuntimeError):
    pass


def kalibr_read_camchain(path):
    """A re-implementation of Kalibr's camchain reader's checks (ethz-asl/kalibr,
    aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py): ParametersBase.readYaml
    (yaml.safe_load); CameraChainParameters.numCameras (len of the top-level map: every key is a camera),
    getCameraParameters (the key 'camN'), getCamOverlaps / checkCamOverlaps (a list of camera ids below
    numCameras), getExtrinsicsLastCamToHere (T_cn_cnm1, a 4 x 4 transformation, for camN with N >= 1);
    CameraParameters.getRosTopic / checkRosTopic (a str), getIntrinsics / checkIntrinsics (camera_model pinhole,
    omni or ds with 4, 5, 6 intrinsics; focal length and principal point floats, not negative),
    getDistortion / checkDistortion (radtan 4, equidistant 4, fov 1, none 0 coefficients), getResolution /
    checkResolution (two ints). A missing key is the reader's "Field ... missing" (its catch_keyerror).
    IccCameraChain (kalibr_imu_camera_calibration/IccSensors.py) reads rostopic of every camera to open the
    bag. Returns [(rostopic, camera_model, intrinsics, distortion_model, coeffs, resolution, overlaps)]."""
    with open(path) as handle:
        data = yaml.safe_load(handle)

    def field(entry, key):
        if key not in entry:
            raise KalibrConfigError(f"Field '{key}' missing in file: {path}")
        return entry[key]

    cameras = []
    count = len(data)
    for nr in range(count):
        cam = field(data, f"cam{nr}")
        topic = field(cam, "rostopic")
        if not isinstance(topic, str):
            raise KalibrConfigError("rostopic has to be a string")
        model, intrinsics = field(cam, "camera_model"), field(cam, "intrinsics")
        sizes = {"pinhole": 4, "omni": 5, "ds": 6}
        if model not in sizes:
            raise KalibrConfigError(f"Unknown camera model '{model}'")
        if len(intrinsics) != sizes[model]:
            raise KalibrConfigError(f"invalid intrinsics for {model}: {len(intrinsics)} parameters")
        focal, centre = intrinsics[-4:-2], intrinsics[-2:]
        if not all(isinstance(v, float) and v >= 0.0 for v in focal):
            raise KalibrConfigError("invalid focalLength (2 floats)")
        if not all(isinstance(v, float) and v >= 0.0 for v in centre):
            raise KalibrConfigError("invalid principalPoint")
        dist_model, coeffs = field(cam, "distortion_model"), field(cam, "distortion_coeffs")
        counts = {"radtan": 4, "equidistant": 4, "fov": 1, "none": 0}
        if dist_model not in counts:
            raise KalibrConfigError(f"Unknown distortion model '{dist_model}'")
        if len(coeffs) != counts[dist_model]:
            raise KalibrConfigError(f"distortion model '{dist_model}' requires {counts[dist_model]} coefficients")
        resolution = field(cam, "resolution")
        if len(resolution) != 2 or not all(isinstance(v, int) for v in resolution):
            raise KalibrConfigError("invalid resolution")
        overlaps = field(cam, "cam_overlaps")
        if any(i >= count for i in overlaps):
            raise KalibrConfigError("out-of-range: camera id")
        if nr >= 1 and np.asarray(field(cam, "T_cn_cnm1"), float).shape != (4, 4):
            raise KalibrConfigError(f"invalid camera baseline (cam{nr} in {path})")
        cameras.append((topic, model, intrinsics, dist_model, coeffs, resolution, overlaps))
    return cameras


def lens_line(err):
    return next(line for line in err.splitlines() if "chosen from the lens" in line)


FRAME_24MM = dict(width=5984, height=4000, pixel_mm=0.006, focal_mm=24.0)     # a 35.9 x 24 mm sensor


def fisheye_entry(corner_deg, w=1280, h=1024, pixel_mm=0.0048):
    """camera.json entry of a fisheye: a true equidistant lens (image height f theta, the image corner
    ``corner_deg`` off axis) as selfcal's Brown camera represents it (its least-squares fit)."""
    from selfcal.calibration_models import initial_from_model
    f = np.hypot(w / 2, h / 2) / np.radians(corner_deg)
    q = [f, f, w / 2 + 2.5, h / 2 - 2.5, -0.01, 0.002, 0.0, 0.0]
    ini = initial_from_model(MODELS["kalibr", "equidistant"], q, w, h, pixel_mm, "brown")
    return camera_entry(list(ini.ap_values_px), width=w, height=h, pixel_mm=pixel_mm, focal_mm=ini.focal_mm,
                        x0_mm=ini.x0_mm, y0_mm=ini.y0_mm)


def test_kalibr_camchain_passes_kalibrs_reader(brown, tmp_path, capsys):
    """Every key Kalibr's reader requires is written, with its types: rostopic (default and --rostopic),
    cam_overlaps [] for the one camera; the file written before this (no rostopic, no cam_overlaps) fails it."""
    folder, cal = brown
    out = tmp_path / "camchain.yaml"
    assert run_cli("export", "kalibr", str(folder), "--out", str(out)) == 0
    ((topic, model, intrinsics, dist_model, coeffs, resolution, overlaps),) = kalibr_read_camchain(out)
    assert (topic, model, resolution, overlaps) == ("/cam0/image_raw", "pinhole", [WIDTH, HEIGHT], [])
    assert dist_model == "radtan" and len(coeffs) == 4
    assert intrinsics[0] == pytest.approx(FOCAL_MM / PIXEL_MM, rel=1e-3)
    assert run_cli("export", "kalibr", str(folder), "--out", str(out), "--rostopic", "/left/image_raw") == 0
    assert kalibr_read_camchain(out)[0][0] == "/left/image_raw"
    capsys.readouterr()
    assert run_cli("export", "kalibr", str(folder), "--out", str(out), "--rostopic", "") == 2
    assert "--rostopic" in capsys.readouterr().err
    old = yaml.safe_load(out.read_text())
    del old["cam0"]["rostopic"], old["cam0"]["cam_overlaps"]
    out.write_text(yaml.safe_dump(old))
    with pytest.raises(KalibrConfigError, match="rostopic"):
        kalibr_read_camchain(out)


def export_kalibr(tmp_path, capsys, entry):
    """``selfcal export kalibr`` of a results folder holding ``entry``: (the lens line it prints, the field across
    the diagonal in deg, the printed rms and largest misfit in px, the camchain's camera, the largest miss of
    Kalibr's documented projection against selfcal's camera over a 41-node grid, px)."""
    folder = results_folder(tmp_path / "r", entry)
    cal = Calibration.from_camera_json(CAMERA_ID, entry)
    out = tmp_path / "camchain.yaml"
    assert run_cli("export", "kalibr", str(folder), "--out", str(out)) == 0
    err = capsys.readouterr().err
    line = lens_line(err)
    field = float(re.search(r"([\d.]+) deg across the diagonal", line).group(1))
    rms, worst = printed_misfit(err)
    (cam,) = yaml.safe_load(out.read_text()).values()
    assert kalibr_read_camchain(out)
    measured, n = grid(cal, 41)
    miss = np.hypot(*(kalibr_project(n, cam) - measured).T)
    return line, field, rms, worst, cam, float(miss.max()), folder, cal


@pytest.mark.parametrize("brown_px", [[-60.0, 8.0, -1.0, 1.0, -0.5, 0.2, 0.0],    # usual: radtan fits to 0.15 px
                                      [-60.0, 20.0, -8.0, 0.0, 0.0, 0.0, 0.0]])   # equidistant closer, still radtan
def test_a_24mm_frame_camera_is_exported_as_radtan(tmp_path, capsys, brown_px):
    """A 24 mm lens on a 35.9 x 24 mm sensor (85 deg across the diagonal) is a frame lens: radtan, also where
    its higher-order radial distortion makes equidistant's largest misfit the smaller (the issue's case: 'auto'
    took the closest model). The misfit is the one Kalibr's documented projection shows."""
    line, field, rms, worst, cam, miss, _, cal = export_kalibr(tmp_path, capsys, camera_entry(brown_px, **FRAME_24MM))
    assert "Kalibr radtan" in line and "a frame lens" in line and 84.0 < field < 86.0, line
    assert cam["distortion_model"] == "radtan"
    print(f"24 mm {brown_px}: radtan {rms:.4f} px rms, {worst:.4f} px max; measured {miss:.4f} px; {line}")
    assert miss <= worst + 1e-3
    if brown_px[1] == 8.0:
        assert worst < 0.2 and rms < 0.02                 # the usual lens: radtan reproduces selfcal's
    else:
        # the closest model was equidistant, which 'auto' used to take for this frame camera
        closer = fit_camera_model(cal, MODELS["kalibr", "equidistant"]).misfit_max_px
        print(f"  equidistant would miss by {closer:.4f} px")
        assert closer < 0.6 * worst and 0.3 < worst < 1.0


@pytest.mark.parametrize("corner_deg,by", [(62.0, "field"), (55.0, "misfit")])
def test_a_fisheye_is_exported_as_equidistant(tmp_path, capsys, corner_deg, by):
    """A fisheye (an equidistant lens 62 deg off axis at the corner: 125 deg across the diagonal) is exported as
    equidistant for its field; one of 111 deg, because radtan misses by far more than 1 px where equidistant
    does not. --model radtan still forces radtan."""
    line, field, _, worst, cam, miss, folder, _ = export_kalibr(tmp_path, capsys, fisheye_entry(corner_deg,
                                                                                                pixel_mm=0.0048))
    assert "Kalibr equidistant" in line and "a fisheye" in line, line
    assert cam["distortion_model"] == "equidistant"
    print(f"fisheye {corner_deg} deg: {field} deg field, equidistant {worst:.3f} px max; {line}")
    assert miss <= worst + 1e-3
    if by == "field":
        assert field > 120.0 and "radtan misses" not in line
    else:
        assert 105.0 < field < 120.0
        frame_px, fisheye_px = (float(v) for v in re.search(r"radtan misses selfcal's model by ([\d.]+) px.*"
                                                              r"equidistant by ([\d.]+) px", line).groups())
        assert frame_px > 5.0 and fisheye_px < 0.5 * frame_px and fisheye_px == pytest.approx(worst, abs=1e-3)
    out = tmp_path / "camchain.yaml"
    assert run_cli("export", "kalibr", str(folder), "--out", str(out), "--model", "radtan") == 0
    err = capsys.readouterr().err
    assert "chosen from the lens" not in err and yaml.safe_load(out.read_text())["cam0"]["distortion_model"] == \
        "radtan"


def test_kalibr_help_states_the_rule(capsys):
    with pytest.raises(SystemExit):
        run_cli("export", "kalibr", "--help")
    text = " ".join(capsys.readouterr().out.split())
    assert "chosen from the lens" in text and "120 deg" in text and "--rostopic" in text
