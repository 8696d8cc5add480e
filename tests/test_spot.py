"""SPOT 5 DIMAP: the reader (selfcal.io.spot) against ASP's TestSpotCameraModel.cxx and the camera
(selfcal.sensors.spot) against the vendor's scene corners (../shared/data/pushbroom/asp_dg_spot/EXPECTED_VALUES.txt).

spot_example1.xml is a SPOT 5 HRS segment truncated by ASP to 300 columns (look angles of detectors 1-300) that
kept the full scene's corners: its Geoposition tie points place the Dataset_Frame corners "(300, 1)" and
"(300, 96168)" at column 12000 (TIE_POINT_DATA_X), the scene's last detector. Corners (1, 1) and (1, 96168) are
therefore checked directly; the far ones on a line extended to 12000 detectors (an extrapolation of the look
angles 40 times the table's length).
"""
import os

import numpy as np
import pytest

from conftest import SHARED_DATA
from selfcal.errors import BlockError
from selfcal.geometry.earth import ecef_from_geodetic, geodetic_from_ecef
from selfcal.io.spot import read_spot5
from selfcal.sensors.pushbroom import ground_to_image, image_to_ground
from selfcal.sensors.spot import line_image_from_spot5, look_angle_polynomials

PATH = os.path.join(SHARED_DATA, "pushbroom", "asp_dg_spot", "spot_example1.xml")
#: ASP's test tolerance for the values read (TestSpotCameraModel.cxx: EPS = 1e-8)
ASP_EPS = 1e-8
#: the corners (FRAME_COL, FRAME_ROW, lon, lat) of EXPECTED_VALUES.txt
CORNERS = ((1, 1, -75.519946, -76.636309), (300, 1, -71.924271, -77.389028),
           (300, 96168, -88.569672, -80.241112), (1, 96168, -91.818476, -79.298919))

_CACHE = {}


def sensor():
    if "sensor" not in _CACHE:
        _CACHE["sensor"] = read_spot5(PATH)
    return _CACHE["sensor"]


def test_reader_reads_what_asp_reads():
    s = sensor()
    assert (s.columns, s.rows) == (300, 96168)
    np.testing.assert_allclose(s.corners, np.array(CORNERS, float), rtol=0, atol=ASP_EPS)
    assert s.line_period_s == pytest.approx(7.5199705115e-04, abs=ASP_EPS)
    # ASP converts SCENE_CENTER_LINE / _COL to 0-based (48084, 6000); the file's are 1-based
    assert (s.center_line - 1, s.center_col - 1) == (48084, 6000)
    assert s.center_time_s == pytest.approx(3 * 60 + 12.349737, abs=1e-9)   # 12:31:39.349737 - 12:28:27
    assert s.epoch_utc == "2008-03-04T12:28:27.000000Z"
    assert s.detector_ids[9] == 10
    assert s.psi_x_rad[9] == pytest.approx(3.4977741700e-01, abs=ASP_EPS)
    assert s.psi_y_rad[9] == pytest.approx(-7.1264930800e-02, abs=ASP_EPS)
    # first / last corrected attitude (12:31:03.206912, 12:32:15.331747): yaw, pitch, roll
    assert s.attitude_t_s[0] == pytest.approx(156.206912, abs=1e-9)
    assert s.attitude_t_s[-1] == pytest.approx(228.331747, abs=1e-9)
    np.testing.assert_allclose(s.yaw_pitch_roll_rad[0], (1.1621635280e-03, -9.5496029568e-04, -1.7549389832e-05),
                               rtol=0, atol=ASP_EPS)
    np.testing.assert_allclose(s.yaw_pitch_roll_rad[-1], (1.2001004714e-03, -9.5696493468e-04, -2.4331461036e-05),
                               rtol=0, atol=ASP_EPS)
    assert s.ephemeris_t_s[0] == 0.0
    np.testing.assert_allclose(s.positions_m[0], (1.7495691231e+06, -2.2672541162e+06, -6.6183333707e+06),
                               rtol=0, atol=ASP_EPS)
    np.testing.assert_allclose(s.velocities_m_s[0], (-6.2538959540e+03, 3.1331303950e+03, -2.7272519760e+03),
                               rtol=0, atol=ASP_EPS)
    # "exactly": the file's digits
    assert s.psi_x_rad[9] == 3.4977741700e-01 and s.yaw_pitch_roll_rad[0, 0] == 1.1621635280e-03
    assert s.positions_m[0, 0] == 1.7495691231e+06 and s.velocities_m_s[0, 2] == -2.7272519760e+03
    np.testing.assert_array_equal(s.tie_points[:, 0], (1, 12000, 12000, 1))


