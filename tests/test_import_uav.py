"""Importers of the UAV tools' tie points and control: PAT-B, OpenSfM, Pix4D params/, Metashape markers.

Each test writes a simulated block in the tool's format AS THE TOOL DOCUMENTS IT (the writers here follow
the cited documentation, not selfcal's readers), imports it through ``selfcal import``, and recovers the
block's numbers: image measurements within 1e-6 px, orientations within 1e-6 m and 1e-9 rad, control exact,
sigmas as written.
"""
import csv
import os
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from selfcal.io import read_block
from selfcal.simulate import simulate_uav

from conftest import run_cli

PX_TOL = 1e-6
M_TOL = 1e-6
RAD_TOL = 1e-9


@pytest.fixture(scope="module")
def sim():
    """Six images (2 strips of 3), about 250 points per image, no distortion, 0.5 px noise."""
    return simulate_uav(seed=5, distortion="none", n_strips=2, images_per_strip=3, points_per_mm2=0.3)


def patb_rotation(omega, phi, kappa):
    """PAT-B's (and Pix4D's) image-to-object rotation R = Rx(omega) Ry(phi) Rz(kappa), active elementary
    rotations (Pix4D, "How are the internal and external camera parameters defined", PATB convention)."""
    co, so, cp, sp, ck, sk = np.cos(omega), np.sin(omega), np.cos(phi), np.sin(phi), np.cos(kappa), np.sin(kappa)
    rx = np.array([[1, 0, 0], [0, co, -so], [0, so, co]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[ck, -sk, 0], [sk, ck, 0], [0, 0, 1]])
    return rx @ ry @ rz


def observations_by_pair(block):
    ob = block.observations
    return {(block.images.image_id[i], block.points.point_id[p]): ob.pixel[k]
            for k, (i, p) in enumerate(zip(ob.image_index, ob.point_index))}


def assert_same_measurements(imported, truth_block, skip_points=()):
    got = observations_by_pair(imported)
    want = {k: v for k, v in observations_by_pair(truth_block).items() if k[1] not in skip_points}
    assert set(got) == set(want)
    diff = np.array([got[k] - want[k] for k in want])
    assert np.max(np.abs(diff)) < PX_TOL, np.max(np.abs(diff))


def assert_same_orientations(imported, sim):
    index = {i: k for k, i in enumerate(imported.images.image_id)}
    order = [index[i] for i in sim.truth.image_id]
    np.testing.assert_allclose(imported.images.position_m[order], sim.truth.eop[:, :3], rtol=0, atol=M_TOL)
    d = imported.images.attitude_rad[order] - sim.truth.eop[:, 3:]
    d = (d + np.pi) % (2 * np.pi) - np.pi
    assert np.max(np.abs(d)) < RAD_TOL, np.max(np.abs(d))


# ------------------------------------------------------------------------------------------------- PAT-B

def write_patb(folder, sim, stem="block", unit_mm=1.0):
    """PAT-B as Metashape exports it (Agisoft's "Export cameras in PAT-B format": x right, y up, mm; PCI's
    "Using Pat-B in OrthoEngine" for the .ori records): .im photo blocks closed by -99, .con closed by -99,
    .ori with three records per photo (centre; a11 a12 a13 a21 a22; a23 a31 a32 a33)."""
    block, cam = sim.blocks["type1"], sim.truth.camera
    p, w, h = cam.pixel_size_mm, cam.width_px, cam.height_px
    ob = block.observations
    with open(os.path.join(folder, stem + ".im"), "w") as f:
        for i, image in enumerate(block.images.image_id):
            f.write(f"{image:>12} {cam.focal_mm:12.6f}\n")
            for k in np.flatnonzero(ob.image_index == i):
                col, row = ob.pixel[k]
                x = (col - w / 2) * p - cam.x0_mm          # from the principal point, y up
                y = (h / 2 - row) * p - cam.y0_mm
                f.write(f"{block.points.point_id[ob.point_index[k]]:>10} {x / unit_mm:16.10f} {y / unit_mm:16.10f}\n")
            f.write("       -99\n")
    marks = np.flatnonzero(block.points.role != "tie")
    coords = np.round(block.points.xyz_m[marks], 3)
    with open(os.path.join(folder, stem + ".con"), "w") as f:
        for k, xyz in zip(marks, coords):
            f.write(f"{block.points.point_id[k]:>10} {xyz[0]:14.3f} {xyz[1]:14.3f} {xyz[2]:12.3f}\n")
        f.write("       -99\n")
    with open(os.path.join(folder, stem + ".ori"), "w") as f:
        for image, eop in zip(sim.truth.image_id, sim.truth.eop):
            a = patb_rotation(*eop[3:])
            f.write(f"{image:>16}{'':16}{eop[0]:16.7f}{eop[1]:16.7f}{eop[2]:16.7f}\n")
            f.write("".join(f"{v:16.12f}" for v in a.ravel()[:5]) + "\n")
            f.write("".join(f"{v:16.12f}" for v in a.ravel()[5:]) + "\n")
    return dict(zip(block.points.point_id[marks], coords))


def patb_argv(folder, out, *extra):
    return ["import", "patb", os.path.join(folder, "block.im"), "--image-size", "6000x4000", "--pixel-size-mm",
            "0.0059", "--principal-point-mm", "0.034,-0.021", "--out", out, *extra]


def test_patb_import_recovers_the_block(tmp_path, sim):
    src = tmp_path / "src"
    src.mkdir()
    control = write_patb(str(src), sim)
    out = str(tmp_path / "block")
    checks = ["M05", "M20"]
    assert run_cli(*patb_argv(str(src), out, "--check", ",".join(checks), "--gcp-sigma-xy", "0.0167",
                              "--gcp-sigma-z", "0.0289")) == 0
    block = read_block(out)
    assert_same_measurements(block, sim.blocks["type1"])
    assert_same_orientations(block, sim)
    cam = block.cameras["patb"]
    assert (cam.focal_mm, cam.x0_mm, cam.y0_mm, cam.pixel_size_mm) == (20.962, 0.034, -0.021, 0.0059)
    pts = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        k = pts[name]
        assert np.array_equal(block.points.xyz_m[k], xyz)                        # as written, to the mm
        assert block.points.role[k] == ("chk" if name in checks else "gcp")
        assert tuple(block.points.sigma_m[k]) == (0.0167, 0.0167, 0.0289)
    assert block.datum == "control"


def test_patb_in_microns(tmp_path, sim):
    src = tmp_path / "src"
    src.mkdir()
    write_patb(str(src), sim, unit_mm=0.001)
    out = str(tmp_path / "block")
    assert run_cli(*patb_argv(str(src), out, "--image-units", "um")) == 0
    assert_same_measurements(read_block(out), sim.blocks["type1"])


def test_patb_adjustment_recovers_the_truth(tmp_path, sim):
    """One adjustment of the imported block: focal length, orientations and points within 4 sigma of the truth."""
    src = tmp_path / "src"
    src.mkdir()
    write_patb(str(src), sim)
    block_dir, results = str(tmp_path / "block"), str(tmp_path / "results")
    assert run_cli(*patb_argv(str(src), block_dir, "--gcp-sigma-xy", "0.0167", "--gcp-sigma-z", "0.0289",
                              "--image-sigma-px", "0.5")) == 0
    assert run_cli("adjust", block_dir, "--out", results, "--ap", "none", "--no-report", "--quiet") == 0
    camera = read_json(os.path.join(results, "camera.json"))["cameras"]["patb"]
    cam = sim.truth.camera
    zc = [(camera[k]["value"] - getattr(cam, k)) / camera[k]["sigma"] for k in ("focal_mm", "x0_mm", "y0_mm")]
    print("interior orientation errors / sigma:", np.round(zc, 2))
    assert np.max(np.abs(zc)) < 4.0
    truth = {i: e for i, e in zip(sim.truth.image_id, sim.truth.eop)}
    z = []
    for row in read_rows(os.path.join(results, "images.csv")):
        e = truth[row["image_id"]]
        for key, k in (("X0", 0), ("Y0", 1), ("Z0", 2)):
            z.append((float(row[key]) - e[k]) / float(row[f"sigma_{key}_m"]))
        for key, k in (("omega", 3), ("phi", 4), ("kappa", 5)):
            z.append(np.radians(float(row[f"{key}_deg"]) - np.degrees(e[k])) / np.radians(float(row[f"sigma_{key}_deg"])))
    z = np.array(z)
    print("exterior orientation errors / sigma:", np.round(z, 2))
    assert np.max(np.abs(z)) < 4.0
    truth_xyz = dict(zip(sim.truth.point_id, sim.truth.xyz))
    zt = np.array([[(float(r[c]) - truth_xyz[r["point_id"]][k]) / float(r[f"sigma_{c}_m"]) for k, c in
                    enumerate(("X", "Y", "Z"))] for r in read_rows(os.path.join(results, "points.csv"))
                   if r["role"] == "tie"])
    rms = np.sqrt(np.mean(zt**2, axis=0))
    print(f"{len(zt)} tie points, errors / sigma: rms {np.round(rms, 3)}, largest {np.max(np.abs(zt)):.2f}")
    assert np.all(rms < 1.3) and np.max(np.abs(zt)) < 5.0


