"""DigitalGlobe / Maxar XML: the reader (selfcal.io.dg), the rigorous line camera (selfcal.sensors.dg) against
ASP's expected values (../shared/data/pushbroom/asp_dg_spot/EXPECTED_VALUES.txt, from ASP's
TestDGCameraModel.cxx), the rigorous camera against the vendor RPC (RPB block) of the same XML, and the RPC
formats of GDAL's world (selfcal.io.rpc_gdal through selfcal.io.rpc.read_rpc): .RPB, the XML's RPB block,
_RPC.TXT and GeoTIFF RPC tags.

Pixel conventions: ASP's and DigitalGlobe's pixels (the tie point, the TLC list, the RPB) have the centre of the
first pixel at (0, 0); selfcal's at (0.5, 0.5). ASP's tie point (27728, 10702) is selfcal's (27728.5, 10702.5).
"""
import os
import shutil

import numpy as np
import pytest
import rasterio

from conftest import SHARED_DATA
from selfcal.errors import BlockError
from selfcal.io.dg import read_dg
from selfcal.io.rpc import read_rpc
from selfcal.io.rpc_gdal import (GDAL_PIXEL_ORIGIN, RPC00A_TO_RPC00B, rasterio_rpcs, read_rpb, write_rpb,
                                 write_rpc_txt)
from selfcal.sensors.dg import dg_line_times, line_image_from_dg
from selfcal.sensors.pushbroom import ecef_of, ground_to_image, image_to_ground, intersect, line_of_sight
from selfcal.sensors.rpc import RpcModel
from selfcal.sensors.vendor import line_image_from_file

DATA = os.path.join(SHARED_DATA, "pushbroom", "asp_dg_spot")
POLYNOMIALS = ("line_num", "line_den", "samp_num", "samp_den")
NORMALISATION = ("line_off", "line_scale", "samp_off", "samp_scale", "lat_off", "lat_scale", "long_off",
                 "long_scale", "height_off", "height_scale")


def path(name: str) -> str:
    return os.path.join(DATA, name)


def setup_module():
    assert os.path.isdir(DATA), f"shared test data missing: {DATA}"


_CACHE = {}


def sensor(name: str):
    if name not in _CACHE:
        _CACHE[name] = read_dg(path(name))
    return _CACHE[name]


def image(name: str, corrections=("refraction", "aberration")):
    key = (name, tuple(corrections))
    if key not in _CACHE:
        _CACHE[key] = line_image_from_dg(sensor(name), corrections=corrections)
    return _CACHE[key]


# --- reader: ASP's XMLReading test ----------------------------------------------------------------

def test_reader_reads_what_asp_reads():
    s = sensor("dg_example1.xml")
    assert s.principal_distance_mm == pytest.approx(7949.165, abs=1e-6)
    assert s.detector_origin_mm == pytest.approx((0.05372, 140.71193), abs=1e-6)
    assert s.detector_rotation_deg == 0 and s.detector_pitch_mm == pytest.approx(0.008, abs=1e-6)
    assert s.camera_attitude == (0.0, 0.0, 0.0, 1.0) and s.perspective_center_m == (0.0, 0.0, 0.0)
    assert s.attitude_dt_s == pytest.approx(0.02) and s.ephemeris_dt_s == pytest.approx(0.02)
    assert s.quaternions.shape == (840, 4) and np.all(s.quaternions[:, 3] != 0)
    assert s.quaternion_covariance.shape == (840, 10) and np.all(s.quaternion_covariance != 0)
    assert s.positions_m.shape == (840, 3) and s.velocities_m_s.shape == (840, 3)
    assert s.position_covariance.shape == (840, 6) and np.all(s.position_covariance != 0)
    assert np.all(s.positions_m[:, 0] != 0) and np.all(s.velocities_m_s[:, 0] != 0)
    np.testing.assert_allclose(s.positions_m[0], (-1.150529111070304e+06, -4.900037170821411e+06,
                                                  4.673402253879593e+06), rtol=0, atol=1e-6)
    # TLC list (0, 0 s), (23708, 1.975667 s) after TLCTIME, which is 7.753447 s after EPH/STARTTIME
    np.testing.assert_allclose(s.tlc_lines, (0, 23708), atol=1e-8)
    np.testing.assert_allclose(s.tlc_times_s - 7.753447, (0.0, 1.975667), atol=1e-8)
    assert (s.columns, s.rows) == (35170, 23708)
    assert s.has_rpb and not sensor("dg_example2.xml").has_rpb