def _ground_error_m(img, col, row, lon, lat) -> np.ndarray:
    """Distance (m) between the camera's point of DIMAP pixel (col, row) (1-based centres) on the ellipsoid and
    the vendor's (lon, lat, 0)."""
    X = image_to_ground(img, np.asarray(row, float) - 0.5, np.asarray(col, float) - 0.5, 0.0)
    P = ecef_from_geodetic(np.radians(lat), np.radians(lon), np.zeros(len(X)))
    return np.linalg.norm(X - P, axis=1)


def test_near_corners_match_the_vendor():
    """Corners (1, 1) and (1, 96168) at height 0 (the tie points' TIE_POINT_CRS_Z): measured 0.013 m and 0.145 m
    from the vendor's (lon, lat), i.e. 1.6e-7 / 3.0e-6 deg, at the corners' printed precision (1e-6 deg is 0.11 m
    in latitude, 0.02 m in longitude at 79 S). Tolerance 0.5 m (ASP checks only that the corners are read, to
    1e-8 deg; it has no projection test). The vendor applies no aberration (it would be 20 m)."""
    img = line_image_from_spot5(sensor())
    near = np.array([CORNERS[0], CORNERS[3]])
    errors = _ground_error_m(img, *near.T)
    assert np.all(errors < 0.5), errors
    X = image_to_ground(img, near[:, 1] - 0.5, near[:, 0] - 0.5, 0.0)
    lat, lon, _ = geodetic_from_ecef(X)
    np.testing.assert_allclose(np.degrees(lon), near[:, 2], atol=5e-6)
    np.testing.assert_allclose(np.degrees(lat), near[:, 3], atol=5e-6)


def test_far_corners_are_the_full_scenes_column_12000():
    """Column 300 of the truncated line lands 120 km from the "(300, .)" corners: they are column 12000's.
    On a line extended to 12000 detectors by the look-angle polynomial (degree 3, chosen by the table's fit
    within 2e-10 rad) the far corners come within 200 m (degree 1: 307 m, degree 2: 598 m): the extrapolation
    over 40 table lengths, not the model, sets this. Tolerance 1 km; the near corners stay within 0.5 m."""
    s = sensor()
    corners = np.array(CORNERS)
    truncated = line_image_from_spot5(s)
    assert np.all(_ground_error_m(truncated, *corners[[1, 2]].T) > 100e3)
    assert look_angle_polynomials(s)[2] == 3
    full = line_image_from_spot5(s, columns=12000)
    columns = np.array([1.0, 12000.0, 12000.0, 1.0])
    errors = _ground_error_m(full, columns, corners[:, 1], corners[:, 2], corners[:, 3])
    assert np.all(errors[[0, 3]] < 0.5) and np.all(errors[[1, 2]] < 1000.0), errors


def test_look_angles_reproduced_and_round_trip():
    """The look-angle polynomial reproduces the table within 6e-11 (tan); ground_to_image inverts
    image_to_ground within 1e-6 px over the scene (measured 4e-10 px)."""
    s = sensor()
    _, _, degree, misfit = look_angle_polynomials(s)
    assert misfit < 1e-10
    img = line_image_from_spot5(s)
    assert img.camera.view_pitch_deg == pytest.approx(np.degrees(np.arctan(np.tan(s.psi_x_rad[150]))), abs=1e-3)
    row, col = (a.ravel() for a in np.meshgrid(np.linspace(0.5, s.rows - 0.5, 25),
                                                np.linspace(0.5, s.columns - 0.5, 7)))
    X = image_to_ground(img, row, col, 500.0)
    r, c = ground_to_image(img, X)
    assert np.max(np.abs(r - row)) < 1e-6 and np.max(np.abs(c - col)) < 1e-6


def test_reader_errors_name_file_line_and_element(tmp_path):
    with open(PATH, encoding="utf-8") as handle:
        text = handle.read()
    broken = tmp_path / "broken.xml"
    broken.write_text(text.replace("<LINE_PERIOD>7.5199705115e-04</LINE_PERIOD>", ""), encoding="utf-8")
    with pytest.raises(BlockError, match="missing element LINE_PERIOD") as info:
        read_spot5(broken)
    assert info.value.path == str(broken)
    assert info.value.column == "Dimap_Document/Data_Strip/Sensor_Configuration/Time_Stamp/LINE_PERIOD"
    assert info.value.line == text[:text.index("<Time_Stamp>")].count("\n") + 1
    broken.write_text(text.replace("<TIME>2008-03-04T12:31:03.331912</TIME>", "<TIME>2008-03-04 noon</TIME>"),
                      encoding="utf-8")
    with pytest.raises(BlockError, match="must be a UTC time") as info:
        read_spot5(broken)
    corrected = text.index("<Corrected_Attitudes>")
    assert info.value.line == text[:text.index("<TIME>2008-03-04T12:31:03.331912", corrected)].count("\n") + 1
