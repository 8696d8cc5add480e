"""Camera GNSS from the images (issue 23 item 4): per-image sigmas of the trajectory observations, EXIF GPS and
DJI XMP read from JPEGs written with Pillow, ODM geo.txt, strips from time and heading, geographic GCPs."""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from selfcal.adjust.residuals import parameter_observations
from selfcal.adjust.initial import initial_state
from selfcal.adjust import AdjustOptions, TrajectoryOptions
from selfcal.adjust.problem import build_problem
from selfcal.block import prune
from selfcal.errors import BlockError
from selfcal.io.block_folder import read_block, write_block

from conftest import simulation


# ---------------------------------------------------------------------------- per-image sigmas

@pytest.fixture(scope="module")
def uav():
    return simulation(seed=5, distortion="none", points_per_mm2=0.6)


def test_per_image_sigma_overrides_the_block_sigma_in_the_engine(uav, tmp_path):
    """An image's own GNSS/IMU sigma (images.csv) whitens its observation instead of block.toml's: with the
    same residual, 10 times the sigma gives a tenth of the whitened residual; the others are unchanged."""
    block = prune(uav.blocks["type2"])
    n = len(block.images)
    own = np.full((n, 3), np.nan)
    own[3] = [0.5, 0.5, 1.0]                                  # 10 x [gnss] sigma_m = 0.05, 0.05, 0.10
    own_imu = np.full((n, 3), np.nan)
    own_imu[7] = np.radians([0.2, 0.2, 0.5])                  # 10 x [imu] sigma_deg
    write_block(replace(block, images=replace(block.images, gnss_sigma_m=own, imu_sigma_rad=own_imu)),
                tmp_path / "own")
    text = (tmp_path / "own" / "images.csv").read_text()
    assert "sigma_gnss_X_m" in text.splitlines()[0] and "sigma_imu_kappa_deg" in text.splitlines()[0]
    read = read_block(tmp_path / "own")
    np.testing.assert_allclose(read.images.gnss_sigma_m[3], [0.5, 0.5, 1.0])
    np.testing.assert_allclose(np.degrees(read.images.imu_sigma_rad[7]), [0.2, 0.2, 0.5])
    assert np.isnan(read.images.gnss_sigma_m[np.arange(n) != 3]).all()

    residuals = {}
    for name, b in (("block", block), ("own", read)):
        problem = build_problem(b, AdjustOptions(trajectory=TrajectoryOptions(gnss_drift=-1, imu_drift=-1)))
        state, _ = initial_state(problem, b)
        state.image[:, :3] += [0.3, -0.2, 0.4]                # every observation gets a residual
        state.image[:, 3:6] += np.radians([0.05, -0.04, 0.1])
        _, r = parameter_observations(problem, state)
        k = int(np.sum(np.isfinite(problem.image_prior_sigma) & problem.image_free))
        traj = r[k:].reshape(2, n, 3)                         # GNSS rows, then IMU rows
        residuals[name] = traj
        gnss = next(t for t in problem.trajectory if t.sensor == "GNSS")
        if name == "own":
            np.testing.assert_allclose(gnss.sigma[3], [0.5, 0.5, 1.0])
            np.testing.assert_allclose(gnss.sigma[0], block.gnss_sigma_m)
    ratio = residuals["own"] / residuals["block"]
    np.testing.assert_allclose(ratio[0, 3], 0.1, rtol=1e-9)
    np.testing.assert_allclose(ratio[1, 7], 0.1, rtol=1e-9)
    mask = np.ones((2, n), bool)
    mask[0, 3] = mask[1, 7] = False
    np.testing.assert_allclose(ratio[mask], 1.0, rtol=1e-12)
    # variance components scale an image's own sigma with its group's
    from selfcal.stats.variance import reweighted
    scaled = reweighted(read, {"GNSS": 2.0, "IMU": 0.5})
    np.testing.assert_allclose(scaled.images.gnss_sigma_m[3], [1.0, 1.0, 2.0])
    np.testing.assert_allclose(np.degrees(scaled.images.imu_sigma_rad[7]), [0.1, 0.1, 0.25])