def test_single_tlc_entry_takes_the_average_line_rate():
    """dg_example3: one TLC entry (line 101020 at TLCTIME); ASP adds the slope 1 / AVGLINERATE and checks
    that line 0 then falls on FIRSTLINETIME (within 1/10 line). selfcal's row 0.5 is line 0."""
    s = sensor("dg_example3.xml")
    times = dg_line_times(s)
    assert times.period_s == pytest.approx(1.0 / 24000.0, rel=1e-12) and times.linear
    assert abs(times.time(0.5) - s.first_line_time_s) < 0.1 / s.average_line_rate
    img = image("dg_example3.xml")
    assert img.time_of_row(0.5) == pytest.approx(times.time(0.5), abs=1e-9)


def test_reader_errors_name_file_line_and_element(tmp_path):
    with open(path("dg_example1.xml"), encoding="utf-8") as handle:
        text = handle.read()
    broken = tmp_path / "broken.xml"
    broken.write_text(text.replace("<PD>7.949165000000000e+03</PD>", ""), encoding="utf-8")
    with pytest.raises(BlockError) as info:
        read_dg(broken)
    error = info.value
    assert error.path == str(broken) and error.column == "isd/GEO/PRINCIPAL_DISTANCE/PD"
    assert error.line == text[:text.index("<PRINCIPAL_DISTANCE>")].count("\n") + 1
    assert "missing element PD" in str(error)
    broken.write_text(text.replace("<NUMPOINTS>840</NUMPOINTS>", "<NUMPOINTS>841</NUMPOINTS>", 1), encoding="utf-8")
    with pytest.raises(BlockError, match="NUMPOINTS is 841 but isd/EPH/EPHEMLISTList holds 840 EPHEMLIST"):
        read_dg(broken)
    broken.write_text(text.replace("<TLCLIST>2.370800000000000e+04 1.975667000000000e+00</TLCLIST>",
                                   "<TLCLIST>2.370800000000000e+04 x</TLCLIST>"), encoding="utf-8")
    with pytest.raises(BlockError, match="TLCLISTList/TLCLIST must hold numbers") as info:
        read_dg(broken)
    assert info.value.line == text[:text.index("<TLCLIST>2.3708")].count("\n") + 1


# --- the rigorous camera: ASP's CreateCamera test ------------------------------------------------------------

def _closest_points(S1, d1, S2, d2):
    w = S1 - S2
    a, b, c, d, e = d1 @ d1, d1 @ d2, d2 @ d2, d1 @ w, d2 @ w
    s = (b * e - c * d) / (a * c - b * b)
    t = (a * e - b * d) / (a * c - b * b)
    return S1 + s * d1, S2 + t * d2


@pytest.mark.parametrize("corrections", [("refraction", "aberration"), ()])
def test_stereo_tie_point_triangulates_as_asp_requires(corrections):
    """ASP: the tie point (13864, 5351) * 2 <-> (15045, 5183) * 2 triangulates with an intersection error
    (distance of the rays) below 5 m, below the camera, and reprojects into both images within 4 px.
    Measured (ASP's corrections / none): rays 3.32 / 3.15 m apart, the point at h = 1734 m near Golden, CO;
    reprojection of the rays' midpoint (col, row) (-2.61, -0.69) px and (3.19, 0.67) px / (-2.47, -0.65),
    (3.02, 0.64); of the least-squares intersection (-3.10, -0.81), (2.60, 0.54)."""
    cams = [image("dg_example1.xml", corrections), image("dg_example2.xml", corrections)]
    pixels = [np.array([13864.0, 5351.0]) * 2 + 0.5, np.array([15045.0, 5183.0]) * 2 + 0.5]    # (col, row)
    rays = [line_of_sight(cam, [px[1]], [px[0]]) for cam, px in zip(cams, pixels)]
    (S1, d1), (S2, d2) = [(S[0], d[0]) for S, d in rays]
    P1, P2 = _closest_points(S1, d1, S2, d2)
    assert np.linalg.norm(P1 - P2) < 5.0
    assert (P1 - S1) @ d1 > 0 and (P2 - S2) @ d2 > 0                   # in front of both cameras
    X_mid = 0.5 * (P1 + P2)
    X_lsq, _ = intersect(cams, np.array([0, 1]), np.array([p[1] for p in pixels]), np.array([p[0] for p in pixels]))
    for X in (X_mid, X_lsq):
        assert np.linalg.norm(X) < np.linalg.norm(S1)                     # below the camera
        for cam, px in zip(cams, pixels):
            row, col = ground_to_image(cam, X[None])
            assert abs(col[0] - px[0]) < 4.0 and abs(row[0] - px[1]) < 4.0