def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def read_json(path):
    import json
    with open(path) as f:
        return json.load(f)


# ------------------------------------------------------------------------------------------------ OpenSfM

def write_opensfm(folder, sim, camera_name="v2 sony ilce7m3 6000 4000 brown 0.8528"):
    """reconstruction.json and tracks.csv as OpenSfM documents them (doc/source/geometry.rst: world-to-camera
    angle-axis poses, camera x right, y down, z forward; normalized coordinates with the larger image side 1,
    pixel = normalized * max(w, h) + (w - 1) / 2 with the origin at the centre of the upper-left pixel; the
    brown camera's focal_x, focal_y, c_x, c_y normalized), tracks.csv v2 tab separated."""
    import json
    block, cam = sim.blocks["type1"], sim.truth.camera
    p, w, h = cam.pixel_size_mm, cam.width_px, cam.height_px
    s = max(w, h)
    flip = np.diag([1.0, -1.0, -1.0])           # photogrammetric camera (y up, looking along -z) -> OpenSfM's
    shots = {}
    for image, eop in zip(sim.truth.image_id, sim.truth.eop):
        r_cv = flip @ patb_rotation(*eop[3:]).T
        shots[str(image)] = {"rotation": list(Rotation.from_matrix(r_cv).as_rotvec()),
                             "translation": list(-r_cv @ eop[:3]), "camera": camera_name,
                             "orientation": 1, "capture_time": 0.0, "gps_dop": 999999.0}
    camera = {"projection_type": "brown", "width": w, "height": h, "focal_x": cam.focal_mm / p / s,
              "focal_y": cam.focal_mm / p / s, "c_x": cam.x0_mm / p / s, "c_y": -cam.y0_mm / p / s,
              "k1": 0.0, "k2": 0.0, "k3": 0.0, "p1": 0.0, "p2": 0.0}
    points = {str(pid): {"coordinates": list(xyz), "color": [128, 128, 128]}
              for pid, xyz in zip(sim.truth.point_id, sim.truth.xyz)}
    with open(os.path.join(folder, "reconstruction.json"), "w") as f:
        json.dump([{"cameras": {camera_name: camera}, "shots": shots, "points": points}], f)
    ob = block.observations
    with open(os.path.join(folder, "tracks.csv"), "w") as f:
        f.write("OPENSFM_TRACKS_VERSION_v2\n")
        for k in range(len(ob)):
            u, v = ob.pixel[k] - 0.5                   # OpenCV pixel coordinates: the first pixel's centre is 0
            xn, yn = (u - (w - 1) / 2) / s, (v - (h - 1) / 2) / s
            f.write(f"{block.images.image_id[ob.image_index[k]]}\t{block.points.point_id[ob.point_index[k]]}\t{k}\t"
                    f"{float(xn)!r}\t{float(yn)!r}\t0.004\t128\t128\t128\t-1\t-1\n")
        # a feature of a track the reconstruction does not hold: left out
        f.write(f"{block.images.image_id[0]}\tunreconstructed\t999999\t0.1\t0.1\t0.004\t1\t2\t3\t-1\t-1\n")


def test_opensfm_import_recovers_the_block(tmp_path, sim, capsys):
    src = tmp_path / "osfm"
    src.mkdir()
    write_opensfm(str(src), sim)
    out = str(tmp_path / "block")
    assert run_cli("import", "opensfm", str(src), "--pixel-size-mm", "0.0059", "--image-sigma-px", "0.5",
                   "--out", out) == 0
    assert "1 of" in capsys.readouterr().err
    block = read_block(out)
    assert_same_measurements(block, sim.blocks["type1"])
    assert_same_orientations(block, sim)
    (cam,) = block.cameras.values()
    assert cam.camera_id == "v2_sony_ilce7m3_6000_4000_brown_0_8528"
    assert cam.initial_ap is None
    np.testing.assert_allclose([cam.focal_mm, cam.x0_mm, cam.y0_mm], [20.962, 0.034, -0.021], rtol=0, atol=1e-12)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    truth = np.array([sim.truth.xyz[list(sim.truth.point_id).index(p)] for p in block.points.point_id])
    np.testing.assert_allclose(block.points.xyz_m, truth, rtol=0, atol=M_TOL)
    assert set(block.points.role) == {"tie"} and block.datum == "free" and index


def test_opensfm_distortion_becomes_initial_brown_values(tmp_path, sim):
    """A brown camera with distortion: its initial APs reproduce OpenSfM's own projection (the documented
    brown model) of the true points within 0.05 px."""
    import json
    src = tmp_path / "osfm"
    src.mkdir()
    write_opensfm(str(src), sim)
    path = os.path.join(src, "reconstruction.json")
    data = read_json(path)
    (camera,) = data[0]["cameras"].values()
    camera.update(k1=-0.01, k2=0.002, k3=0.0, p1=1e-4, p2=-5e-5)
    with open(path, "w") as f:
        json.dump(data, f)
    out = str(tmp_path / "block")
    assert run_cli("import", "opensfm", str(src), "--pixel-size-mm", "0.0059", "--out", out) == 0
    block = read_block(out)
    (cam,) = block.cameras.values()
    assert cam.initial_ap is not None and cam.initial_ap.spec == "brown"
    # OpenSfM's projection of a point (geometry.rst, "Brown Camera"), into selfcal's pixels
    from selfcal.ap import ImageFrame, create_ap
    from selfcal.sensors.frame import project
    s, w, h = 6000.0, 6000, 4000
    k = 2
    shot = data[0]["shots"][str(sim.truth.image_id[k])]
    r_cv = Rotation.from_rotvec(shot["rotation"]).as_matrix()
    seen = sim.blocks["type1"].observations.point_index[sim.blocks["type1"].observations.image_index == k]
    xyz = sim.truth.xyz[seen]                  # points inside image k's frame
    xc = xyz @ r_cv.T + shot["translation"]
    xn, yn = xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]
    r2 = xn**2 + yn**2
    c = camera
    dr = 1 + c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3
    u = c["focal_x"] * (dr * xn + 2 * c["p1"] * xn * yn + c["p2"] * (r2 + 2 * xn**2)) + c["c_x"]
    v = c["focal_y"] * (dr * yn + 2 * c["p2"] * xn * yn + c["p1"] * (r2 + 2 * yn**2)) + c["c_y"]
    want = np.column_stack([u * s + w / 2, v * s + h / 2])
    # selfcal: collinearity with the imported orientation plus the brown APs at their initial values
    eop = np.concatenate([block.images.position_m[k], block.images.attitude_rad[k]])
    iop = np.array([cam.focal_mm, cam.x0_mm, cam.y0_mm])
    xy = project(xyz, np.broadcast_to(eop, (len(xyz), 6)), iop)
    ap = create_ap("brown", ImageFrame(cam.width_mm, cam.height_mm, cam.pixel_size_mm))
    values = np.array([cam.initial_ap.values_px[cam.initial_ap.names.index(n)] for n in ap.parameter_names])
    measured = xy.copy()
    for _ in range(20):          # selfcal's Delta is a function of the measured position: observed = ideal + Delta
        bx, by = ap.basis(measured[:, 0], measured[:, 1])
        measured = xy + np.column_stack([bx @ values, by @ values]) * cam.pixel_size_mm
    got_col = measured[:, 0] / cam.pixel_size_mm + w / 2
    got_row = h / 2 - measured[:, 1] / cam.pixel_size_mm
    err = np.hypot(got_col - want[:, 0], got_row - want[:, 1])
    print("largest difference to OpenSfM's projection (px):", np.max(err))
    assert np.max(err) < 0.05, np.max(err)