def test_per_image_sigma_needs_its_section_and_a_positive_value(uav, tmp_path):
    block = prune(uav.blocks["type1"])                       # no [gnss]
    own = np.full((len(block.images), 3), np.nan)
    own[0] = 0.02
    with pytest.raises(BlockError, match=r"sigma_gnss_X_m.*no \[gnss\]|no \[gnss\]") as info:
        write_block(replace(block, images=replace(block.images, gnss_sigma_m=own)), tmp_path / "b", source="x")
    assert "sigma_gnss_X_m" in str(info.value)
    write_block(prune(uav.blocks["type2"]), tmp_path / "t2")
    path = tmp_path / "t2" / "images.csv"
    lines = path.read_text().splitlines()
    lines[0] += ",sigma_gnss_Z_m"
    lines[1:] = [line + "," for line in lines[1:]]
    lines[2] = lines[2] + "-0.1"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BlockError) as info:
        read_block(tmp_path / "t2")
    assert info.value.line == 3 and info.value.column == "sigma_gnss_Z_m" and "positive" in info.value.reason


# ---------------------------------------------------------------------------- JPEGs with EXIF GPS and DJI XMP

from fractions import Fraction                                      # noqa: E402

from PIL import Image                                               # noqa: E402
from PIL.TiffImagePlugin import IFDRational                          # noqa: E402

from selfcal.simulate.trajectory import TrajectoryErrors            # noqa: E402
from selfcal.adjust import APOptions

CRS = "EPSG:32632"                        # UTM 32N: the simulated block's local frame moved to ORIGIN
ORIGIN = np.array([500_000.0, 5_200_000.0, 0.0])
XMP_STRIPS = ("S2", "S3")                 # images of these strips carry a DJI XMP packet with RtkStd sigmas
RTK_SIGMA = (0.03, 0.03, 0.05)            # the simulated GNSS noise, written as RtkStdLon, RtkStdLat, RtkStdHgt
GPS_DAY = 1_714_953_600.0                 # 2024-05-06 00:00:00 UTC


def _utm_block(block):
    """``block`` in UTM 32N: every coordinate moved by ORIGIN."""
    images = replace(block.images, position_m=block.images.position_m + ORIGIN)
    points = replace(block.points, xyz_m=block.points.xyz_m + ORIGIN)
    return replace(block, crs=CRS, images=images, points=points)


def _dms(value: float, den: int = 10 ** 7) -> tuple:
    """Degrees as EXIF's three rationals (EXIF 2.32, GPSLatitude: degrees, minutes, seconds)."""
    value = abs(value)
    d = int(value)
    m = int((value - d) * 60)
    s = Fraction(round(((value - d) * 60 - m) * 60 * den), den)
    return IFDRational(d, 1), IFDRational(m, 1), IFDRational(s.numerator, s.denominator)


def _xmp(gimbal_ypr_deg, position=None, sigma=None) -> bytes:
    """A DJI XMP packet as DJI's manuals list its drone-dji fields (attributes of rdf:Description): the gimbal's
    angles, and where given the position and its RTK standard deviations."""
    fields = [f'drone-dji:Gimbal{a}Degree="{v:+.9f}"' for a, v in zip(("Yaw", "Pitch", "Roll"), gimbal_ypr_deg)]
    fields += ['drone-dji:FlightYawDegree="+12.3"', 'drone-dji:FlightPitchDegree="+1.5"',
               'drone-dji:FlightRollDegree="-0.7"']
    if position is not None:
        lon, lat, h = position
        fields += [f'drone-dji:GpsLatitude="{lat:+.10f}"', f'drone-dji:GpsLongitude="{lon:+.10f}"',
                   f'drone-dji:AbsoluteAltitude="{h:+.4f}"', 'drone-dji:RtkFlag="50"']
    if sigma is not None:
        fields += [f'drone-dji:RtkStd{a}="{v:.5f}"' for a, v in zip(("Lon", "Lat", "Hgt"), sigma)]
    return ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>'
            '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            '<rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
            + " ".join(fields) + '/></rdf:RDF></x:xmpmeta><?xpacket end="w"?>').encode("utf-8")