def test_project_out_and_back_on_a_500_px_grid():
    """ASP: for (i, j) on a 500-px grid (i < 30000, j < 24000), point_to_pixel(center + 2e4 m * direction)
    == (i, j) within 0.1 px. Measured: 9e-8 px (cols), 8e-9 px (rows), 2880 points."""
    cam = image("dg_example1.xml")
    i, j = np.meshgrid(np.arange(0, 30000, 500.0), np.arange(0, 24000, 500.0))
    col, row = i.ravel() + 0.5, j.ravel() + 0.5
    S, d = line_of_sight(cam, row, col)
    r, c = ground_to_image(cam, S + 2e4 * d)
    assert np.all(np.abs(c - col) < 0.1) and np.all(np.abs(r - row) < 0.1)
    assert np.max(np.abs(c - col)) < 1e-6 and np.max(np.abs(r - row)) < 1e-6


def test_lines_of_sight_look_down_and_ahead():
    """The camera looks at the Earth (the ray meets the ellipsoid in front of it); IMD's mean in-track view
    angle of dg_example1 is 32.6 deg: the body is pitched forward by about that much (measured 33.4 deg)."""
    cam = image("dg_example1.xml")
    S, d = line_of_sight(cam, [0.5, 11854.5], [0.5, 17585.5])
    assert np.all(np.einsum("ni,ni->n", -S / np.linalg.norm(S, axis=1, keepdims=True), d) > 0.8)
    X = image_to_ground(cam, [11854.5], [17585.5], 2000.0)
    assert (X[0] - S[1]) @ d[1] > 0
    roll, pitch, yaw = cam.trajectory.attitude(cam.time_of_row(np.array([11854.5])))[0]
    assert np.degrees(pitch) == pytest.approx(32.6, abs=1.5)


# --- rigorous camera against the vendor RPC of the same XML ------------------------------------------------

def rigorous_minus_rpb(name: str, corrections=("refraction", "aberration")):
    """(n, 2) row, col differences (px) on a 15 x 15 grid over the RPB's validity domain at its lowest, middle
    and highest height, points inside the image only."""
    rpc = read_rpc(path(name))
    s = sensor(name)
    lon, lat, h = np.meshgrid(np.linspace(rpc.long_off - rpc.long_scale, rpc.long_off + rpc.long_scale, 15),
                              np.linspace(rpc.lat_off - rpc.lat_scale, rpc.lat_off + rpc.lat_scale, 15),
                              [rpc.height_off - rpc.height_scale, rpc.height_off, rpc.height_off + rpc.height_scale])
    lon, lat, h = lon.ravel(), lat.ravel(), h.ravel()
    row_rpc, col_rpc = rpc.project(lon, lat, h)
    inside = (row_rpc > 0) & (row_rpc < s.rows) & (col_rpc > 0) & (col_rpc < s.columns)
    row, col = ground_to_image(image(name, corrections), ecef_of(lat[inside], lon[inside], h[inside]))
    return np.column_stack([row - row_rpc[inside], col - col_rpc[inside]])


@pytest.mark.parametrize("name, rms_px, max_px", [("dg_example1.xml", (0.30, 0.30), (0.6, 0.7)),
                                                  ("dg_example3.xml", (0.15, 0.35), (0.3, 1.0))])