# ------------------------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("fmt, name, edit, line, reason", [
    ("patb", "block.im", lambda t: t[:t.rindex("       -99")], None, "not closed by -99: a truncated file?"),
    ("patb", "block.im", lambda t: t.replace("       -99\n", "", 1), None, "or -99 to close photo 'S1_01'"),
    ("patb", "block.im", lambda t: t.replace(t.splitlines()[1], t.splitlines()[1].rsplit(" ", 1)[0], 1), 2,
     "expected 'point_id x y'"),
    ("patb", "block.im", lambda t: t.replace(t.splitlines()[2].split()[1], "1.2.3", 1), 3, "'1.2.3' is not a number"),
    ("patb", "block.ori", lambda t: t.replace("S1_02", "NOPE", 1), 4, "photo 'NOPE' has no image measurements"),
    ("patb", "block.ori", lambda t: "\n".join(t.splitlines()[:-1]) + "\n", 17, "has 2 of its 3 records"),
    ("patb", "block.con", lambda t: t.replace("-99", ""), None, "not closed by -99"),
    ("opensfm", "tracks.csv", lambda t: t.replace("\t", "\tx", 4), 2, "is not a number"),
])
def test_bad_input_names_file_line_and_reason(tmp_path, sim, capsys, fmt, name, edit, line, reason):
    src = tmp_path / "src"
    src.mkdir()
    if fmt == "patb":
        write_patb(str(src), sim)
        argv = patb_argv(str(src), str(tmp_path / "out"))
    else:
        write_opensfm(str(src), sim)
        argv = ["import", "opensfm", str(src), "--out", str(tmp_path / "out")]
    path = os.path.join(src, name)
    with open(path) as f:
        text = f.read()
    with open(path, "w") as f:
        f.write(edit(text))
    assert run_cli(*argv) == 2
    err = capsys.readouterr().err
    assert name in err and reason in err, err
    if line is not None:
        assert f"line {line}" in err, err
    assert not os.path.exists(tmp_path / "out")


# -------------------------------------------------------------------------------------------------- Pix4D

def write_pix4d(folder, sim, project="proj", bingo_label=str, gcp_label=str, northing_first=False, end_marker=True):
    """A Pix4D params folder as Pix4D documents it: the BINGO file ("What is the bingo file": mm from the image
    centre, one block per image closed by -99; with ``end_marker`` False as that article's example shows it,
    ``P1060498 H_8.07_6.0525`` headers, blocks apart by a blank line, no -99), the .cam (F, Px, Py in mm, Px/Py from the sensor's upper-left
    corner, the sensor size in the comment), the external parameters (imageName X Y Z Omega Phi Kappa, degrees,
    PATB convention) and the calibrated camera parameters (fileName imageWidth imageHeight, K, ...), and a GCP
    file in PIX4D's import format (label, X, Y, Z, horizontal accuracy, vertical accuracy).

    ``bingo_label``, ``gcp_label``: the label of a marked point (gcp, chk) in the BINGO and the GCP file;
    ``northing_first``: the GCP file in the order label, Y, X, Z (a survey file in northing, easting order)."""
    block, cam = sim.blocks["type1"], sim.truth.camera
    p, w, h = cam.pixel_size_mm, cam.width_px, cam.height_px
    params = os.path.join(folder, "1_initial", "params")
    os.makedirs(params)
    ob = block.observations
    with open(os.path.join(params, f"{project}_tp_bingo.txt"), "w") as f:
        for i, image in enumerate(block.images.image_id):
            f.write(f"{image} ilce7m3_20.96_35.4\n")
            for k in np.flatnonzero(ob.image_index == i):
                col, row = ob.pixel[k]
                pid = block.points.point_id[ob.point_index[k]]
                if block.points.role[ob.point_index[k]] != "tie":
                    pid = bingo_label(pid)
                f.write(f"{pid} {(col - w / 2) * p:.10f} {(h / 2 - row) * p:.10f}\n")
            f.write("-99\n\n" if end_marker else "\n")
    with open(os.path.join(params, f"{project}_pix4d_calibrated_internal_camera_parameters.cam"), "w") as f:
        f.write(f"Pix4D camera calibration file 0\n#Focal Length mm assuming a sensor width of {w * p:g}x{h * p:g}mm\n"
                f"F {cam.focal_mm}\n#Principal Point mm\nPx {w * p / 2 + cam.x0_mm}\nPy {h * p / 2 - cam.y0_mm}\n"
                "#Symmetrical Lens Distortion Coeffs\nK1 0\nK2 0\nK3 0\n#Tangential Lens Distortion Coeffs\n"
                "T1 0\nT2 0\n")
    with open(os.path.join(params, f"{project}_calibrated_external_camera_parameters.txt"), "w") as f:
        f.write("imageName X Y Z Omega Phi Kappa\n")
        for image, eop in zip(sim.truth.image_id, sim.truth.eop):
            f.write(f"{image}.JPG {eop[0]:.8f} {eop[1]:.8f} {eop[2]:.8f} "      # BINGO: without the extension
                    + " ".join(f"{np.degrees(a):.12f}" for a in eop[3:])
                    + "\n")
    with open(os.path.join(params, f"{project}_calibrated_camera_parameters.txt"), "w") as f:
        f.write("fileName imageWidth imageHeight\ncamera matrix K [3x3]\nradial distortion [3x1]\n"
                "tangential distortion [2x1]\ncamera position t [3x1]\ncamera rotation R [3x3]\n"
                "camera model m = K [R|-Rt] X\n\n")
        fpx = cam.focal_mm / p
        for image, eop in zip(sim.truth.image_id, sim.truth.eop):
            r = patb_rotation(*eop[3:]).T
            f.write(f"{image}.JPG {w} {h}\n{fpx} 0 {w / 2 + cam.x0_mm / p}\n0 {fpx} {h / 2 - cam.y0_mm / p}\n0 0 1\n"
                    f"0 0 0\n0 0\n{eop[0]} {eop[1]} {eop[2]}\n" + "\n".join(" ".join(map(str, row)) for row in r) + "\n")
    marks = np.flatnonzero(block.points.role != "tie")
    coords = np.round(block.points.xyz_m[marks], 3)
    gcp = os.path.join(folder, "gcp.csv")
    with open(gcp, "w") as f:
        for k, xyz in zip(marks, coords):
            first, second = (xyz[1], xyz[0]) if northing_first else (xyz[0], xyz[1])
            f.write(f"{gcp_label(block.points.point_id[k])},{first:.3f},{second:.3f},{xyz[2]:.3f},0.0167,0.0289\n")
    return dict(zip(block.points.point_id[marks], coords)), gcp


def test_pix4d_import_recovers_the_block(tmp_path, sim):
    control, gcp = write_pix4d(str(tmp_path / "project"), sim)
    out = str(tmp_path / "block")
    assert run_cli("import", "pix4d", str(tmp_path / "project"), "--gcp", gcp, "--check", "M07", "--out", out) == 0
    block = read_block(out)
    assert_same_measurements(block, sim.blocks["type1"])
    assert_same_orientations(block, sim)
    cam = block.cameras["pix4d"]
    np.testing.assert_allclose([cam.focal_mm, cam.x0_mm, cam.y0_mm, cam.pixel_size_mm], [20.962, 0.034, -0.021, 0.0059],
                               rtol=0, atol=1e-12)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        k = index[name]
        assert np.array_equal(block.points.xyz_m[k], xyz)
        assert tuple(block.points.sigma_m[k]) == (0.0167, 0.0167, 0.0289)
        assert block.points.role[k] == ("chk" if name == "M07" else "gcp")


