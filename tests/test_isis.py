"""ISIS control networks, cube labels and the Apollo 15 Metric frame ISDs, against ISIS's own numbers
(../shared/data/isis: the networks and cubes of ISIS's jigsaw tests; EXPECTED_VALUES.txt: jigsaw's published
results, transcribed from isis/tests/FunctionalTestsJigsaw.cpp)."""
import dataclasses
import json
import os
import shutil

import numpy as np
import pytest

from selfcal.errors import BlockError
from selfcal.geometry.body import covariance_from_sigmas, sigmas_from_covariance
from selfcal.geometry.rotation import quaternion_from_matrix
from selfcal.io.isis import match_serials, read_control_network, read_cube_label, read_image_folder
from selfcal.io.pvl import parse_pvl
from selfcal.io.usgscsm_frame import read_frame_isd
from selfcal.sensors import usgscsm_frame as F
from selfcal.sensors.frame import project

from conftest import SHARED_DATA

APOLLO = os.path.join(SHARED_DATA, "isis", "apollo15_metric")
NAC = os.path.join(SHARED_DATA, "isis", "lro_nac_pair")
NET = os.path.join(APOLLO, "apolloNet.pvl")


def setup_module():
    assert os.path.isdir(APOLLO) and os.path.isdir(NAC), f"shared test data missing: {APOLLO}, {NAC}"


@pytest.fixture(scope="module")
def apollo():
    """(network, {serial: FrameIsd}, {cube number: serial}) of the Apollo block."""
    net = read_control_network(NET)
    images = read_image_folder(APOLLO)
    isds = {s: read_frame_isd(isd, label.alpha_cube) for s, (label, isd) in images.items()}
    cube = {int(os.path.basename(label.path)[len("apolloImage"):-len(".pvl")]): s for s, (label, _) in images.items()}
    return net, isds, cube


# --- networks --------------------------------------------------------------------------------------

def test_apollo_network_counts(apollo):
    net = apollo[0]
    counts = net.counts()
    assert counts["points"] == 395 and counts["measures"] == 969
    assert counts["points_by_type"] == {"Free": 363, "Constrained": 32}
    assert counts["measures_by_type"] == {"RegisteredPixel": 903, "Manual": 66}
    assert counts["ignored_points"] == counts["ignored_measures"] == counts["measures_of_ignored_points"] == 0
    assert net.network_id == "LandingSite" and net.target_name == "Moon" and net.version == 5


def test_nac_network_counts_and_serials():
    net = read_control_network(os.path.join(NAC, "observationPair.net"))
    counts = net.counts()
    assert counts["points"] == 46 and counts["measures"] == 92
    assert counts["points_by_type"] == {"Fixed": 2, "Free": 44}
    assert counts["measures_by_type"] == {"RegisteredSubPixel": 40, "Candidate": 28, "RegisteredPixel": 24}
    images = read_image_folder(NAC)                         # the PDS original label beside them is passed over
    assert sorted(images) == ["LRO/1/269182000:51104/NACL", "LRO/1/269182000:51104/NACR"]
    assert set(match_serials(net, [label for label, _ in images.values()])) == set(images)
    fixed = [p for p in net.points if p.point_type == "Fixed"]
    assert all(p.apriori_xyz_m is not None for p in fixed)
    assert all(p.apriori_xyz_m is None for p in net.points if p.point_type == "Free")


def test_measures_are_converted_to_corner_pixels_once(apollo):
    m = apollo[0].points[0].measures[0]                     # AS15_000031172, first measure (file line 34)
    assert (m.point_id, m.sample, m.line) == ("AS15_000031172", 4803.1346854703, 4530.858132006)
    assert (m.col_px, m.row_px) == (4803.1346854703 - 0.5, 4530.858132006 - 0.5)
    assert (m.sample_residual_px, m.line_residual_px) == (0.51918067263978, -0.49757745590614)
    assert m.source_line == 34 and m.measure_type == "RegisteredPixel"