def test_rigorous_camera_agrees_with_the_rpb(name, rms_px, max_px):
    """With ASP's refraction and aberration corrections the rigorous camera and the vendor's RPC00B agree to a
    fraction of a pixel over the RPB's domain x 3 heights. Measured rows / cols: dg_example1 RMS 0.22 / 0.20 px,
    max 0.38 / 0.48 px (447 points); dg_example3 RMS 0.064 / 0.27 px, max 0.14 / 0.74 px (578 points; the
    columns keep a scale of -1.5e-5 and a height-dependent shift of 0.3 px per km, the terrain height 0 m of
    ASP's refraction against the RPB's 171 m). Tolerances: the RMS and max above, about 1.5 x measured."""
    d = rigorous_minus_rpb(name)
    assert len(d) > 400
    rms, largest = np.sqrt(np.mean(d ** 2, axis=0)), np.abs(d).max(axis=0)
    assert np.all(rms < rms_px), rms
    assert np.all(largest < max_px), largest


def test_the_rpb_includes_aberration_and_refraction():
    """Without the corrections the rigorous camera misses the RPB by 23.3 px in rows and 6.9 px in columns
    (aberration 20.8 / 5.3 px, refraction 2.5 / 1.6 px): the vendor's model applies both, as ASP does."""
    d = rigorous_minus_rpb("dg_example1.xml", corrections=())
    assert np.mean(d[:, 0]) == pytest.approx(-23.3, abs=0.5) and np.mean(d[:, 1]) == pytest.approx(6.9, abs=0.5)
    d = rigorous_minus_rpb("dg_example1.xml", corrections=("refraction",))
    assert np.mean(d[:, 0]) == pytest.approx(-20.6, abs=0.5)
    d = rigorous_minus_rpb("dg_example1.xml", corrections=("aberration",))
    assert np.mean(d[:, 0]) == pytest.approx(-2.5, abs=0.5)


def test_vendor_file_entry_point():
    img = line_image_from_file(path("dg_example2.xml"), "left")
    assert img.image_id == "left" and img.rows == 27576 and img.camera.columns == 35170
    spot = line_image_from_file(path("spot_example1.xml"))
    assert spot.rows == 96168 and spot.camera.columns == 300
    with pytest.raises(BlockError, match="not a vendor sensor file"):
        line_image_from_file(path("sample.RPB"))


# --- RPC formats ------------------------------------------------------------------------------------------

def _assert_same(a: RpcModel, b: RpcModel, rtol=0.0):
    for name in POLYNOMIALS:
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=rtol, atol=0, err_msg=name)
    for name in NORMALISATION + ("pixel_origin",):
        assert getattr(a, name) == pytest.approx(getattr(b, name), rel=rtol, abs=0), name


def test_rpb_file_is_read():
    """sample.RPB (GDAL's / DigitalGlobe's keyword layout); pixel_origin 0: selfcal row = line + 0.5."""
    m = read_rpc(path("sample.RPB"))
    assert (m.line_off, m.samp_off, m.lat_off, m.long_off, m.height_off) == (531.0, 1278.0, 37.6198, -122.3733, -40.0)
    assert (m.line_scale, m.samp_scale, m.lat_scale, m.long_scale, m.height_scale) == (531.0, 1278.0, 0.0115,
                                                                                        0.0206, 580.0)
    assert m.line_num[0] == 9.318045017e-03 and m.line_num[19] == 1.342808018e-02
    assert m.samp_den[0] == 1.0 and m.samp_den[19] == -1.950670407e-03
    assert m.pixel_origin == GDAL_PIXEL_ORIGIN == 0.0
    row, col = m.project(m.long_off, m.lat_off, m.height_off)
    assert row == pytest.approx(m.line_off + m.line_num[0] * m.line_scale + 0.5)


def test_xml_rpb_block_is_the_rpb_gdal_reads_and_writes(tmp_path):
    """The DigitalGlobe XML's RPB block as we read it == as GDAL reads it (the XML beside a TIFF), and == the
    .RPB that GDAL writes from it (rasterio, RPB=YES) read by our .RPB reader: every coefficient identical."""
    ours = read_rpc(path("dg_example1.xml"))
    tif = tmp_path / "scene.TIF"
    profile = dict(driver="GTiff", width=4, height=4, count=1, dtype="uint8",
                   transform=rasterio.Affine(1.0, 0.0, 0.0, 0.0, -1.0, 4.0))
    with rasterio.open(tif, "w", **profile) as dst:
        dst.write(np.zeros((1, 4, 4), "uint8"))
    shutil.copy(path("dg_example1.xml"), tmp_path / "scene.XML")
    with rasterio.open(tif) as src:
        gdal = src.rpcs
    for name in POLYNOMIALS:
        np.testing.assert_array_equal(np.asarray(getattr(gdal, f"{name}_coeff")), getattr(ours, name))
    for name in NORMALISATION:
        assert getattr(gdal, name) == getattr(ours, name)
    written = tmp_path / "copy.tif"
    with rasterio.open(written, "w", rpcs=rasterio_rpcs(ours), RPB="YES", **profile) as dst:
        dst.write(np.zeros((1, 4, 4), "uint8"))
    _assert_same(read_rpb(tmp_path / "copy.RPB"), ours)
    _assert_same(read_rpc(tmp_path / "copy.RPB"), ours)