def test_pix4d_bingo_without_end_markers_reads_as_with_them(tmp_path, sim):
    """The BINGO layout of Pix4D's own example ("What is the bingo file": header ``image camera``, then ``point x
    y`` records, no -99) and the closed one (-99 after each block) give the same block."""
    blocks = []
    for end_marker in (True, False):
        project = tmp_path / f"project{int(end_marker)}"
        _, gcp = write_pix4d(str(project), sim, end_marker=end_marker)
        bingo = (project / "1_initial" / "params" / "proj_tp_bingo.txt").read_text()
        assert ("-99" in bingo) == end_marker
        out = str(tmp_path / f"block{int(end_marker)}")
        assert run_cli("import", "pix4d", str(project), "--gcp", gcp, "--out", out) == 0
        blocks.append(read_block(out))
        assert_same_measurements(blocks[-1], sim.blocks["type1"])
    closed, open_ = blocks
    assert list(closed.images.image_id) == list(open_.images.image_id)
    assert list(closed.points.point_id) == list(open_.points.point_id)
    np.testing.assert_array_equal(closed.observations.pixel, open_.observations.pixel)


@pytest.mark.parametrize("edit, line, reason", [
    (lambda t: t.replace("\n", "\nM99 1.5\n", 2).replace("\nM99 1.5\n", "\n", 1), 3,
     "expected 'point_id x y' (or a header 'image camera' after photo 'S1_01'), found 2 field(s)"),
    (lambda t: "1006 -1.9 1.8\n" + t, 1, "a 'point_id x y' record before the first image header"),
    (lambda t: t.replace("\n", "\nM98 x 1.5\n", 1), 2, "x: 'x' is not a number"),
])
def test_pix4d_bingo_without_end_markers_bad_input(tmp_path, sim, capsys, edit, line, reason):
    write_pix4d(str(tmp_path / "project"), sim, end_marker=False)
    path = tmp_path / "project" / "1_initial" / "params" / "proj_tp_bingo.txt"
    path.write_text(edit(path.read_text()))
    assert run_cli("import", "pix4d", str(tmp_path / "project"), "--out", str(tmp_path / "out")) == 2
    err = capsys.readouterr().err
    assert "proj_tp_bingo.txt" in err and reason in err and f"line {line}" in err, err


def write_gcps_position(params, control, layout):
    """A params folder's ``*_measured_gcps_position.txt`` in the layouts public Pix4D exports show (Pix4D does not
    document the columns): ``hash`` (``#Label,X/East,Y/North,Z/Altitude,Accuracy_(m),Error_(m),X_error,Y_error,
    Z_error,X_est,Y_est,Z_est``, a quoted label, an empty accuracy) and ``named`` (``GCP label, GCP measured X, ...``
    separated by ``, ``, horizontal and vertical accuracies, then the estimated position). The error and estimated
    columns hold other numbers: a reader taking them would fail. Returns the sigma per point (NaN: none given)."""
    sigma = {}
    with open(os.path.join(params, "proj_measured_gcps_position.txt"), "w") as f:
        if layout == "hash":
            f.write("#Label,X/East,Y/North,Z/Altitude,Accuracy_(m),Error_(m),X_error,Y_error,Z_error,X_est,Y_est,"
                    "Z_est\n")
            for k, (name, xyz) in enumerate(control.items()):
                accuracy = "" if k % 2 else "0.015"
                sigma[name] = (np.nan,) * 3 if k % 2 else (0.015,) * 3
                label = f'"{name}"' if k % 3 == 0 else name
                f.write(f"{label},{xyz[0]:.3f},{xyz[1]:.3f},{xyz[2]:.3f},{accuracy},0.027775,-0.019520,-0.006123,"
                        f"0.018786,{xyz[0] + 0.7:.3f},{xyz[1] - 0.4:.3f},{xyz[2] + 0.3:.3f}\n")
        else:
            f.write("GCP label, GCP measured X, GCP measured Y, GCP measured Z, Accuracy Horz, Accuracy Vert, "
                    "GCP estimated X, GCP estimated Y, GCP estimated Z\n")
            for name, xyz in control.items():
                sigma[name] = (0.012, 0.012, 0.021)
                f.write(f"{name}, {xyz[0]:.3f}, {xyz[1]:.3f}, {xyz[2]:.3f}, 0.012, 0.021, {xyz[0] + 0.7:.3f}, "
                        f"{xyz[1] - 0.4:.3f}, {xyz[2] + 0.3:.3f}\n")
    return sigma


@pytest.mark.parametrize("layout", ["hash", "named"])
def test_pix4d_measured_gcps_position_is_the_control(tmp_path, sim, capsys, layout):
    """Without --gcp, the params folder's *_measured_gcps_position.txt is the control: coordinates as written
    (not the estimated ones beside them), sigmas as written, the default where the accuracy is empty; --gcp still
    wins over it, and says so."""
    control, gcp = write_pix4d(str(tmp_path / "project"), sim)
    params = str(tmp_path / "project" / "1_initial" / "params")
    sigma = write_gcps_position(params, control, layout)
    out = str(tmp_path / "block")
    assert run_cli("import", "pix4d", str(tmp_path / "project"), "--check", "M07", "--out", out) == 0
    assert "proj_measured_gcps_position.txt" in capsys.readouterr().err
    block = read_block(out)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    assert set(control) <= set(index)
    for name, xyz in control.items():
        k = index[name]
        assert np.array_equal(block.points.xyz_m[k], xyz)
        want = (0.01, 0.01, 0.02) if np.isnan(sigma[name][0]) else sigma[name]          # the import's default
        assert tuple(block.points.sigma_m[k]) == want
        assert block.points.role[k] == ("chk" if name == "M07" else "gcp")
    out2 = str(tmp_path / "block2")
    assert run_cli("import", "pix4d", str(tmp_path / "project"), "--gcp", gcp, "--out", out2) == 0
    assert "(--gcp), not from" in capsys.readouterr().err
    k = list(read_block(out2).points.point_id).index(next(iter(control)))
    assert tuple(read_block(out2).points.sigma_m[k]) == (0.0167, 0.0167, 0.0289)             # the --gcp file's


@pytest.mark.parametrize("edit, line, reason", [
    (lambda t: t.replace("Z/Altitude", "Height_est"), 1, "the header names no z column"),
    (lambda t: t.replace(",0.015,", ",-0.015,", 1), 2, "Accuracy_(m) must be positive"),
    (lambda t: t.replace("\n", "\n" + t.splitlines()[1].replace(",", ",x", 1) + "\n", 1), 2, "X/East: 'x"),
])
def test_pix4d_measured_gcps_position_bad_input(tmp_path, sim, capsys, edit, line, reason):
    control, _ = write_pix4d(str(tmp_path / "project"), sim)
    params = tmp_path / "project" / "1_initial" / "params"
    write_gcps_position(str(params), control, "hash")
    path = params / "proj_measured_gcps_position.txt"
    path.write_text(edit(path.read_text()))
    assert run_cli("import", "pix4d", str(tmp_path / "project"), "--out", str(tmp_path / "out")) == 2
    err = capsys.readouterr().err
    assert "proj_measured_gcps_position.txt" in err and reason in err and f"line {line}" in err, err
    assert not os.path.exists(tmp_path / "out")


# ------------------------------------------------------------------------------------------ Metashape markers