def test_every_measure_maps_to_exactly_one_image(apollo):
    net, isds, cube = apollo
    images = read_image_folder(APOLLO)
    assert len(images) == 7                                  # apolloNet.pvl itself is no cube label
    used = match_serials(net, [label for label, _ in images.values()])
    assert set(used) == set(images)
    assert cube[1] == "APOLLO15/METRIC/1971-07-31T14:00:53.547"    # SpacecraftName -> APOLLO15, StartTime as written
    per_image = {s: sum(m.serial_number == s for m in net.measures) for s in images}
    assert sum(per_image.values()) == 969 and min(per_image.values()) == 9


def test_apriori_covariance_is_body_fixed_m2_of_the_stated_sigmas(apollo):
    """AprioriCovarianceMatrix turned into north/east/radial gives back the sigmas ISIS writes in the comment
    above it: 300/300/500 m for the 32 Constrained points; 299.93270116266/244.17167723289/500 m for
    AS15_SocetPAN_45 (a Free point that carries a covariance, which jigsaw does not use)."""
    net = apollo[0]
    with_cov = [p for p in net.points if p.apriori_covariance_m2 is not None]
    assert len(with_cov) == 33
    for p in with_cov:
        sigmas = sigmas_from_covariance(p.apriori_xyz_m, p.apriori_covariance_m2)
        if p.point_id == "AS15_SocetPAN_45":
            assert p.point_type == "Free"
            np.testing.assert_allclose(sigmas, [299.93270116266, 244.17167723289, 500.0], atol=1e-6)
        else:
            assert p.point_type == "Constrained" and p.constrained == (True, True, True)
            np.testing.assert_allclose(sigmas, [300.0, 300.0, 500.0], atol=1e-6)
            np.testing.assert_allclose(covariance_from_sigmas(p.apriori_xyz_m, 300.0, 300.0, 500.0),
                                       p.apriori_covariance_m2, rtol=0, atol=1e-5)


# --- the frame camera --------------------------------------------------------------------------------

SPOT_MEASURES = [  # point, cube, x, y (mm), sample, line (px): EXPECTED_VALUES.txt
    ("AS15_000031448", 1, -24.91466695, -8.24555721, 4109.77150653, 2450.19288272),
    ("AS15_000032200", 2, -25.59176653, -10.57595228, 4143.71597937, 2333.56318790),
    ("AS15_000055094", 1, 20.35945995, 34.23830209, 1844.18431849, 4576.36730130),
    ("AS15_test01", 3, -5.04180938, -34.53366096, 3115.51026031, 1134.42313078),
]


def test_spot_checked_measures_reach_isis_focal_plane(apollo):
    """Sample/line -> ISIS's undistorted focal plane (x, y) as jigsaw writes it in residuals.csv: agreement
    to the 8 printed decimals (measured: 5e-9 mm at most)."""
    net, isds, cube = apollo
    for point_id, k, x, y, sample, line in SPOT_MEASURES:
        m = next(m for p in net.points if p.point_id == point_id for m in p.measures if m.serial_number == cube[k])
        assert abs(m.sample - sample) < 1e-8 and abs(m.line - line) < 1e-8
        u, v = F.undistort(isds[cube[k]], *F.focal_plane_from_pixel(isds[cube[k]], m.col_px, m.row_px))
        assert abs(u - x) < 1e-8 and abs(v - y) < 1e-8, (point_id, u - x, v - y)