def gimbal_angles(opk_grid: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """(n, 3) DJI gimbal yaw, pitch, roll (degrees) of cameras with omega, phi, kappa in the UTM grid.

    Written independently of selfcal's conversion: the camera's body axes (x along the view, y to the image's
    right, z to its bottom) from the rows of M, turned from the grid to true north by pyproj's own meridian
    convergence (PROJ's factors: the grid azimuth of true north is minus the convergence), then the aerospace
    yaw-pitch-roll (Z-Y-X) angles of the body in north-east-down."""
    from pyproj import Proj
    from selfcal.geometry.rotation import matrix_from_opk
    M = matrix_from_opk(opk_grid)
    body = np.stack([-M[:, 2], M[:, 0], -M[:, 1]], -1)             # columns x, y, z in grid east-north-up
    gamma = np.radians(Proj(CRS).get_factors(lon, lat).meridian_convergence)
    beta = -gamma
    c, s = np.cos(beta), np.sin(beta)
    e, n, u = body[:, 0], body[:, 1], body[:, 2]
    true_e = c[:, None] * e - s[:, None] * n
    true_n = s[:, None] * e + c[:, None] * n
    R = np.stack([true_n, true_e, -u], 1)                           # rows north, east, down; columns x, y, z
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    pitch = np.arctan2(-R[:, 2, 0], np.hypot(R[:, 0, 0], R[:, 1, 0]))
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    return np.degrees(np.column_stack([yaw, pitch, roll]))


def write_jpeg(path, lon: float, lat: float, h: float, time_s: float | None, xmp: bytes | None = None) -> None:
    """A tiny JPEG with EXIF GPS tags (Pillow), optionally a DJI XMP packet."""
    exif = Image.Exif()
    gps = exif.get_ifd(0x8825)
    gps[1], gps[2] = ("N" if lat >= 0 else "S"), _dms(lat)
    gps[3], gps[4] = ("E" if lon >= 0 else "W"), _dms(lon)
    gps[5], gps[6] = (b"\x01", IFDRational(round(-h * 10 ** 4), 10 ** 4)) if h < 0 else \
        (b"\x00", IFDRational(round(h * 10 ** 4), 10 ** 4))
    if time_s is not None:
        day = time_s % 86400
        gps[7] = (IFDRational(int(day // 3600), 1), IFDRational(int(day % 3600 // 60), 1),
                  IFDRational(round(day % 60 * 1000), 1000))
        gps[29] = "2024:05:06"
    Image.new("RGB", (16, 12), (90, 120, 60)).save(path, exif=exif, **({"xmp": xmp} if xmp else {}))


def geodetic(xyz_utm: np.ndarray) -> np.ndarray:
    """(n, 3) longitude, latitude, ellipsoidal height of UTM 32N positions (pyproj, the other tool)."""
    from pyproj import Transformer
    t = Transformer.from_crs(CRS, "EPSG:4979", always_xy=True)
    return np.column_stack(t.transform(*xyz_utm.T))


@pytest.fixture(scope="module")
def drone(tmp_path_factory):
    """A simulated block with strip-wise GNSS errors drawn independently of Eq. 12, in UTM; one JPEG per image
    with its simulated GNSS position; the block handed to the import has no [gnss] and true positions."""
    from selfcal.simulate import simulate_uav
    sim = simulate_uav(seed=11, distortion="none", points_per_mm2=0.6, gnss_sigma_m=RTK_SIGMA,
                       trajectory_errors=TrajectoryErrors(gnss_noise_m=RTK_SIGMA, drift_share=0.75))
    root = tmp_path_factory.mktemp("drone")
    truth_block = _utm_block(sim.blocks["type1"])           # sparse control, no trajectory observations
    gnss_utm = truth_block.images.position_m.copy()           # the simulated GNSS observations, in UTM
    given = replace(truth_block, images=replace(truth_block.images, position_m=sim.truth.eop[:, :3] + ORIGIN,
                                                strip_id=np.full(len(gnss_utm), "", dtype=object),
                                                time_s=np.full(len(gnss_utm), np.nan)))
    write_block(given, root / "block")
    geo = geodetic(gnss_utm)
    imu = truth_block.images.attitude_rad                     # the simulated IMU observations (grid)
    gimbal = gimbal_angles(imu, geo[:, 0], geo[:, 1])
    images = root / "images"
    images.mkdir()
    strips = sim.blocks["type1"].images.strip_id
    for k, image_id in enumerate(truth_block.images.image_id):
        lon, lat, h = geo[k]
        if strips[k] in XMP_STRIPS:
            xmp = _xmp(gimbal[k], geo[k], RTK_SIGMA)
            lon, lat, h = lon + 2e-5, lat - 2e-5, h + 1.0       # EXIF off by metres: the XMP must win
        else:
            xmp = _xmp(gimbal[k])
        write_jpeg(images / f"{image_id}.JPG", lon, lat, h, GPS_DAY + 36000.0 + truth_block.images.time_s[k], xmp)
    return sim, root, gnss_utm


def test_exif_and_xmp_positions_sigmas_times_and_strips(drone, cli):
    sim, root, gnss_utm = drone
    assert cli("import", "gnss", str(root / "images"), "--block", str(root / "block"), "--out", str(root / "gnss"),
               "--sigma-m", "0.03,0.03,0.05") == 0
    block = read_block(root / "gnss")
    assert block.crs == CRS and block.gnss_sigma_m == RTK_SIGMA
    np.testing.assert_allclose(block.images.position_m, gnss_utm, atol=1e-3, rtol=0)
    xmp = np.isin(sim.blocks["type1"].images.strip_id, XMP_STRIPS)
    np.testing.assert_allclose(block.images.gnss_sigma_m[xmp], np.tile(RTK_SIGMA, (xmp.sum(), 1)), rtol=1e-9)
    assert np.isnan(block.images.gnss_sigma_m[~xmp]).all()
    np.testing.assert_array_equal(block.images.strip_id, sim.blocks["type1"].images.strip_id)
    np.testing.assert_allclose(block.images.time_s, sim.blocks["type1"].images.time_s, atol=1e-3)


def test_gimbal_angles_become_the_imu_observations(drone, cli):
    """DJI's gimbal yaw, pitch, roll (written from the simulated IMU observations through pyproj's meridian
    convergence) come back as the block's omega, phi, kappa in the UTM grid within 1e-7 degrees."""
    sim, root, gnss_utm = drone
    assert cli("import", "gnss", str(root / "images"), "--block", str(root / "block"), "--out",
               str(root / "gnss_imu"), "--sigma-m", "0.03,0.03,0.05", "--imu-sigma-deg", "0.005,0.005,0.01") == 0
    block = read_block(root / "gnss_imu")
    assert block.imu_sigma_deg == (0.005, 0.005, 0.01)
    diff = (block.images.attitude_rad - sim.blocks["type1"].images.attitude_rad + np.pi) % (2 * np.pi) - np.pi
    assert np.degrees(np.abs(diff)).max() < 1e-7
    np.testing.assert_allclose(block.images.position_m, gnss_utm, atol=1e-3, rtol=0)


def test_adjustment_recovers_the_strip_shifts_and_drifts(drone, cli):
    """Eq. 12 of seed 000 on the imported block: every simulated GNSS and IMU shift and drift recovered within
    3 sigma (errors drawn independently of the model: TrajectoryErrors)."""
    from selfcal.adjust import adjust, AdjustOptions, APOptions, TrajectoryOptions
    from selfcal.simulate.trajectory import true_terms_by_name
    sim, root, _ = drone
    if not (root / "gnss_imu").exists():
        assert cli("import", "gnss", str(root / "images"), "--block", str(root / "block"), "--out",
                   str(root / "gnss_imu"), "--sigma-m", "0.03,0.03,0.05", "--imu-sigma-deg", "0.005,0.005,0.01") == 0
    result = adjust(read_block(root / "gnss_imu"), AdjustOptions(ap=APOptions("none"), trajectory=TrajectoryOptions(gnss_drift=1, imu_drift=1)))
    assert result.converged
    truth = true_terms_by_name(sim.truth, result)
    names = list(result.theta_names)
    value = dict(zip(names, result.problem.pack(result.state)))
    sigma = dict(zip(names, np.sqrt(result.variance_factor * np.diag(result.Q_theta))))
    for sensor in ("GNSS", "IMU"):
        terms = [n for n in names if n.startswith(sensor + " ")]
        assert len(terms) == 4 * 2 * 3
        z = np.array([(value[n] - truth[n][0]) / sigma[n] for n in terms])
        size = np.array([truth[n][0] / sigma[n] for n in terms if " D0 " in n])
        print(sensor, "terms: max |est - true| / sigma", np.abs(z).max(), "RMS", np.sqrt(np.mean(z ** 2)),
              "RMS of true shift / sigma", np.sqrt(np.mean(size ** 2)))
        assert np.all(np.abs(z) < 3), dict(zip(terms, z.round(2)))
        assert np.sqrt(np.mean(z ** 2)) < 1.5                # sigmas not pessimistic
        assert np.sqrt(np.mean(size ** 2)) > 5               # shifts far beyond their sigma: the test can fail


def test_grid_bearing_of_north_is_minus_the_meridian_convergence():
    """selfcal's numerical grid bearing of true north against PROJ's own meridian convergence (its factors)."""
    from pyproj import Proj
    from selfcal.geometry.gnss import grid_bearing_of_north
    lon, lat = np.array([6.2, 9.0, 11.7, 7.5]), np.array([46.0, 47.1, 45.3, -33.0])
    gamma = np.radians(Proj(CRS).get_factors(lon, lat).meridian_convergence)
    np.testing.assert_allclose(grid_bearing_of_north(lon, lat, CRS), -gamma, atol=1e-7)
    assert np.degrees(np.abs(gamma)).max() > 1.5                 # 3 degrees from the central meridian


# ---------------------------------------------------------------------------- ODM geo.txt

def test_geo_txt_in_longitude_latitude_with_accuracies(drone, cli, tmp_path):
    """ODM's "Image Geolocation Files": EPSG:4326 with the longitude first, the height, yaw pitch roll (0: not
    available) and the horizontal/vertical accuracy on some lines; no times (the strips come from the headings
    in the block's image order)."""
    sim, root, gnss_utm = drone
    block = read_block(root / "block")
    geo = geodetic(gnss_utm)
    lines = ["EPSG:4326"]
    for k, image_id in enumerate(block.images.image_id):
        lon, lat, h = geo[k]
        extra = " 0 0 0 0.02 0.04 label" if k % 3 == 0 else ""
        lines.append(f"{image_id}.JPG {lon:.11f} {lat:.11f} {h:.5f}{extra}")
    (tmp_path / "geo.txt").write_text("\n".join(lines) + "\n")
    assert cli("import", "gnss", str(tmp_path / "geo.txt"), "--block", str(root / "block"),
               "--out", str(tmp_path / "out")) == 0
    out = read_block(tmp_path / "out")
    np.testing.assert_allclose(out.images.position_m, gnss_utm, atol=1e-3, rtol=0)
    every3 = np.arange(len(geo)) % 3 == 0
    np.testing.assert_allclose(out.images.gnss_sigma_m[every3], np.tile([0.02, 0.02, 0.04], (every3.sum(), 1)))
    assert np.isnan(out.images.gnss_sigma_m[~every3]).all() and out.gnss_sigma_m == (3.0, 3.0, 5.0)
    np.testing.assert_array_equal(out.images.strip_id, sim.blocks["type1"].images.strip_id)


def test_geo_txt_in_the_block_crs_with_orthometric_heights(drone, cli, tmp_path):
    """A geo.txt already in UTM: --heights orthometric keeps the heights, the plan position is the same."""
    sim, root, gnss_utm = drone
    block = read_block(root / "block")
    lines = ["WGS84 UTM 32N"] + [f"{i} {x:.4f} {y:.4f} {z:.4f}" for i, (x, y, z) in
                                 zip(block.images.image_id, gnss_utm + [0, 0, -47.5])]
    (tmp_path / "geo.txt").write_text("\n".join(lines) + "\n")
    assert cli("import", "gnss", str(tmp_path / "geo.txt"), "--block", str(root / "block"), "--heights",
               "orthometric", "--out", str(tmp_path / "out")) == 0
    np.testing.assert_allclose(read_block(tmp_path / "out").images.position_m, gnss_utm + [0, 0, -47.5], atol=1e-4)


# ---------------------------------------------------------------------------- bad input

def test_jpeg_without_gps_and_jpeg_not_in_the_block_are_counted_warnings(drone, cli, capsys, tmp_path):
    sim, root, gnss_utm = drone
    images = tmp_path / "images"
    images.mkdir()
    names = sorted(os.listdir(root / "images"))
    for name in names[1:]:
        (images / name).write_bytes((root / "images" / name).read_bytes())
    Image.new("RGB", (8, 8)).save(images / names[0])                 # no EXIF at all
    (images / "DJI_9999.JPG").write_bytes((root / "images" / names[3]).read_bytes())
    assert cli("import", "gnss", str(images), "--block", str(root / "block"), "--out", str(tmp_path / "o")) == 0
    said = capsys.readouterr()
    err = said.err
    assert f"{images / names[0]}: no GPS position" in err
    assert "DJI_9999.JPG' is not in the block" in err
    assert "(3 warnings)" in said.out                      # the two above and the block image left without GNSS
    out = read_block(tmp_path / "o")
    assert np.isnan(out.images.position_m[0]).all()
    np.testing.assert_allclose(out.images.position_m[1:], gnss_utm[1:], atol=1e-3)


def test_bad_input_exits_2_naming_the_file_and_line(drone, cli, capsys, tmp_path):
    sim, root, gnss_utm = drone
    bad = tmp_path / "geo.txt"
    bad.write_text("EPSG:4326\nS1_01.JPG 9.1 45.2 300\nS1_02.JPG 9.1 north 300\n")
    assert cli("import", "gnss", str(bad), "--block", str(root / "block"), "--out", str(tmp_path / "o")) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "line 3" in err and "geo_y" in err and "'north' is not a number" in err
    bad.write_text("EPSG:4326\nS1_01.JPG 45.2 109.1 300\n")          # latitude first: not ODM's order
    assert cli("import", "gnss", str(bad), "--block", str(root / "block"), "--out", str(tmp_path / "o")) == 2
    assert "geo_x is the longitude" in capsys.readouterr().err
    empty = tmp_path / "nogps"
    empty.mkdir()
    Image.new("RGB", (8, 8)).save(empty / "S1_01.JPG")
    assert cli("import", "gnss", str(empty), "--block", str(root / "block"), "--out", str(tmp_path / "o")) == 2
    assert "none of the 1 JPEGs has a GPS position" in capsys.readouterr().err
    write_block(replace(read_block(root / "block"), crs="local"), tmp_path / "local")
    assert cli("import", "gnss", str(root / "images"), "--block", str(tmp_path / "local"), "--out",
               str(tmp_path / "o")) == 2
    assert "crs is \"local\"" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_geo_txt_in_latitude_longitude_order(drone, cli, capsys, tmp_path):
    """A geo.txt in EPSG:4326 with the latitude first (47.0 9.0, both valid either way): against the block's
    control it lies thousands of km off, swapped on it. Exit 2 naming geo.txt and the swapped columns, before
    any conversion; nothing is written."""
    sim, root, gnss_utm = drone
    block = read_block(root / "block")
    geo = geodetic(gnss_utm)
    lines = ["EPSG:4326"] + [f"{image_id}.JPG {lat:.11f} {lon:.11f} {h:.5f}"
                             for image_id, (lon, lat, h) in zip(block.images.image_id, geo)]
    bad = tmp_path / "geo.txt"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert cli("import", "gnss", str(bad), "--block", str(root / "block"), "--out", str(out)) == 2
    err = capsys.readouterr().err
    assert f"{bad}: the GNSS positions' longitude and latitude look swapped (the file in latitude, longitude " \
           f"order?): as given they lie " in err, err
    assert "m from the " in err and "control points of the block" in err, err
    assert "selfcal reads X as the longitude and Y as the latitude; swap the two columns (point 'S1_01.JPG'" in err
    assert not out.exists()


def test_block_control_in_northing_easting_order_against_camera_gnss(drone, cli, capsys, tmp_path):
    """The block's points.csv with its control in northing, easting order: the images' GNSS positions show it.
    Exit 2 naming the block's points.csv (the positions' file is right)."""
    sim, root, gnss_utm = drone
    block = read_block(root / "block")
    xyz = block.points.xyz_m.copy()
    marked = block.points.role != "tie"
    xyz[marked] = xyz[marked][:, [1, 0, 2]]
    write_block(replace(block, points=replace(block.points, xyz_m=xyz)), tmp_path / "swapped")
    out = tmp_path / "out"
    assert cli("import", "gnss", str(root / "images"), "--block", str(tmp_path / "swapped"), "--out", str(out)) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'swapped' / 'points.csv'}: the control points' X and Y look swapped (the file in " \
           f"northing, easting order?): as given they lie " in err, err
    assert f"m from the {len(block.images)} GNSS positions of the images" in err, err
    assert not out.exists()


def test_geo_txt_in_northing_easting_order_in_the_block_crs(drone, cli, capsys, tmp_path):
    """A geo.txt in the block's UTM with northing, easting: against the control it is the same mismatch as a
    swapped points.csv, but the block's own image positions say which file it is: exit 2 naming geo.txt."""
    sim, root, gnss_utm = drone
    block = read_block(root / "block")
    lines = [CRS] + [f"{image_id}.JPG {y:.4f} {x:.4f} {z:.4f}"
                     for image_id, (x, y, z) in zip(block.images.image_id, gnss_utm)]
    bad = tmp_path / "geo.txt"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert cli("import", "gnss", str(bad), "--block", str(root / "block"), "--out", str(out)) == 2
    err = capsys.readouterr().err
    assert f"{bad}: the GNSS positions' X and Y look swapped (the file in northing, easting order?): as given they " \
           f"lie " in err, err
    assert f"m from the {len(block.images)} positions of the block's images.csv" in err, err
    assert not out.exists()


def test_gcp_list_in_latitude_longitude_order(tmp_path, capsys):
    """ODM's gcp_list.txt in EPSG:4326 with the latitude first, in Taiwan (121.5 E): 121.5 is no latitude. Exit 2
    naming the file, the line and geo_y, and that the columns look swapped."""
    from selfcal.io.odm import read_gcp_list
    bad = tmp_path / "gcp_list.txt"
    bad.write_text("EPSG:4326\n25.0301 121.5651 10.0 1000 800 DJI_0001.JPG gcp1\n")
    with pytest.raises(BlockError) as info:
        read_gcp_list(bad)
    assert info.value.line == 2 and info.value.column == "geo_y"
    assert "latitude 121.565 is outside -90..90 degrees" in info.value.reason
    assert "geo_x and geo_y look swapped (geo_x 25.0301 would be a latitude); swap the two columns" in \
        info.value.reason


# ---------------------------------------------------------------------------- ODM gcp_list.txt: longitude/latitude, NaN heights

COPR = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "copr")


def test_geographic_gcp_list_with_a_plan_only_point(tmp_path):
    """ODM's gcp_list.txt in EPSG:4326 (geo_x the longitude, as ODM reads it) becomes the UTM zone of its points,
    the same plan coordinates as the projected list (pyproj, within 1 mm); a NaN elevation is a plan-only gcp:
    left out of the 3-D georeference and held at its intersected height with a loose sigma."""
    from pyproj import Transformer
    from selfcal.convert import PLAN_ONLY_SIGMA_Z_M, block_from_colmap
    from selfcal.io.colmap import read_colmap
    from selfcal.io.odm import read_gcp_list
    assert os.path.isdir(COPR), "shared test data missing: ../shared/data/copr"
    model = read_colmap(os.path.join(COPR, "sparse"))
    projected = read_gcp_list(os.path.join(COPR, "gcp_list.txt"))
    to_geo = Transformer.from_crs(projected.crs, "EPSG:4326", always_xy=True)
    with open(os.path.join(COPR, "gcp_list.txt")) as handle:
        lines = handle.read().splitlines()
    out = ["EPSG:4326"]
    for line in lines[1:]:
        f = line.split()
        if len(f) < 6:
            continue
        lon, lat = to_geo.transform(float(f[0]), float(f[1]))
        z = "NaN" if f[6:7] == ["gcp07"] else f[2]
        out.append(" ".join([f"{lon:.10f}", f"{lat:.10f}", z] + f[3:]))
    (tmp_path / "gcp_geo.txt").write_text("\n".join(out) + "\n")
    geographic = read_gcp_list(tmp_path / "gcp_geo.txt")
    assert geographic.crs == "EPSG:4326" and np.isnan(geographic.xyz[list(geographic.point_names).index("gcp07"), 2])
    a, notes_a = block_from_colmap(model, projected, pixel_size_mm=0.0052)
    b, notes_b = block_from_colmap(model, geographic, pixel_size_mm=0.0052)
    assert b.crs == projected.crs == "EPSG:32611"
    assert any("converted from WGS 84" in n for n in notes_b) and any("gcp07" in n and "plan" in n for n in notes_b)
    gcp = b.points.role == "gcp"
    np.testing.assert_array_equal(a.points.point_id[:gcp.sum()], b.points.point_id[:gcp.sum()])
    np.testing.assert_allclose(b.points.xyz_m[gcp, :2], a.points.xyz_m[gcp, :2], atol=1e-3, rtol=0)
    k = list(b.points.point_id).index("gcp07")
    assert b.points.sigma_m[k, 2] == PLAN_ONLY_SIGMA_Z_M and b.points.sigma_m[k, 0] == a.points.sigma_m[k, 0]
    others = gcp & (b.points.point_id != "gcp07")
    np.testing.assert_allclose(b.points.xyz_m[others, 2], a.points.xyz_m[others, 2], atol=1e-9)
    # its height is where its rays meet, near the others' (a beach at about 0 m), not the surveyed one
    assert abs(b.points.xyz_m[k, 2] - a.points.xyz_m[k, 2]) < 3.0


def test_a_plan_only_control_point_leaves_the_adjustment_alone(uav):
    """The engine weights control per axis: a gcp whose height is 40 m wrong but held with the plan-only sigma
    (1e6 m) moves no check point by more than 0.1 mm against the same point with its right height, and its
    adjusted height is the true one."""
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.convert import PLAN_ONLY_SIGMA_Z_M
    block = prune(uav.blocks["type1"])
    k = int(np.flatnonzero(block.points.role == "gcp")[4])
    sigma = block.points.sigma_m.copy()
    sigma[k, 2] = PLAN_ONLY_SIGMA_Z_M
    xyz = block.points.xyz_m.copy()
    xyz[k, 2] += 40.0
    plan = replace(block, points=replace(block.points, xyz_m=xyz, sigma_m=sigma))
    free = replace(block, points=replace(block.points, sigma_m=sigma))
    a, b = (adjust(x, AdjustOptions(ap=APOptions("none"))) for x in (plan, free))
    assert a.converged and b.converged
    i = list(uav.truth.point_id).index(block.points.point_id[k])
    assert abs(a.state.points[k, 2] - uav.truth.xyz[i, 2]) < 0.2
    chk = block.points.role == "chk"
    assert np.abs(a.state.points[chk] - b.state.points[chk]).max() < 1e-4


def test_exif_reader_details(tmp_path):
    """South/west references, an altitude below the reference (GPSAltitudeRef 1), the camera clock with its
    sub-seconds and UTC offset where there is no GPS time, DJI tags as XMP elements; a broken XMP packet and a
    file that is no image name the file."""
    from selfcal.io.exif import read_image_gnss
    path = tmp_path / "a.jpg"
    exif = Image.Exif()
    gps = exif.get_ifd(0x8825)
    gps[1], gps[2], gps[3], gps[4] = "S", _dms(33.5), "W", _dms(70.25)
    gps[5], gps[6] = b"\x01", IFDRational(125, 10)
    camera = exif.get_ifd(0x8769)
    camera[0x9003], camera[0x9291], camera[0x9011] = "2024:05:06 12:00:01", "25", "+02:00"
    xmp = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
           '<rdf:Description xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"><drone-dji:RtkStdLon>0.011'
           '</drone-dji:RtkStdLon><drone-dji:RtkStdLat>0.012</drone-dji:RtkStdLat><drone-dji:RtkStdHgt>0.025'
           '</drone-dji:RtkStdHgt></rdf:Description></rdf:RDF></x:xmpmeta>').encode()
    Image.new("RGB", (8, 8)).save(path, exif=exif, xmp=xmp)
    r = read_image_gnss(path)
    assert (r.latitude_deg, r.longitude_deg, r.height_m) == (-33.5, -70.25, -12.5)
    assert r.time_source == "camera" and r.time_s == GPS_DAY + 10 * 3600 + 1.25
    assert r.sigma_enu_m == (0.011, 0.012, 0.025)
    Image.new("RGB", (8, 8)).save(path, exif=exif, xmp=xmp.replace(b"</rdf:RDF>", b""))
    with pytest.raises(BlockError, match="XMP packet is not well-formed") as info:
        read_image_gnss(path)
    assert info.value.path == str(path)
    path.write_bytes(b"not a jpeg")
    with pytest.raises(BlockError, match="not an image"):
        read_image_gnss(path)