def write_markers(folder, sim, disabled="M03", ref_label=str, northing_first=False):
    """Metashape's markers XML (chunk layout: <cameras>, <markers> with <reference>, and the projections in
    <frames><frame><markers><marker marker_id><location camera_id x y/>, pixels with the image centre at
    (w/2, h/2)) and a reference CSV (label, X, Y, Z, X/Y/Z accuracy); ``ref_label``: a marker's label in the CSV,
    ``northing_first``: the CSV in the order label, Y, X, Z."""
    block = sim.blocks["type1"]
    ob = block.observations
    marks = np.flatnonzero(block.points.role != "tie")
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<document version="1.2.0">', '  <chunk label="Chunk 1">',
             "    <cameras>"]
    lines += [f'      <camera id="{i}" sensor_id="0" label="{image}"/>' for i, image in enumerate(block.images.image_id)]
    lines += ["    </cameras>", "    <markers>"]
    coords = np.round(block.points.xyz_m[marks], 3)
    for j, (k, xyz) in enumerate(zip(marks, coords)):
        label = block.points.point_id[k]
        enabled = "false" if label == disabled else "true"
        lines += [f'      <marker id="{j}" label="{label}">',
                  f'        <reference x="{xyz[0]:.3f}" y="{xyz[1]:.3f}" z="{xyz[2]:.3f}" enabled="{enabled}"/>',
                  "      </marker>"]
    lines += ["    </markers>", "    <frames>", '      <frame id="0">', "        <markers>"]
    for j, k in enumerate(marks):
        lines.append(f'          <marker marker_id="{j}">')
        for o in np.flatnonzero(ob.point_index == k):
            x, y = ob.pixel[o]
            lines.append(f'            <location camera_id="{ob.image_index[o]}" pinned="true" x="{float(x)!r}" '
                         f'y="{float(y)!r}"/>')
        lines.append("          </marker>")
    lines += ["        </markers>", "      </frame>", "    </frames>", "  </chunk>", "</document>", ""]
    xml = os.path.join(folder, "markers.xml")
    with open(xml, "w") as f:
        f.write("\n".join(lines))
    ref = os.path.join(folder, "reference.csv")
    with open(ref, "w") as f:
        f.write("# Label,X,Y,Z,X_acc,Y_acc,Z_acc\n")
        for k, xyz in zip(marks[:20], coords[:20]):        # the others keep the XML's reference
            first, second = (xyz[1], xyz[0]) if northing_first else (xyz[0], xyz[1])
            f.write(f"{ref_label(block.points.point_id[k])},{first:.3f},{second:.3f},{xyz[2]:.3f},0.012,0.012,0.025\n")
    return dict(zip(block.points.point_id[marks], coords)), xml, ref, set(block.points.point_id[marks[:20]])


@pytest.fixture
def tie_block(tmp_path, sim):
    """The simulated block without its marks (a free network of tie points)."""
    from dataclasses import replace
    from selfcal.block import Observations
    from selfcal.io.block_folder import write_block
    block = sim.blocks["type1"]
    ties = np.flatnonzero(block.points.role == "tie")
    new_index = np.full(len(block.points), -1)
    new_index[ties] = np.arange(len(ties))
    keep = new_index[block.observations.point_index] >= 0
    ob = block.observations
    obs = Observations(ob.image_index[keep], new_index[ob.point_index[keep]], ob.pixel[keep], ob.sigma_px[keep],
                       np.arange(1, keep.sum() + 1))
    folder = str(tmp_path / "ties")
    write_block(replace(block, points=block.points.take(ties), observations=obs, datum="free"), folder)
    return folder


def test_metashape_markers_add_control_to_a_block(tmp_path, sim, tie_block):
    control, xml, ref, in_csv = write_markers(str(tmp_path), sim)
    out = str(tmp_path / "with_markers")
    assert run_cli("import", "metashape-markers", xml, "--block", tie_block, "--reference", ref, "--check", "M10",
                   "--gcp-sigma-xy", "0.0167", "--gcp-sigma-z", "0.0289", "--out", out) == 0
    block = read_block(out)
    assert_same_measurements(block, sim.blocks["type1"])           # tie points as before, markers to 1e-6 px
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        k = index[name]
        assert np.array_equal(block.points.xyz_m[k], xyz)
        want = (0.012, 0.012, 0.025) if name in in_csv else (0.0167, 0.0167, 0.0289)
        assert tuple(block.points.sigma_m[k]) == want, name
        assert block.points.role[k] == ("chk" if name in ("M03", "M10") else "gcp"), name
    assert block.datum == "control"
    assert not os.path.exists(os.path.join(tie_block, "points.csv.tmp"))


@pytest.mark.parametrize("edit, snippet, reason", [
    (lambda t: t.replace('label="S1_02"', 'label="OTHER"'), '<location camera_id="1"',
     "camera 'OTHER' is not an image of the block"),
    (lambda t: t.replace('camera_id="1" pinned', 'camera_id="77" pinned', 1), 'camera_id="77"',
     "camera id 77 is not among"),
    (lambda t: t.replace(' x="', ' x="abc', 1), ' x="abc', "'abc"),
])
def test_metashape_markers_bad_input(tmp_path, sim, tie_block, capsys, edit, snippet, reason):
    """The error names the file, the line of the offending element and the reason."""
    import re
    _, xml, ref, _ = write_markers(str(tmp_path), sim)
    with open(xml) as f:
        text = edit(f.read())
    with open(xml, "w") as f:
        f.write(text)
    out = str(tmp_path / "out")
    assert run_cli("import", "metashape-markers", xml, "--block", tie_block, "--reference", ref, "--out", out) == 2
    err = capsys.readouterr().err
    assert "markers.xml" in err and reason in err, err
    line = int(re.search(r"line (\d+)", err).group(1))
    assert snippet in text.splitlines()[line - 1], (line, err)
    assert not os.path.exists(out)


def test_metashape_markers_need_a_block(tmp_path, sim, capsys):
    _, xml, ref, _ = write_markers(str(tmp_path), sim)
    assert run_cli("import", "metashape-markers", xml, "--out", str(tmp_path / "out")) == 2
    assert "--block" in capsys.readouterr().err


@pytest.mark.parametrize("name, edit, line, reason", [
    ("proj_tp_bingo.txt", lambda t: t[:t.rindex("-99")], None, "not closed by -99"),
    ("proj_calibrated_external_camera_parameters.txt", lambda t: t.replace("S2_01.JPG ", "S9_99.JPG ", 1), 5,
     "photo 'S9_99.JPG' has no image measurements"),
    ("proj_calibrated_external_camera_parameters.txt", lambda t: t.replace("\nS1_01.JPG ", "\nS1_01.JPG x", 1), 2,
     "X: 'x"),
    ("proj_pix4d_calibrated_internal_camera_parameters.cam", lambda t: t.replace("F 20.962", "F twenty"), 3,
     "F: 'twenty' is not a number"),
])
def test_pix4d_bad_input(tmp_path, sim, capsys, name, edit, line, reason):
    write_pix4d(str(tmp_path / "project"), sim)
    path = os.path.join(tmp_path, "project", "1_initial", "params", name)
    with open(path) as f:
        text = f.read()
    with open(path, "w") as f:
        f.write(edit(text))
    out = str(tmp_path / "out")
    assert run_cli("import", "pix4d", str(tmp_path / "project" / "1_initial" / "params"), "--out", out) == 2
    err = capsys.readouterr().err
    assert name in err and reason in err, err
    if line is not None:
        assert f"line {line}" in err, err
    assert not os.path.exists(out)


def pix4d_distorted(col, row, f_px, cx, cy, d, y_down=True):
    """Pixels of Pix4D's documented lens model ("How are the internal and external camera parameters defined")
    at the ideal pixels (col, row): on the homogeneous point (x_h, y_h), x_d = x_h (1 + R1 r^2 + R2 r^4 + R3 r^6)
    + 2 T1 x_h y_h + T2 (r^2 + 2 x_h^2), y_d = y_h (...) + T1 (r^2 + 2 y_h^2) + 2 T2 x_h y_h, pixel = f x_d + c;
    with ``y_down`` False, y_h taken upwards (the reading selfcal rejects)."""
    s = 1.0 if y_down else -1.0
    xh, yh = (col - cx) / f_px, s * (row - cy) / f_px
    r2 = xh**2 + yh**2
    radial = 1 + d["K1"] * r2 + d["K2"] * r2**2 + d["K3"] * r2**3
    xd = xh * radial + 2 * d["T1"] * xh * yh + d["T2"] * (r2 + 2 * xh**2)
    yd = yh * radial + d["T1"] * (r2 + 2 * yh**2) + 2 * d["T2"] * xh * yh
    return np.column_stack([f_px * xd + cx, s * f_px * yd + cy])