def test_initial_orientation_is_jigsaws(apollo):
    """Position (J2000 km) and RA/DEC/TWIST of every cube as jigsaw reports their initial values."""
    expected = {1: (774.31325994618, 1070.7396447319, 1281.8228287147, 143.75643505897, 46.120746428714,
                    -168.38036906625),
                6: (657.49557080071, 1126.2181683192, 1301.3147739155, 118.21104209923, 53.317384096946,
                    -150.28440526839),
                7: (489.97204152251, 1197.7389611966, 1313.3186725115, 159.32459434907, 84.419718861554,
                    -178.65839562226)}
    isds, cube = apollo[1], apollo[2]
    for k, (x, y, z, ra, dec, twist) in expected.items():
        isd = isds[cube[k]]
        np.testing.assert_allclose(isd.positions_m[0] / 1000.0, [x, y, z], rtol=0, atol=1e-9)
        np.testing.assert_allclose(F.isis_angles_deg(isd), [ra, dec, twist], rtol=0, atol=1e-9)
        # the camera looks at the Moon along -z (ISIS's flipped focal plane)
        nadir = -F.sensor_position_m(isd) / np.linalg.norm(F.sensor_position_m(isd))
        assert F.camera_from_body(isd)[2] @ nadir < -0.7


def test_round_trips_of_every_measure(apollo):
    """pixel -> ground (sphere through the point's a-priori radius) -> pixel within 1e-6 px for all 969
    measures (measured: 6e-12 px), and point -> pixel -> ground within 1e-6 m; distort inverts undistort."""
    net, isds, _ = apollo
    points = {p.point_id: p for p in net.points}
    for serial, isd in isds.items():
        ms = [m for m in net.measures if m.serial_number == serial]
        col, row = np.array([m.col_px for m in ms]), np.array([m.row_px for m in ms])
        X = np.array([points[m.point_id].apriori_xyz_m for m in ms])
        radius = np.linalg.norm(X, axis=1)
        c2, r2 = F.ground_to_image(isd, F.image_to_ground(isd, col, row, radius))
        assert np.abs(c2 - col).max() < 1e-6 and np.abs(r2 - row).max() < 1e-6
        c3, r3 = F.ground_to_image(isd, X)
        assert np.abs(F.image_to_ground(isd, c3, r3, radius) - X).max() < 1e-6
        x, y = F.focal_plane_from_pixel(isd, col, row)
        xd, yd = F.distort(isd, *F.undistort(isd, x, y))
        assert np.abs(xd - x).max() < 1e-11 and np.abs(yd - y).max() < 1e-11
    corners = F.image_to_ground(isds[apollo[2][1]], [0.0, 5725.0], [0.0, 5725.0])
    assert np.allclose(np.linalg.norm(corners, axis=1), 1737400.0)       # the ISD's sphere by default


def test_pixel_convention_against_isis_detector(apollo):
    """Cube sample S (1-based centre) is detector sample 4 (S - 0.5) + 0.5; ISIS's detector origin is
    AlphaSamples / 2 = 11450, so the photo origin (the cube's centre) sits at focal (-0.0025, +0.0025) mm."""
    isd = apollo[1][apollo[2][1]]
    s, l = F.detector_from_pixel(isd, 4109.77150653 - 0.5, 2450.19288272 - 0.5)
    assert abs(s - (4 * (4109.77150653 - 0.5) + 0.5)) < 1e-9 and abs(l - (4 * (2450.19288272 - 0.5) + 0.5)) < 1e-9
    form = F.frame_form(isd)
    np.testing.assert_allclose(form.focal_offset_mm, [-0.0025, 0.0025], atol=1e-12)
    np.testing.assert_allclose(form.focal_from_photo, -np.eye(2), atol=1e-15)
    assert form.pixel_size_mm == pytest.approx(0.02) and (form.width_px, form.height_px) == (5725, 5725)
    np.testing.assert_allclose([form.x0_mm, form.y0_mm], [0.0035, 0.0045], atol=1e-12)
    col, row = F.pixel_from_detector(isd, s, l)
    assert abs(col - (4109.77150653 - 0.5)) < 1e-9 and abs(row - (2450.19288272 - 0.5)) < 1e-9