def _random_model(seed: int = 3, pixel_origin: float = 0.0) -> RpcModel:
    rng = np.random.default_rng(seed)
    coefficients = {name: rng.normal(0, 0.1, 20) for name in POLYNOMIALS}
    coefficients["line_den"][0] = coefficients["samp_den"][0] = 1.0
    return RpcModel(line_off=12345.678901234567, line_scale=12000.123456789, samp_off=17564.25,
                    samp_scale=17927.987654321, lat_off=39.745412345678901, lat_scale=0.10031234567,
                    long_off=-105.29031234567891, long_scale=0.134512345678, height_off=2281.123456789,
                    height_scale=637.987654321, pixel_origin=pixel_origin, **coefficients)


@pytest.mark.parametrize("writer, suffix", [(write_rpb, ".RPB"), (write_rpc_txt, "_RPC.TXT")])
def test_round_trip_keeps_every_coefficient(tmp_path, writer, suffix):
    """write -> read_rpc keeps every number exactly (17 significant digits); a model in another pixel
    convention (DIMAP, 1-based) is written 0-based: its offsets move by 1 and it projects the same."""
    model = _random_model()
    target = tmp_path / f"scene{suffix}"
    writer(model, target)
    _assert_same(read_rpc(target), model)
    dimap = _random_model(pixel_origin=1.0)
    writer(dimap, target)
    back = read_rpc(target)
    assert back.pixel_origin == 0.0 and back.line_off == dimap.line_off - 1.0 and back.samp_off == dimap.samp_off - 1.0
    lon, lat, h = dimap.long_off + 0.05, dimap.lat_off - 0.03, dimap.height_off + 100.0
    np.testing.assert_allclose(back.project(lon, lat, h), dimap.project(lon, lat, h), rtol=0, atol=1e-9)


def test_rpc_txt_in_geoeye_layout_is_read(tmp_path):
    """A _RPC.TXT as GeoEye / GDAL write it (units after the numbers, signed zero-padded values), from known
    coefficients; missing keys are errors naming file and key."""
    model = _random_model(seed=5)
    units = {"LINE": "pixels", "SAMP": "pixels", "LAT": "degrees", "LONG": "degrees", "HEIGHT": "meters"}
    lines = ["ERR_BIAS:   -1.00 meters", "ERR_RAND:    -1.00 meters"]
    for name in NORMALISATION:
        key = name.upper()
        lines.append(f"{key}: {getattr(model, name):+025.15f} {units[key.split('_')[0]]}")
    for name in POLYNOMIALS:
        lines += [f"{name.upper()}_COEFF_{k}: {c:+.20E}" for k, c in enumerate(getattr(model, name), start=1)]
    target = tmp_path / "po_12345_pan_0000000_RPC.TXT"
    target.write_text("\n".join(lines) + "\n", encoding="utf-8")
    _assert_same(read_rpc(target), model, rtol=1e-15)
    target.write_text("\n".join(line for line in lines if not line.startswith("SAMP_DEN_COEFF_7:")) + "\n",
                      encoding="utf-8")
    with pytest.raises(BlockError, match="missing key SAMP_DEN_COEFF_7") as info:
        read_rpc(target)
    assert info.value.path == str(target) and info.value.column == "SAMP_DEN_COEFF_7"