@pytest.mark.parametrize("distortion", [
    {"K1": -0.012, "K2": 0.003, "K3": -0.0004, "T1": 0.0, "T2": 0.0},
    {"K1": -0.012, "K2": 0.003, "K3": -0.0004, "T1": 0.0006, "T2": -0.0009},
    {"K1": 0.0, "K2": 0.0, "K3": 0.0, "T1": -0.0011, "T2": 0.0004}], ids=["radial", "radial+tangential", "tangential"])
def test_pix4d_distortion_becomes_initial_brown_values(tmp_path, sim, capsys, distortion):
    """R1..R3, T1, T2 of the .cam: the initial brown APs reproduce Pix4D's documented model (OpenCV's, x right, y
    down, T1, T2 as p1, p2) over the image within the misfit the import states (brown's terms are taken at the
    measured point, OpenCV's at the ideal one: the radial and tangential parts cross), at most 0.05 px for each
    part alone and 0.2 px for both at 42 px of distortion; with y taken upwards the tangential part would be off
    by more than 1 px (the test tells the two readings apart)."""
    write_pix4d(str(tmp_path / "project"), sim)
    cam_file = os.path.join(tmp_path, "project", "1_initial", "params",
                            "proj_pix4d_calibrated_internal_camera_parameters.cam")
    with open(cam_file) as f:
        text = f.read()
    for key, value in distortion.items():
        text = text.replace(f"{key} 0\n", f"{key} {value}\n")
    with open(cam_file, "w") as f:
        f.write(text)
    out = str(tmp_path / "block")
    assert run_cli("import", "pix4d", str(tmp_path / "project"), "--out", out) == 0
    note = capsys.readouterr().err
    assert "not carried over" not in note
    misfit = float(re.search(r"largest misfit of the conversion ([0-9.]+) px", note).group(1))
    cam = read_block(out).cameras["pix4d"]
    assert cam.initial_ap is not None and cam.initial_ap.spec == "brown"
    from selfcal.ap import ImageFrame, create_ap
    truth = sim.truth.camera
    p, w, h = truth.pixel_size_mm, truth.width_px, truth.height_px
    f_px, cx, cy = truth.focal_mm / p, w / 2 + truth.x0_mm / p, h / 2 - truth.y0_mm / p
    col, row = (g.ravel() for g in np.meshgrid(np.linspace(100, w - 100, 25), np.linspace(100, h - 100, 17)))
    want = pix4d_distorted(col, row, f_px, cx, cy, distortion)
    ideal_mm = np.column_stack([(col - w / 2) * p, (h / 2 - row) * p])
    ap = create_ap("brown", ImageFrame(cam.width_mm, cam.height_mm, cam.pixel_size_mm))
    values = np.array([cam.initial_ap.values_px[cam.initial_ap.names.index(n)] for n in ap.parameter_names])
    measured = ideal_mm.copy()
    for _ in range(30):
        bx, by = ap.basis(measured[:, 0], measured[:, 1])
        measured = ideal_mm + np.column_stack([bx @ values, by @ values]) * p
    got = np.column_stack([measured[:, 0] / p + w / 2, h / 2 - measured[:, 1] / p])
    err = np.hypot(*(got - want).T)
    other = np.hypot(*(got - pix4d_distorted(col, row, f_px, cx, cy, distortion, y_down=False)).T)
    print(f"largest difference to Pix4D's model: {np.max(err):.4f} px; to the y-up reading {np.max(other):.2f} px "
          f"(distortion up to {np.max(np.hypot(*(want - np.column_stack([col, row])).T)):.1f} px)")
    assert np.max(err) <= misfit + 0.005
    assert np.max(err) < (0.2 if distortion["T1"] and distortion["K1"] else 0.05)
    if distortion["T1"] or distortion["T2"]:
        assert np.max(other) > 1.0


# ------------------------------------------------------------------- control of real files (issue 39, item 5)
# A 581-image DJI P1 block exported by Pix4D: the survey file says GCP05 where BINGO says GCP_GCP05, and a survey
# file in northing, easting order was read as X = northing. Labels are joined after the normalisations a real
# pair of files needs (and the import says which); control that lies swapped against the cameras is refused.

#: a projected CRS's easting and northing of the block (TWD97 / TM2 in Taiwan: northings far above eastings)
EAST, NORTH = 251000.0, 2690000.0


@pytest.fixture(scope="module")
def geo_sim(sim):
    """``sim`` moved to EAST, NORTH: a block whose cameras know where they are (Pix4D's external parameters)."""
    from dataclasses import replace
    from types import SimpleNamespace
    d = np.array([EAST, NORTH, 0.0])
    block = sim.blocks["type1"]
    block = replace(block, crs="EPSG:3826", points=replace(block.points, xyz_m=block.points.xyz_m + d),
                    images=replace(block.images, position_m=block.images.position_m + d))
    eop = sim.truth.eop.copy()
    eop[:, :3] += d
    return SimpleNamespace(blocks={"type1": block}, truth=replace(sim.truth, eop=eop, xyz=sim.truth.xyz + d))


def pix4d_import(tmp_path, sim, *extra, **labels):
    """(exit code, stderr, block folder) of ``selfcal import pix4d`` of ``sim`` written by write_pix4d."""
    control, gcp = write_pix4d(str(tmp_path / "project"), sim, **labels)
    out = str(tmp_path / "block")
    return control, gcp, out, ["import", "pix4d", str(tmp_path / "project"), "--gcp", gcp, "--out", out, *extra]


def renamed_truth(sim, name):
    """The simulated block with its marked points renamed by ``name`` (what the import should give)."""
    from dataclasses import replace
    block = sim.blocks["type1"]
    ids = np.array([name(p) if r != "tie" else p for p, r in zip(block.points.point_id, block.points.role)], object)
    return replace(block, points=replace(block.points, point_id=ids))


def test_pix4d_control_labels_with_a_prefix_of_bingo(tmp_path, sim, capsys):
    """The user's files: GCP05 in the survey file, GCP_GCP05 in BINGO. The import joins them after removing the
    prefix BINGO adds (found from the labels, not from a list), says so, and keeps the survey's labels."""
    control, gcp, out, argv = pix4d_import(tmp_path, sim, "--check", "GCP_GCP07",
                                           gcp_label=lambda p: "GCP" + p[1:], bingo_label=lambda p: "GCP_GCP" + p[1:])
    assert run_cli(*argv) == 0
    err = capsys.readouterr().err
    n = len(control)
    assert (f"warning: control labels matched after removing the prefix 'GCP_' of proj_tp_bingo.txt's labels "
            f"(gcp.csv to proj_tp_bingo.txt): {n} of {n} (GCP01 = GCP_GCP01, GCP02 = GCP_GCP02, GCP03 = GCP_GCP03, "
            f"...)") in err, err
    block = read_block(out)
    assert_same_measurements(block, renamed_truth(sim, lambda p: "GCP" + p[1:]))
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        k = index["GCP" + name[1:]]
        assert np.array_equal(block.points.xyz_m[k], xyz)
        assert block.points.role[k] == ("chk" if name == "M07" else "gcp")      # --check by BINGO's label
    assert not any(p.startswith("GCP_") for p in block.points.point_id)


def test_pix4d_control_labels_in_other_case_and_without_leading_zeros(tmp_path, sim, capsys):
    """gcp7 in the survey file, M07 in BINGO: joined ignoring case and leading zeros (one message per rule that
    was needed, with its count)."""
    control, gcp, out, argv = pix4d_import(tmp_path, sim, gcp_label=lambda p: "m" + str(int(p[1:])))
    assert run_cli(*argv) == 0
    err = capsys.readouterr().err
    n = len(control)
    small = sum(int(p[1:]) < 10 for p in control)
    assert (f"warning: control labels matched ignoring case and leading zeros (gcp.csv to proj_tp_bingo.txt): "
            f"{small} of {n} (m1 = M01, m2 = M02, m3 = M03, ...)") in err, err
    assert (f"warning: control labels matched ignoring case (gcp.csv to proj_tp_bingo.txt): {n - small} of {n} "
            f"(m10 = M10, m11 = M11, m12 = M12, ...)") in err, err
    block = read_block(out)
    assert_same_measurements(block, renamed_truth(sim, lambda p: "m" + str(int(p[1:]))))
    assert int(np.sum(block.points.role == "gcp")) == n                     # every surveyed point is control