def test_frame_form_projects_to_isis_undistorted_focal_plane(apollo):
    """selfcal's collinearity (frame.project) with frame_form's orientation gives ISIS's undistorted focal
    plane point in selfcal's photo axes, within 1e-9 mm (measured: 1e-13 mm), for every measured point; and
    a measured pixel's ideal photo point is what the projection of its ground point gives."""
    net, isds, _ = apollo
    points = {p.point_id: p for p in net.points}
    for serial, isd in isds.items():
        ms = [m for m in net.measures if m.serial_number == serial]
        X = np.array([points[m.point_id].apriori_xyz_m for m in ms])
        form = F.frame_form(isd)
        xy = project(X, np.tile(form.eop, (len(X), 1)), form.iop)
        u, v = F.ground_to_focal_plane(isd, X)
        J = form.focal_from_photo
        expected = np.stack([form.x0_mm + J[0, 0] * u + J[1, 0] * v, form.y0_mm + J[0, 1] * u + J[1, 1] * v], -1)
        assert np.abs(xy - expected).max() < 1e-9
        col, row = np.array([m.col_px for m in ms]), np.array([m.row_px for m in ms])
        ground = F.image_to_ground(isd, col, row, np.linalg.norm(X, axis=1))
        ideal = np.stack(F.ideal_photo_from_pixel(isd, form, col, row), -1)
        assert np.abs(project(ground, np.tile(form.eop, (len(X), 1)), form.iop) - ideal).max() < 1e-9
        # observed photo coordinates are selfcal's of the cube pixel: their focal point is ISIS's distorted one
        xo, yo = (col - 5725 / 2) * 0.02, (5725 / 2 - row) * 0.02
        fx, fy = F.focal_plane_from_photo(form, xo, yo)
        x, y = F.focal_plane_from_pixel(isd, col, row)
        assert np.abs(fx - x).max() < 1e-12 and np.abs(fy - y).max() < 1e-12


JIGSAW_FINAL = {  # cube: X, Y, Z (J2000 km), RA, DEC, TWIST (deg) after jigsaw, EXPECTED_VALUES.txt
    1: (774.98193589261, 1069.639424051, 1281.3643301551, 144.30776829552, 46.296886759887, -168.85535726521),
    2: (808.10303308435, 1051.4866026087, 1275.873186198, 142.67053795553, 46.562507234484, -167.714326645),
    3: (840.9318076291, 1032.8578207434, 1269.8307652154, 141.02790666672, 46.829440856056, -166.60682206061),
    4: (873.38416544245, 1013.7994434139, 1263.2547390718, 139.42550448412, 47.133801561495, -165.53709453981),
    5: (905.51743768036, 994.29256938313, 1256.1112112196, 137.83041748346, 47.476798808429, -164.47181097169),
    6: (658.11826370693, 1126.2965500357, 1301.5109517672, 119.17252815033, 53.180942309077, -150.8974268085),
    7: (490.3678051648, 1197.1333191769, 1313.2366581846, 159.96947727074, 84.676266037343, -178.93105692564),
}
SPOT_POINTS = {  # point: residual RMS (px), adjusted X, Y, Z (km), EXPECTED_VALUES.txt
    "AS15_000031957": (0.33, (1573.65050943, 169.59077243, 712.98695596)),
    "AS15_000055107": (2.22, (1570.96622187, 186.17020493, 713.15150243)),
    "AS15_Tie14": (0.76, (1590.02287614, 125.90958874, 688.23852695)),
    "AS15_SocetPAN_01": (0.27, (1536.92627520, 58.76110229, 804.58132250)),
    "AS15_SocetPAN_10": (1.14, (1557.52735013, 96.42556502, 759.96089165)),
    "AS15_SocetPAN_40": (0.42, (1562.04594097, 51.29735448, 754.68811810)),
}