def test_geotiff_rpc_tags_round_trip_and_gdal_pixel_convention(tmp_path):
    """A GeoTIFF written by rasterio with rpcs= and read back: every number to 15 significant digits (GDAL
    hands the tag's doubles on as "%.15g" text, RPCInfoV2ToMD; measured 2.7e-15 relative); and GDAL's own RPC
    transformer (corner-based pixels, which are selfcal's) gives our
    (row, col) to 1e-9 px: pixel_origin 0 is GDAL's convention."""
    from rasterio.transform import RPCTransformer
    model = _random_model(seed=7)
    model = RpcModel(**{name: getattr(model, name) for name in NORMALISATION}, pixel_origin=0.0,
                     **{name: getattr(read_rpc(path("dg_example1.xml")), name) for name in POLYNOMIALS})
    tif = tmp_path / "rpc.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=4, height=4, count=1, dtype="uint8",
                       rpcs=rasterio_rpcs(model)) as dst:
        dst.write(np.zeros((1, 4, 4), "uint8"))
    assert not (tmp_path / "rpc.RPB").exists()
    back = read_rpc(tif)
    _assert_same(back, model, rtol=1e-14)
    lon = model.long_off + model.long_scale * np.array([-0.6, 0.0, 0.4])
    lat = model.lat_off + model.lat_scale * np.array([0.5, 0.0, -0.3])
    h = model.height_off + np.array([-300.0, 0.0, 250.0])
    with RPCTransformer(rasterio_rpcs(model)) as transformer:
        rows, cols = transformer.rowcol(lon, lat, zs=h, op=lambda x: x)
    row, col = back.project(lon, lat, h)
    np.testing.assert_allclose(row, rows, atol=1e-9)
    np.testing.assert_allclose(col, cols, atol=1e-9)


def test_rpc00a_order_is_converted(tmp_path):
    """An .RPB whose SpecId is RPC00A lists PLH before the squares (1 L P H LP LH PH PLH L2 P2 H2 ...): read, it
    is the RPC00B model it was written from."""
    model = _random_model(seed=11)
    target = tmp_path / "a.RPB"
    write_rpb(model, target)
    text = target.read_text(encoding="utf-8").replace('SpecId = "RPC00B";', 'SpecId = "RPC00A";')
    for name in POLYNOMIALS:
        b_order = [repr(float(c)) for c in getattr(model, name)]
        a_order = [b_order[RPC00A_TO_RPC00B[k]] for k in range(20)]
        listed = ",\n".join(f"\t\t{c}" for c in b_order)
        assert listed in text
        text = text.replace(listed, ",\n".join(f"\t\t{c}" for c in a_order))
    target.write_text(text, encoding="utf-8")
    _assert_same(read_rpc(target), model)


def test_rpb_reader_errors(tmp_path):
    with open(path("sample.RPB"), encoding="utf-8") as handle:
        text = handle.read()
    broken = tmp_path / "broken.RPB"
    broken.write_text(text.replace("\tlineScale =   531.0;\n", ""), encoding="utf-8")
    with pytest.raises(BlockError, match="missing key lineScale") as info:
        read_rpc(broken)
    assert info.value.path == str(broken) and info.value.column == "lineScale"
    broken.write_text(text.replace("-2.364340703e+00,", "-2.364340703e+00,\n 1.0,"), encoding="utf-8")
    with pytest.raises(BlockError, match="lineNumCoef must hold 20 coefficients, found 21") as info:
        read_rpc(broken)
    assert info.value.line == text[:text.index("lineNumCoef")].count("\n") + 1


# --- generic-model contract on the vendor cameras -------------------------------------------------------

def _vendor_cameras():
    from selfcal.io.spot import read_spot5
    from selfcal.sensors.spot import line_image_from_spot5
    return [image("dg_example1.xml"), line_image_from_spot5(read_spot5(path("spot_example1.xml")))]