def test_pix4d_control_labels_that_match_nothing(tmp_path, sim, capsys):
    """GPC05 in BINGO for the survey's GCP05 (a typo in the project): no normalisation joins them. Exit 2 naming
    the GCP file, the count of labels on each side and, for a few control labels, the nearest BINGO labels;
    nothing is written."""
    control, gcp, out, argv = pix4d_import(tmp_path, sim, gcp_label=lambda p: "GCP" + p[1:],
                                           bingo_label=lambda p: "GPC" + p[1:])
    assert run_cli(*argv) == 2
    err = capsys.readouterr().err
    n_bingo = len(set(sim.blocks["type1"].points.point_id[sim.blocks["type1"].observations.point_index]))
    assert f"{gcp}: none of its {len(control)} control labels matches one of the {n_bingo} labels of " \
           f"proj_tp_bingo.txt" in err, err
    assert "'GCP01' (nearest there: 'GPC01'" in err and "'GCP02' (nearest there: 'GPC02'" in err, err
    assert f"and {len(control) - 5} more" in err and "Rename the labels" in err, err
    assert "usable gcp" not in err and not os.path.exists(out)


def test_pix4d_control_labels_partly_matched(tmp_path, sim, capsys):
    """A typo in the project (MO5 for M05) and a surveyed point that Pix4D did not measure: the import goes on and
    names both (with the nearest BINGO labels); the others are joined as before, MO5 is a tie point."""
    typo = {"M05": "MO5"}
    control, gcp, out, argv = pix4d_import(tmp_path, sim, bingo_label=lambda p: typo.get(p, p))
    with open(gcp, "a") as f:
        f.write("BM-Church,5.000,6.000,7.000\n")
    assert run_cli(*argv) == 0
    err = capsys.readouterr().err
    assert (f"warning: 2 of the {len(control) + 1} control labels of gcp.csv match nothing in proj_tp_bingo.txt: "
            f"'M05' (nearest there: 'MO5'), 'BM-Church' (nothing alike there)") in err, err
    block = read_block(out)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    assert "M05" not in index and "BM-Church" not in index     # no image measurement: not a usable gcp
    assert block.points.role[index["MO5"]] == "tie"
    assert_same_measurements(block, renamed_truth(sim, lambda p: typo.get(p, p)))


def test_pix4d_control_in_northing_easting_order(tmp_path, geo_sim, capsys):
    """The survey file in northing, easting order: exit 2 before anything is written, naming the file, the columns
    and the distances from the cameras in either order (before: exit 0, and the adjustment stopped on a point
    "1.26e+06 m from the block's centre")."""
    control, gcp, out, argv = pix4d_import(tmp_path, geo_sim, "--crs", "EPSG:3826", northing_first=True)
    assert run_cli(*argv) == 2
    err = capsys.readouterr().err
    assert f"{gcp}: the control points' X and Y look swapped (the file in northing, easting order?): as given " \
           f"they lie " in err, err
    import re
    far, size, near = (float(v) for v in re.search(r"they lie (\S+) m from the 6 camera positions \(the median "
                                                    r"distance from their extent, (\S+) m across\), with X and Y "
                                                    r"swapped (\S+) m\.", err).groups())
    assert far == pytest.approx(np.sqrt(2) * (NORTH - EAST), rel=0.01)   # the mirror image across X = Y
    cams = geo_sim.truth.eop[:, :3]              # the block's size: its diagonal, or the cameras' height if larger
    height = np.median(cams[:, 2]) - np.median(np.array(list(control.values()))[:, 2])
    assert size == pytest.approx(max(np.hypot(*np.ptp(cams[:, :2], axis=0)), height), rel=0.01) and near < size
    with open(gcp) as f:
        label, x, y = f.readline().split(",")[:3]
    assert f"selfcal reads X as the easting and Y as the northing; swap the two columns (point '{label}', line 1: " \
           f"X {x}, Y {y})" in err, err
    assert not os.path.exists(out)


def test_pix4d_control_in_easting_northing_order_imports_as_before(tmp_path, geo_sim, capsys):
    """The same files in the right order: exit 0, no warning, the numbers exactly as written."""
    control, gcp, out, argv = pix4d_import(tmp_path, geo_sim, "--crs", "EPSG:3826")
    assert run_cli(*argv) == 0
    assert "warning" not in capsys.readouterr().err
    block = read_block(out)
    assert_same_measurements(block, geo_sim.blocks["type1"])
    assert_same_orientations(block, geo_sim)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        assert np.array_equal(block.points.xyz_m[index[name]], xyz)


def test_metashape_reference_labels_with_a_prefix_of_their_own(tmp_path, sim, tie_block, capsys):
    """A survey CSV that names marker M05 'CP_M05': joined after removing the prefix the CSV adds (the CSV's
    coordinates and accuracies are the markers'), said in a warning; the points keep the survey's labels."""
    control, xml, ref, in_csv = write_markers(str(tmp_path), sim, ref_label=lambda p: "CP_" + p)
    out = str(tmp_path / "with_markers")
    assert run_cli("import", "metashape-markers", xml, "--block", tie_block, "--reference", ref, "--check", "M10",
                   "--out", out) == 0
    err = capsys.readouterr().err
    assert (f"warning: control labels matched after removing the prefix 'CP_' of reference.csv's labels "
            f"(reference.csv to markers.xml): {len(in_csv)} of {len(in_csv)} (CP_M01 = M01, CP_M02 = M02, "
            f"CP_M03 = M03, ...)") in err, err
    block = read_block(out)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        k = index["CP_" + name if name in in_csv else name]
        assert np.array_equal(block.points.xyz_m[k], xyz)
        assert tuple(block.points.sigma_m[k]) == ((0.012, 0.012, 0.025) if name in in_csv else (0.01, 0.01, 0.02))
        assert block.points.role[k] == ("chk" if name in ("M03", "M10") else "gcp"), name
    assert_same_measurements(block, renamed_truth(sim, lambda p: "CP_" + p if p in in_csv else p))


def test_metashape_reference_that_matches_no_marker(tmp_path, sim, tie_block, capsys):
    _, xml, ref, in_csv = write_markers(str(tmp_path), sim, ref_label=lambda p: "Target " + p[1:])
    out = str(tmp_path / "out")
    assert run_cli("import", "metashape-markers", xml, "--block", tie_block, "--reference", ref, "--out", out) == 2
    err = capsys.readouterr().err
    n_markers = int(np.sum(sim.blocks["type1"].points.role != "tie"))
    assert f"{ref}: none of its {len(in_csv)} control labels matches one of the {n_markers} labels of markers.xml" \
           in err, err
    assert "'Target 01' (nothing alike there)" in err and "the labels of markers.xml: 'M01', 'M02'" in err, err
    assert not os.path.exists(out)


@pytest.fixture
def positioned_block(tmp_path, geo_sim):
    """geo_sim's images with their GNSS positions ([gnss]) and tie points only: a block that knows where it is."""
    from dataclasses import replace
    from selfcal.io.block_folder import write_block
    block = geo_sim.blocks["type1"]
    ties = np.flatnonzero(block.points.role == "tie")
    new_index = np.full(len(block.points), -1)
    new_index[ties] = np.arange(len(ties))
    keep = new_index[block.observations.point_index] >= 0
    ob = block.observations
    from selfcal.block import Observations
    obs = Observations(ob.image_index[keep], new_index[ob.point_index[keep]], ob.pixel[keep], ob.sigma_px[keep],
                       np.arange(1, keep.sum() + 1))
    folder = str(tmp_path / "positioned")
    write_block(replace(block, points=block.points.take(ties), observations=obs, gnss_sigma_m=(0.05, 0.05, 0.1)),
                folder)
    return folder