def test_ellipsoidal_heights_into_a_vertical_datum_need_its_geoid():
    """A block in UTM + EGM96 heights: the ellipsoidal height goes through the geoid (about 49 m here) or, with
    the grid not installed, is refused rather than passed through by PROJ's ballpark fallback; orthometric
    heights are kept."""
    from pyproj import CRS as ProjCRS
    from pyproj.transformer import TransformerGroup
    from selfcal.geometry.gnss import positions_in_crs
    target = "EPSG:32632+5773"
    lonlath = np.array([[9.0, 46.9, 500.0]])
    np.testing.assert_allclose(positions_in_crs(lonlath, "EPSG:4326", target, "orthometric")[0, 2], 500.0)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)               # pyproj's note that the grid is missing
        grid_here = TransformerGroup(ProjCRS("EPSG:4979"), ProjCRS(target)).best_available
    if grid_here:
        assert 40.0 < 500.0 - positions_in_crs(lonlath, "EPSG:4326", target)[0, 2] < 60.0
    else:
        with pytest.raises(ValueError, match="needs a grid that is not installed"):
            positions_in_crs(lonlath, "EPSG:4326", target)


def test_positions_without_times_and_the_default_drift_say_what_to_give(drone, cli, capsys, tmp_path):
    """An ODM geo.txt has no times: the import says a drift needs them; adjust with the default --gnss-drift 1 is
    a usage error (exit 2) naming --gnss-drift 0 and the times, before any work; --gnss-drift 0 adjusts."""
    sim, root, gnss_utm = drone
    block = read_block(root / "block")
    geo = geodetic(gnss_utm)
    lines = ["EPSG:4326"] + [f"{i}.JPG {lon:.11f} {lat:.11f} {h:.5f}" for i, (lon, lat, h) in
                             zip(block.images.image_id, geo)]
    (tmp_path / "geo.txt").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert cli("import", "gnss", str(tmp_path / "geo.txt"), "--block", str(root / "block"), "--sigma-m",
               "0.03,0.03,0.05", "--out", str(out)) == 0
    assert f"{len(geo)} of the positions have no exposure time: adjust with --gnss-drift 0" in capsys.readouterr().err
    assert cli("adjust", str(out), "--out", str(tmp_path / "r1"), "--ap", "none", "--no-report") == 2
    err = capsys.readouterr().err
    assert "--gnss-drift 1 (the default: a shift and a drift per strip) needs the exposure time" in err
    assert "give --gnss-drift 0 (a shift per strip)" in err and "an ODM geo.txt carries no times" in err
    assert not (tmp_path / "r1").exists()
    assert cli("adjust", str(out), "--out", str(tmp_path / "r0"), "--ap", "none", "--no-report", "--quiet",
               "--gnss-drift", "0") == 0