def test_jacobians_of_the_vendor_cameras_match_central_differences():
    """The generic model's analytic Jacobians (photo coordinates by point and by the ten calibration
    parameters) hold on the callable trajectories of the DG and SPOT cameras: measured relative misfits 4e-11 /
    1.4e-10 (point), 6e-9 / 1.5e-10 (parameters)."""
    from selfcal.sensors.pushbroom import PARAMETER_NAMES, photo_coordinates
    for cam in _vendor_cameras():
        rows = np.array([100.5, cam.rows / 2, cam.rows - 100.5])
        cols = np.array([10.5, cam.camera.columns / 2, cam.camera.columns - 10.5])
        X = image_to_ground(cam, rows, cols, 1000.0)
        t = cam.time_of_row(rows)
        _, d_par, d_pt = photo_coordinates(cam, X, t, jacobians=True)
        numeric = np.stack([(photo_coordinates(cam, X + e, t) - photo_coordinates(cam, X - e, t)) / 1.0
                            for e in 0.5 * np.eye(3)], -1)
        assert np.abs(numeric - d_pt).max() < 1e-8 * np.abs(d_pt).max()
        columns = []
        for k in range(len(PARAMETER_NAMES)):
            h = 1e-3 if PARAMETER_NAMES[k] == "focal" else (1e-8 if PARAMETER_NAMES[k].endswith("1") else 1e-7)
            plus, minus = cam.parameters.copy(), cam.parameters.copy()
            plus[k] += h
            minus[k] -= h
            columns.append((photo_coordinates(cam.with_parameters(plus), X, t)
                            - photo_coordinates(cam.with_parameters(minus), X, t)) / (2 * h))
        assert np.abs(np.stack(columns, -1) - d_par).max() < 1e-7 * np.abs(d_par).max()


def test_tlc_list_with_two_line_rates():
    """A TLC list whose line rate changes (1 % after line 10000): the image runs on a pseudo time linear in
    the row and every line is taken at its TLC time; rows of a ray's ground point come back within 1e-6 px."""
    from dataclasses import replace
    s = sensor("dg_example1.xml")
    t0, slope = s.tlc_times_s[0], (s.tlc_times_s[1] - s.tlc_times_s[0]) / s.tlc_lines[1]
    times = np.array([t0, t0 + 10000 * slope, t0 + 10000 * slope + 13708 * slope * 1.01])
    warped = replace(s, tlc_lines=np.array([0.0, 10000.0, 23708.0]), tlc_times_s=times)
    cam = line_image_from_dg(warped, corrections=())
    assert not dg_line_times(warped).linear
    rows = np.array([0.5, 5000.5, 10000.5, 20000.5])
    S, d = line_of_sight(cam, rows, np.full(4, 17000.5))
    true_t = np.interp(rows - 0.5, warped.tlc_lines, times)
    position = cam.trajectory.position.function(true_t)            # the series at the TLC times
    np.testing.assert_allclose(S, position, atol=1e-6)
    r, c = ground_to_image(cam, S + 6e5 * d)
    np.testing.assert_allclose(r, rows, atol=1e-6)
    np.testing.assert_allclose(c, 17000.5, atol=1e-6)


def test_camera_attitude_and_perspective_centre_enter_once():
    """GEO/CAMERA_ATTITUDE (camera -> body) and PERSPECTIVE_CENTER (body frame): a file whose body quaternions
    are turned by QCS^-1 and whose camera is mounted with QCS sees exactly what the original sees; a
    perspective centre offset c moves every camera position by R(q) c."""
    from dataclasses import replace
    from selfcal.geometry.rotation import matrix_from_quaternion, quaternion_from_matrix
    s = sensor("dg_example1.xml")
    qcs = np.array([0.02, -0.01, 0.03, 1.0])
    qcs /= np.linalg.norm(qcs)
    R_qcs = matrix_from_quaternion(qcs, scalar_first=False)
    R_body = matrix_from_quaternion(s.quaternions, scalar_first=False) @ R_qcs.T
    mounted = replace(s, camera_attitude=tuple(qcs), quaternions=quaternion_from_matrix(R_body, scalar_first=False),
                      perspective_center_m=(1.0, -2.0, 0.5))
    rows, cols = np.array([0.5, 12000.5, 23700.5]), np.array([0.5, 17000.5, 35000.5])
    S0, d0 = line_of_sight(image("dg_example1.xml"), rows, cols)
    S1, d1 = line_of_sight(line_image_from_dg(mounted), rows, cols)
    np.testing.assert_allclose(d1, d0, atol=1e-12)
    plain = image("dg_example1.xml", ())
    R_camera = plain.trajectory.attitude.rotation(plain.time_of_row(rows))        # camera -> ECF, uncorrected
    expected = np.einsum("nij,j->ni", R_camera @ R_qcs.T, np.array([1.0, -2.0, 0.5]))
    np.testing.assert_allclose(S1 - S0, expected, atol=1e-6)