def test_metashape_reference_in_northing_easting_order(tmp_path, geo_sim, positioned_block, capsys):
    """The reference CSV in northing, easting order against a block with camera GNSS: exit 2 naming the CSV;
    in the right order the markers import with the CSV's numbers."""
    _, xml, ref, _ = write_markers(str(tmp_path), geo_sim, northing_first=True)
    out = str(tmp_path / "out")
    argv = ["import", "metashape-markers", xml, "--block", positioned_block, "--reference", ref, "--out", out]
    assert run_cli(*argv) == 2
    err = capsys.readouterr().err
    assert f"{ref}: the control points' X and Y look swapped (the file in northing, easting order?): as given they " \
           f"lie 3.45e+06 m from the 6 camera positions" in err, err
    assert not os.path.exists(out)
    control, xml, ref, in_csv = write_markers(str(tmp_path), geo_sim)
    assert run_cli(*argv) == 0
    assert "warning" not in capsys.readouterr().err
    block = read_block(out)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        assert np.array_equal(block.points.xyz_m[index[name]], xyz)


def test_metashape_markers_on_a_free_network_say_nothing_of_axes(tmp_path, sim, tie_block):
    """A free network has no position of its own: control in any order is imported (its datum is the control)."""
    _, xml, ref, _ = write_markers(str(tmp_path), sim, northing_first=True)
    assert run_cli("import", "metashape-markers", xml, "--block", tie_block, "--reference", ref, "--out",
                   str(tmp_path / "out")) == 0


def test_patb_control_in_northing_easting_order(tmp_path, geo_sim, capsys):
    """PAT-B's .con in northing, easting order against the .ori's perspective centres: exit 2 naming the .con."""
    src = tmp_path / "src"
    src.mkdir()
    write_patb(str(src), geo_sim)
    con = os.path.join(src, "block.con")
    with open(con) as f:
        lines = f.read().splitlines()
    with open(con, "w") as f:
        for line in lines:
            t = line.split()
            f.write(f"{t[0]:>10} {t[2]:>14} {t[1]:>14} {t[3]:>12}\n" if len(t) == 4 else line + "\n")
    out = str(tmp_path / "block")
    assert run_cli(*patb_argv(str(src), out, "--crs", "EPSG:3826")) == 2
    err = capsys.readouterr().err
    assert f"{con}: the control points' X and Y look swapped (the file in northing, easting order?)" in err, err
    assert not os.path.exists(out)


def test_patb_control_labels_in_lower_case(tmp_path, sim, capsys):
    """A .con written by another program in lower case: joined to the .im's labels, said, numbers as written."""
    src = tmp_path / "src"
    src.mkdir()
    control = write_patb(str(src), sim)
    con = os.path.join(src, "block.con")
    with open(con) as f:
        text = f.read()
    with open(con, "w") as f:
        f.write(text.replace(" M", " m"))
    out = str(tmp_path / "block")
    assert run_cli(*patb_argv(str(src), out, "--check", "M05")) == 0
    err = capsys.readouterr().err
    n = len(control)
    assert f"warning: control labels matched ignoring case (block.con to block.im): {n} of {n} (m01 = M01, " \
           f"m02 = M02, m03 = M03, ...)" in err, err
    block = read_block(out)
    index = {p: k for k, p in enumerate(block.points.point_id)}
    for name, xyz in control.items():
        k = index["m" + name[1:]]
        assert np.array_equal(block.points.xyz_m[k], xyz)
        assert block.points.role[k] == ("chk" if name == "M05" else "gcp")
    assert_same_measurements(block, renamed_truth(sim, lambda p: "m" + p[1:]))


def test_adjust_refuses_control_swapped_against_the_images_before_any_work(tmp_path, geo_sim, capsys, monkeypatch):
    """A block folder whose points.csv holds northing, easting against the images.csv positions: selfcal adjust
    exits 2 naming points.csv before any adjustment (the AP model choice and the tested adjustment are never
    called); the same block with the columns in order passes the check."""
    from dataclasses import replace
    from selfcal.convert.control import block_control_swapped
    from selfcal.io.block_folder import write_block
    import selfcal.workflows.adjust as workflow

    def never(*args, **kwargs):
        raise AssertionError("an adjustment started")
    monkeypatch.setattr(workflow, "adjust_with_tests", never)
    monkeypatch.setattr(workflow, "choose_ap_model", never)
    block = geo_sim.blocks["type1"]
    assert block_control_swapped(block) is None
    xyz = block.points.xyz_m.copy()
    marked = block.points.role != "tie"
    xyz[marked] = xyz[marked][:, [1, 0, 2]]
    folder, results = str(tmp_path / "swapped"), str(tmp_path / "results")
    write_block(replace(block, points=replace(block.points, xyz_m=xyz)), folder)
    assert run_cli("adjust", folder, "--out", results, "--ap", "auto:none,brown", "--no-report", "--quiet") == 2
    err = capsys.readouterr().err
    assert "points.csv: the control points' X and Y look swapped (the file in northing, easting order?): as given " \
           "they lie 3.45e+06 m from the 6 camera positions" in err, err
    assert "point 'M01', line 2: X 2689945.424" in err, err
    assert not os.path.exists(results)


def test_patb_without_control_is_a_free_network_with_its_warning(tmp_path, sim, capsys):
    """PAT-B without a .con (tie points and orientations only) is imported as a free network with a warning that
    says what that costs; its adjustment recovers the truth within its (relative) sigmas: the principal distance,
    which only the relief holds, within 3 sigma, the photos' centres within 3 sigma. Without a .ori as well, the
    warning says the adjustment cannot start, and adjust says so too (exit 1)."""
    src = tmp_path / "src"
    src.mkdir()
    write_patb(str(src), sim)
    os.remove(src / "block.con")
    block_dir, results = str(tmp_path / "block"), str(tmp_path / "results")
    assert run_cli(*patb_argv(str(src), block_dir, "--image-sigma-px", "0.5")) == 0
    err = capsys.readouterr().err
    assert "warning: no control (no .con): the block is a free network" in err
    assert "no check point measures the accuracy" in err
    block = read_block(block_dir)
    assert block.datum == "free" and set(block.points.role) == {"tie"}
    assert_same_measurements(block, sim.blocks["type1"])              # the control points measured as tie points
    assert run_cli("adjust", block_dir, "--out", results, "--ap", "none", "--no-report", "--quiet") == 0
    focal = read_json(os.path.join(results, "camera.json"))["cameras"]["patb"]["focal_mm"]
    z_focal = (focal["value"] - sim.truth.camera.focal_mm) / focal["sigma"]
    truth = {i: e for i, e in zip(sim.truth.image_id, sim.truth.eop)}
    z = np.array([(float(row[key]) - truth[row["image_id"]][k]) / float(row[f"sigma_{key}_m"])
                  for row in read_rows(os.path.join(results, "images.csv"))
                  for k, key in enumerate(("X0", "Y0", "Z0"))])
    measured = (f"free PAT-B network: focal {focal['value']:.3f} +- {focal['sigma']:.3f} mm (truth "
                f"{sim.truth.camera.focal_mm}), error / sigma {z_focal:.2f}; centres' largest error / sigma "
                f"{np.max(np.abs(z)):.2f}")
    assert abs(z_focal) < 3.0 and np.max(np.abs(z)) < 3.0, measured
    os.remove(src / "block.ori")
    assert run_cli(*patb_argv(str(src), str(tmp_path / "bare"))) == 0
    assert "no orientations (no .ori): the block is a free network the adjustment cannot start" in capsys.readouterr().err
    assert run_cli("adjust", str(tmp_path / "bare"), "--out", str(tmp_path / "r2"), "--no-report", "--quiet") == 1
    assert "cannot orient image(s)" in capsys.readouterr().err
    print(measured)                                                   # after the last capsys read: it shows with -s