def _with_orientation(isd, x_km, y_km, z_km, ra, dec, twist):
    """The ISD with jigsaw's J2000 position and pointing C = R3(twist) R1(dec) R3(ra)."""
    def r1(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])

    def r3(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    C = r3(np.radians(twist)) @ r1(np.radians(dec)) @ r3(np.radians(ra))
    return dataclasses.replace(isd, positions_m=np.array([[x_km, y_km, z_km]]) * 1000.0,
                               pointing_quaternions=quaternion_from_matrix(C)[None], pointing_constant=np.eye(3))


def test_jigsaw_solution_reprojects_with_jigsaws_point_residuals(apollo):
    """The model end to end against the peer: with jigsaw's adjusted orientations and points, the six
    spot-checked points have jigsaw's residual RMS (printed with 2 decimals). ISIS's residuals are
    undistorted *detector* pixels of the scanned frame (0.005 mm = 4 cube pixels), the RMS over samples and
    lines together."""
    net, isds, cube = apollo
    adjusted = {cube[k]: _with_orientation(isds[cube[k]], *v) for k, v in JIGSAW_FINAL.items()}
    assert np.allclose(F.isis_angles_deg(adjusted[cube[7]]), JIGSAW_FINAL[7][3:], atol=1e-9)
    points = {p.point_id: p for p in net.points}
    for point_id, (rms, xyz_km) in SPOT_POINTS.items():
        X = np.array(xyz_km)[None] * 1000.0
        residuals = []
        for m in points[point_id].measures:
            residuals.extend(F.isis_residuals_px(adjusted[m.serial_number], m.col_px, m.row_px, X))
        ours = float(np.sqrt(np.mean(np.square(residuals))))
        assert abs(ours - rms) <= 0.006, (point_id, ours, rms)


def test_apriori_points_project_near_their_measures(apollo, capsys):
    """Plausibility of the a-priori geometry (jigsaw's initial residuals are not published): per image the
    a-priori points land 28-45 px (cube) right and 13-28 px below their measures, a bias of the ISD's
    pointing of about 0.5° that jigsaw's corrections remove; the RMS about that bias is 7-15 px."""
    net, isds, cube = apollo
    points = {p.point_id: p for p in net.points}
    for k in sorted(cube):
        ms = [m for m in net.measures if m.serial_number == cube[k]]
        X = np.array([points[m.point_id].apriori_xyz_m for m in ms])
        c, r = F.ground_to_image(isds[cube[k]], X)
        d = np.stack([[m.col_px for m in ms] - c, [m.row_px for m in ms] - r], -1)
        rms = np.sqrt(np.mean(np.sum(d ** 2, 1)))
        spread = np.sqrt(np.mean(np.sum((d - d.mean(0)) ** 2, 1)))
        print(f"cube{k}: {len(ms)} measures, a-priori reprojection RMS {rms:.1f} px, mean {d.mean(0).round(1)}, "
              f"about the mean {spread:.1f} px")
        assert 30 < rms < 60 and spread < 16


# --- errors ---------------------------------------------------------------------------------------------

def _read(path):
    with open(path, encoding="utf-8") as handle:
        return handle.read()


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


POINT = """Object = ControlNetwork
  NetworkId = t
  Version = 5
  Object = ControlPoint
    PointType = {ptype}
    PointId = P1
    AprioriX = 1.0 <{unit}>
    AprioriY = 2.0 <meters>
    AprioriZ = 3.0 <meters>
    Group = ControlMeasure
      SerialNumber = A/B/C
      MeasureType = Manual
      Sample = {sample}
      Line = 2.0
    End_Group
  End_Object
End_Object
End
"""


def test_network_errors_name_file_line_and_key(tmp_path):
    good = dict(ptype="Free", unit="meters", sample="1.5")
    net = read_control_network(_write(tmp_path, "ok.net", POINT.format(**good)))
    assert net.points[0].measures[0].col_px == 1.0 and net.points[0].apriori_xyz_m.tolist() == [1.0, 2.0, 3.0]
    cases = [
        (dict(good, ptype="Wobbly"), r"bad\.net, line 5, column 'PointType': unknown PointType 'Wobbly'"),
        (dict(good, unit="km"), r"bad\.net, line 7, column 'AprioriX': 'AprioriX' is in <km>; expected <meters>"),
        (dict(good, sample="abc"), r"bad\.net, line 13, column 'Sample': 'Sample' must be a number"),
    ]
    for values, message in cases:
        with pytest.raises(BlockError, match=message):
            read_control_network(_write(tmp_path, "bad.net", POINT.format(**values)))
    broken = POINT.format(**good).replace("    End_Group\n", "")
    with pytest.raises(BlockError, match=r"line 15, column 'End_Object': End_Object closes Group 'ControlMeasure'"):
        read_control_network(_write(tmp_path, "bad.net", broken))
    with pytest.raises(BlockError, match=r"line 10, column 'SerialNumber'.*'A/B/C' is none of the images"):
        match_serials(net, [])
    no_id = POINT.format(**good).replace("    PointId = P1\n", "")
    with pytest.raises(BlockError, match=r"line 4, column 'PointId'"):
        read_control_network(_write(tmp_path, "bad.net", no_id))
    binary = "Object = ProtoBuffer\n  Group = ControlNetworkInfo\n    Version = 5\n  End_Group\nEnd_Object\nEnd\n"
    with pytest.raises(BlockError, match=r"bin\.pvl, line 1, column 'Core': the label's ProtoBuffer has no 'Object = Core'"):
        read_control_network(_write(tmp_path, "bin.pvl", binary))      # binary by its content, not its name
    with pytest.raises(BlockError, match=r"x\.pvl, line 2, column 'B': the array of 'B' is never closed"):
        parse_pvl("A = 1\nB = (1, 2\n", "x.pvl")


def test_ignored_points_and_measures_are_counted(tmp_path):
    text = POINT.format(ptype="Constrained", unit="meters", sample="1.5")
    text = text.replace("MeasureType = Manual", "MeasureType = Manual\n      Ignore = True")
    net = read_control_network(_write(tmp_path, "ign.net", text))
    assert net.counts()["ignored_measures"] == 1 and net.points[0].measures[0].ignored
    text = text.replace("PointId = P1", "PointId = P1\n    Ignore = yes")
    counts = read_control_network(_write(tmp_path, "ign.net", text)).counts()
    assert counts["ignored_points"] == 1 and counts["measures_of_ignored_points"] == 1
    assert counts["ignored_measures"] == 0


def test_label_and_isd_errors(tmp_path):
    label = _read(os.path.join(APOLLO, "apolloImage1.pvl"))
    with pytest.raises(BlockError, match=r"lab\.pvl, line 23, column 'SpacecraftName': no ISIS serial-number rule"):
        read_cube_label(_write(tmp_path, "lab.pvl", label.replace('"APOLLO 15"', '"VOYAGER 1"')))
    isd = json.loads(_read(os.path.join(APOLLO, "apolloImage1.isd")))
    del isd["naif_keywords"]["INS-915240_OD_K"]
    with pytest.raises(BlockError, match=r"bad\.isd, column 'naif_keywords\.INS-915240_OD_K': missing key"):
        read_frame_isd(_write(tmp_path, "bad.isd", json.dumps(isd)))
    isd = json.loads(_read(os.path.join(APOLLO, "apolloImage1.isd")))
    isd["name_model"] = "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"
    with pytest.raises(BlockError, match="only USGS_ASTRO_FRAME_SENSOR_MODEL"):
        read_frame_isd(_write(tmp_path, "bad.isd", json.dumps(isd)))
    wrong = read_cube_label(os.path.join(NAC, "observationImageL.pvl")).alpha_cube
    with pytest.raises(BlockError, match="AlphaCube has 5064 x 52224"):
        read_frame_isd(os.path.join(APOLLO, "apolloImage1.isd"), wrong)
    folder = tmp_path / "images"
    folder.mkdir()
    shutil.copy(os.path.join(APOLLO, "apolloImage1.pvl"), folder)
    with pytest.raises(BlockError, match=r"apolloImage1\.pvl: no sensor file beside the label"):
        read_image_folder(folder)
