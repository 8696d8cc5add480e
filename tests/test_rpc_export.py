"""``selfcal export rpc`` and the NITF RPC reader, checked with GDAL's own RPC reader and transformer (rasterio).

GDAL reads the exported file the way a user's GDAL does: an ``IMAGE.RPB`` / ``IMAGE_RPC.TXT`` beside ``IMAGE.tif``
(GDAL's sidecar search, ``GDALFindAssociatedFile``), ``rasterio.open(IMAGE.tif).rpcs``, then
``rasterio.transform.RPCTransformer`` (GDAL's ``GDALCreateRPCTransformerV2``) takes ground points to GDAL's pixel
and line. GDAL's pixel coordinates put (0, 0) at the upper-left corner of the image, as selfcal does (gdal_rpc.cpp
``RPCTransformPoint`` adds 0.5 to the RPC's centre-based line and sample): the transformer's (row, col) are
compared with selfcal's adjusted model directly, so a half-pixel mistake shows as 0.5 px.

Truth: an ``rpc`` block of one Pleiades image (CNES shareloc's RPC, ../shared/data) whose GCPs are seen by the RPC
with a known bias (shift or affine) and 0.1 px noise; a ``dimap`` block of a Pleiades primary image whose attitude
has known roll, pitch and yaw biases (tests/test_vendor_blocks.py's block writer).
"""
import csv
import os
import shutil

import numpy as np
import pytest
import rasterio
import rasterio.shutil
from rasterio.transform import RPCTransformer

from selfcal.errors import BlockError
from selfcal.geometry.earth import ecef_from_geodetic, geodetic_from_ecef
from selfcal.io import read_block
from selfcal.io.rpc import read_rpc
from selfcal.io.rpc_gdal import rasterio_rpcs
from selfcal.sensors.pushbroom import ground_to_image, image_to_ground
from selfcal.sensors.rpc import RpcBias, RpcModel
from selfcal.sensors.rpc_fit import FIT_GRID, check_grid
from selfcal.sensors.vendor import line_image_from_file

from conftest import SHARED_DATA, run_cli

RPC_DIR = os.path.join(SHARED_DATA, "pushbroom", "pleiades", "rpc")
IMAGE = "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001"
#: the same RPC as DIMAP XML (1-based pixel centres) and OSSIM .geom (0-based)
DIMAP_XML, GEOM = os.path.join(RPC_DIR, f"RPC_{IMAGE}.XML"), os.path.join(RPC_DIR, f"{IMAGE}.geom")
BIASES = {"shift": RpcBias((3.2, 0.0, 0.0), (-1.7, 0.0, 0.0), "shift"),
          "affine": RpcBias((3.2, 2e-5, -3e-5), (-1.7, 1e-5, 4e-5))}
NOISE_PX = 0.1


def _write_rpc_block(folder, kind: str, sensor_file: str, n: int = 30, seed: int = 1):
    """A block of one rpc image (``sensor_file`` copied in) and n GCPs seen with the bias of ``kind`` + noise."""
    os.makedirs(folder)
    model = read_rpc(sensor_file)
    rng = np.random.default_rng(seed)
    rows = model.line_off + model.pixel_shift + model.line_scale * rng.uniform(-0.9, 0.9, n)
    cols = model.samp_off + model.pixel_shift + model.samp_scale * rng.uniform(-0.9, 0.9, n)
    h = model.height_off + model.height_scale * rng.uniform(-0.5, 0.5, n)
    lon, lat = model.localize(rows, cols, h)
    row, col = BIASES[kind].project(model, lon, lat, h)
    row, col = row + rng.normal(0, NOISE_PX, n), col + rng.normal(0, NOISE_PX, n)
    xyz = ecef_from_geodetic(np.radians(lat), np.radians(lon), h)
    name = os.path.basename(sensor_file)
    shutil.copy(sensor_file, os.path.join(folder, name))
    with open(os.path.join(folder, "block.toml"), "w") as f:
        f.write(f'name = "rpc"\ncrs = "EPSG:4978"\n[cameras.sat]\nmodel = "rpc"\nbias = "{kind}"\n'
                f"[observations]\nimage_sigma_px = {NOISE_PX}\n")
    with open(os.path.join(folder, "images.csv"), "w") as f:
        f.write("image_id,camera_id,strip_id,time_s,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sensor_file\n"
                f"img,sat,,,,,,,,,{name}\n")
    with open(os.path.join(folder, "points.csv"), "w") as f:
        f.write("point_id,role,X,Y,Z,sigma_xy_m,sigma_z_m\n")
        f.writelines(f"p{j},gcp,{x:.4f},{y:.4f},{z:.4f},0.01,0.01\n" for j, (x, y, z) in enumerate(xyz))
    with open(os.path.join(folder, "observations.csv"), "w") as f:
        f.write("image_id,point_id,col_px,row_px\n")
        f.writelines(f"img,p{j},{c:.5f},{r:.5f}\n" for j, (c, r) in enumerate(zip(col, row)))


def _parameters(results) -> dict:
    """parameters.csv as {(owner, parameter): (value, sigma)} in the file's units."""
    with open(os.path.join(results, "parameters.csv")) as handle:
        return {(r["owner"], r["parameter"]): (float(r["value"]), float(r["sigma"] or "nan"))
                for r in csv.DictReader(handle)}


def _gdal_rowcol(written, lon, lat, h):
    """GDAL's (row, col) of ground points through the RPC file ``written`` found beside a TIFF of the same name."""
    stem = str(written)[:-len("_RPC.TXT")] if str(written).upper().endswith("_RPC.TXT") else str(written)[:-4]
    if not os.path.exists(stem + ".tif"):          # (GDAL's Create would delete the sidecar of an existing one)
        with rasterio.open(stem + ".tif", "w", driver="GTiff", width=4, height=4, count=1, dtype="uint8",
                           transform=rasterio.Affine(1.0, 0.0, 0.0, 0.0, -1.0, 4.0)) as dst:
            dst.write(np.zeros((1, 4, 4), "uint8"))
    with rasterio.open(stem + ".tif") as src:
        rpcs = src.rpcs
    assert rpcs is not None, "GDAL found no RPC beside the TIFF"
    with RPCTransformer(rpcs) as transformer:
        rows, cols = transformer.rowcol(lon, lat, zs=h, op=lambda x: x)
    return np.asarray(rows, float), np.asarray(cols, float)


def _image_grid(rows_px, cols_px, heights, n=15):
    """(row, col, h) on an n x n grid over the whole image (edges included) at 5 heights over the range."""
    row, col, h = np.meshgrid(np.linspace(0, rows_px, n), np.linspace(0, cols_px, n),
                              np.linspace(heights[0], heights[1], 5), indexing="ij")
    return row.ravel(), col.ravel(), h.ravel()


@pytest.fixture(scope="module")
def rpc_results(tmp_path_factory):
    """kind -> (block, results) of the shift block (DIMAP XML RPC, 1-based) and the affine one (.geom, 0-based)."""
    root = tmp_path_factory.mktemp("rpc_export")
    out = {}
    for kind, source in (("shift", DIMAP_XML), ("affine", GEOM)):
        block, results = root / f"block_{kind}", root / f"results_{kind}"
        _write_rpc_block(block, kind, source)
        assert run_cli("adjust", str(block), "--out", str(results), "--no-report", "--quiet") == 0
        out[kind] = (block, results)
    return out


def test_shift_bias_is_folded_into_the_offsets_exactly(rpc_results, tmp_path, capsys):
    """Shift (3.2, -1.7) px: recovered within 4 sigma; the .RPB's lineOffset / sampOffset are the DIMAP RPC's
    LINE_OFF / SAMP_OFF moved to GDAL's 0-based centres (-1) plus a0 / b0 (px, unscaled), every coefficient the
    vendor's; GDAL's transformer on that file gives selfcal's adjusted (row, col) over the image and its heights
    within 0.01 px (measured 1e-9 px), and the true biased RPC's within 0.05 px (the estimate's error)."""
    block, results = rpc_results["shift"]
    p = _parameters(results)
    for name, true in (("a0", 3.2), ("b0", -1.7)):
        value, sigma = p[("img", name)]
        assert abs(value - true) < 4 * sigma, (name, value, sigma)
    written = tmp_path / "scene.RPB"
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img", "--out", str(written)) == 0
    assert "exact" in capsys.readouterr().err
    vendor = read_rpc(DIMAP_XML)
    assert vendor.pixel_origin == 1.0
    text = {line.split("=")[0].strip(): line.split("=")[1].strip(" ;") for line in written.read_text().splitlines()
            if "=" in line and "(" not in line}
    a0, b0 = p[("img", "a0")][0], p[("img", "b0")][0]
    assert float(text["lineOffset"]) == pytest.approx(vendor.line_off - 1.0 + a0, abs=1e-9)
    assert float(text["sampOffset"]) == pytest.approx(vendor.samp_off - 1.0 + b0, abs=1e-9)
    back = read_rpc(written)
    for name in ("line_num", "line_den", "samp_num", "samp_den"):
        np.testing.assert_array_equal(getattr(back, name), getattr(vendor, name))

    bias = RpcBias.from_parameters("shift", [a0, b0])
    rows_px, cols_px = 2 * vendor.line_scale, 2 * vendor.samp_scale
    row, col, h = _image_grid(rows_px, cols_px, (vendor.height_off - vendor.height_scale,
                                                 vendor.height_off + vendor.height_scale))
    lon, lat = bias.localize(vendor, row, col, h)                 # selfcal's adjusted model: ground of each pixel
    g_row, g_col = _gdal_rowcol(written, lon, lat, h)
    worst = np.max(np.hypot(g_row - row, g_col - col))
    print(f"shift: GDAL vs selfcal's adjusted model, max {worst:.2e} px over {len(row)} points")
    assert worst < 0.01
    t_row, t_col = BIASES["shift"].project(vendor, lon, lat, h)
    assert np.max(np.hypot(g_row - t_row, g_col - t_col)) < 0.05
    # the first pixel's centre: selfcal (0.5, 0.5) is GDAL's (0.5, 0.5), i.e. the RPC's (line, samp) = (0, 0)
    lon0, lat0 = bias.localize(vendor, 0.5, 0.5, vendor.height_off)
    np.testing.assert_allclose(_gdal_rowcol(written, [lon0], [lat0], [vendor.height_off]), [[0.5], [0.5]], atol=1e-6)


def test_affine_bias_is_refitted_and_its_reported_misfit_is_what_gdal_measures(rpc_results, tmp_path, capsys):
    """Affine bias: recovered within 4 sigma; the RPC fitted on the 21 x 21 x 7 grid, written as _RPC.TXT, read by
    GDAL: within 0.01 px of selfcal's adjusted model on an independent 15 x 15 x 5 grid (measured 2.5e-6 px), and
    on the exporter's check grid GDAL measures the rms and max the exporter printed (to their 3 digits)."""
    block, results = rpc_results["affine"]
    p = _parameters(results)
    names = ("a0", "a1", "a2", "b0", "b1", "b2")
    for name, true in zip(names, BIASES["affine"].parameters):
        value, sigma = p[("img", name)]
        assert abs(value - true) < 4 * sigma, (name, value, sigma)
    written = tmp_path / "scene_RPC.TXT"
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img", "--out", str(written)) == 0
    err = capsys.readouterr().err
    reported_rms = float(err.split("misfit ")[1].split(" px rms")[0])
    reported_max = float(err.split("px rms, ")[1].split(" px max")[0])

    vendor = read_rpc(GEOM)
    bias = RpcBias.from_parameters("affine", [p[("img", n)][0] for n in names])
    heights = (vendor.height_off - vendor.height_scale, vendor.height_off + vendor.height_scale)
    rows_px, cols_px = vendor.line_off + 0.5 + vendor.line_scale, vendor.samp_off + 0.5 + vendor.samp_scale
    row, col, h = _image_grid(rows_px, cols_px, heights)
    lon, lat = bias.localize(vendor, row, col, h)
    g_row, g_col = _gdal_rowcol(written, lon, lat, h)
    worst = np.max(np.hypot(g_row - row, g_col - col))
    print(f"affine: GDAL vs selfcal's adjusted model, max {worst:.2e} px over {len(row)} points; reported "
          f"{reported_rms:.3g} / {reported_max:.3g} px")
    assert worst < 0.01

    row, col, h = check_grid(rows_px, cols_px, heights, FIT_GRID)
    lon, lat = bias.localize(vendor, row, col, h)
    t_row, t_col = bias.project(vendor, lon, lat, h)
    g_row, g_col = _gdal_rowcol(written, lon, lat, h)
    d = np.hypot(g_row - t_row, g_col - t_col)
    assert np.sqrt(np.mean(d ** 2)) == pytest.approx(reported_rms, rel=6e-3)
    assert np.max(d) == pytest.approx(reported_max, rel=6e-3)


@pytest.mark.parametrize("case, image_id, limit_px", [("pleiades", "phr", 0.01), ("dg-stereo", "left", 0.1)])
def test_rigorous_line_camera_gets_a_fitted_rpc(case, image_id, limit_px, tmp_path, capsys):
    """A vendor line camera adjusted with known attitude biases (M2; tests/test_vendor_blocks.py's block): its RPC,
    fitted to the adjusted physical model over the image and the adjusted points' heights (-89 .. 400 m) and read
    by GDAL beside a TIFF, against that model on an independent 15 x 15 x 5 grid, and on the exporter's check grid
    the rms and max it printed; and against the true (biased) camera within 0.3 px (the adjustment's own error).
    ``--image all --out rpcs/{image}.RPB`` writes one file per image.

    Pleiades DIMAP (49826 lines x 39951 detectors): within 0.01 px (measured 3.0e-4 px; reported 1.9e-4 max).
    DigitalGlobe (dg_example1, 23708 x 35170): the best a cubic RPC does is 0.055 px max, 0.027 px rms on the check
    grid, 0.072 px max on the 15 x 15 x 5 grid (its edges included); a 41 x 41 x 9 fit grid gives 0.064 px, so it
    is not the grid's density: the physical model has
    detail of a few hundredths of a pixel (the attitude's Lagrange interpolation of 0.02 s samples, ASP's
    aberration and refraction per line) that no cubic follows; asserted below 0.1 px."""
    from selfcal.workflows.export_rpc import points_height_range
    from test_vendor_blocks import CASES, TRUTH, _biased, _write_block
    model, images, sensor_model = CASES[case]
    block, results = tmp_path / "block", tmp_path / "results"
    _write_block(block, model, images, np.random.default_rng(11), TRUTH)
    assert run_cli("adjust", str(block), "--out", str(results), "--sensor-model", sensor_model, "--keep-focal",
                   "--snoop", "0", "--no-report", "--quiet") == 0
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "all",
                   "--out", str(tmp_path / "rpcs" / "{image}.RPB")) == 0
    assert sorted(os.listdir(tmp_path / "rpcs")) == sorted(f"{i}.RPB" for i, _ in images)
    written = tmp_path / "rpcs" / f"{image_id}.RPB"
    err = next(line for line in capsys.readouterr().err.splitlines() if line.startswith(f"image {image_id} "))
    reported_rms = float(err.split("misfit ")[1].split(" px rms")[0])
    reported_max = float(err.split("px rms, ")[1].split(" px max")[0])

    # selfcal's adjusted model, built here from parameters.csv (degrees) and the vendor file
    p = _parameters(results)
    k = [i for i, _ in images].index(image_id)
    nominal = line_image_from_file(images[k][1], image_id)
    values = nominal.parameters.copy()
    for j, name in enumerate(("d_roll0", "d_roll1", "d_pitch0", "d_pitch1", "d_yaw0", "d_yaw1")):
        values[j] = np.radians(p[(image_id, name)][0])
    adjusted = nominal.with_parameters(values)
    with open(results / "points.csv") as handle:
        xyz = np.array([[float(r[c]) for c in "XYZ"] for r in csv.DictReader(handle)])
    heights = points_height_range(xyz)

    def ground(row, col, h):
        lat, lon, _ = geodetic_from_ecef(image_to_ground(adjusted, row, col, h))
        return np.degrees(lon), np.degrees(lat)

    row, col, h = _image_grid(nominal.rows, nominal.camera.columns, heights)
    g_row, g_col = _gdal_rowcol(written, *ground(row, col, h), h)
    worst = np.max(np.hypot(g_row - row, g_col - col))
    print(f"{case}: GDAL vs selfcal's adjusted physical model, max {worst:.2e} px over {len(row)} points (heights "
          f"{heights[0]:.0f} .. {heights[1]:.0f} m); reported {reported_rms:.3g} / {reported_max:.3g} px")
    assert worst < limit_px
    t_row, t_col = ground_to_image(_biased(nominal, TRUTH[k]), image_to_ground(adjusted, row, col, h))
    assert np.max(np.hypot(g_row - t_row, g_col - t_col)) < 0.3

    row, col, h = check_grid(nominal.rows, nominal.camera.columns, heights)
    lon, lat = ground(row, col, h)
    m_row, m_col = ground_to_image(adjusted, ecef_from_geodetic(np.radians(lat), np.radians(lon), h))
    g_row, g_col = _gdal_rowcol(written, lon, lat, h)
    d = np.hypot(g_row - m_row, g_col - m_col)
    assert np.sqrt(np.mean(d ** 2)) == pytest.approx(reported_rms, rel=6e-3)
    assert np.max(d) == pytest.approx(reported_max, rel=6e-3)


# --- NITF -------------------------------------------------------------------------------------------

def _nitf_model() -> RpcModel:
    """The shareloc RPC with every number as an RPC00B TRE holds it (7 significant digits and a one-digit exponent:
    coefficients below 1e-9 are 0; whole-pixel image offsets, 4-decimal ground offsets, whole-metre height
    offset). GDAL writes a number the TRE cannot hold into a .aux.xml beside the NITF instead."""
    m = read_rpc(GEOM)
    coefficients = {n: np.array([float(f"{c:.6e}") if abs(c) >= 1e-9 else 0.0 for c in getattr(m, n)])
                    for n in ("line_num", "line_den", "samp_num", "samp_den")}
    return RpcModel(line_off=11469.0, line_scale=11470.0, samp_off=19999.0, samp_scale=20000.0,
                    lat_off=43.6773, lat_scale=0.0591, long_off=7.1138, long_scale=0.0769, height_off=670.0,
                    height_scale=630.0, pixel_origin=0.0, **coefficients)


def test_nitf_rpc00b_is_read_through_the_one_entry_point(tmp_path):
    """A NITF 2.1 written by GDAL's NITF driver (CreateCopy of a raster with RPCs writes the RPC00B TRE): read_rpc
    finds it from the header, reads what the TRE holds (every number equal), and projects as GDAL's transformer on
    the NITF's own RPCs does (1e-9 px); a block naming the NITF as an rpc image's sensor_file reads it too; a NITF
    without the TRE is an error naming the file."""
    model = _nitf_model()
    source = "/vsimem/rpc_source.tif"
    with rasterio.open(source, "w", driver="GTiff", width=4, height=4, count=1, dtype="uint8",
                       rpcs=rasterio_rpcs(model)) as dst:
        dst.write(np.zeros((1, 4, 4), "uint8"))
    ntf = tmp_path / "scene.ntf"
    rasterio.shutil.copy(source, str(ntf), driver="NITF")
    rasterio.shutil.delete(source)
    assert not (tmp_path / "scene.ntf.aux.xml").exists() and len(os.listdir(tmp_path)) == 1
    with rasterio.open(ntf) as src:
        assert src.driver == "NITF" and "RPC00B" in src.tags(ns="TRE")
        gdal_rpcs = src.rpcs
    back = read_rpc(ntf)
    assert back.pixel_origin == 0.0
    for name in ("line_off", "line_scale", "samp_off", "samp_scale", "lat_off", "lat_scale", "long_off", "long_scale",
                 "height_off", "height_scale"):
        assert getattr(back, name) == pytest.approx(getattr(model, name), rel=1e-12), name
    for name in ("line_num", "line_den", "samp_num", "samp_den"):
        np.testing.assert_allclose(getattr(back, name), getattr(model, name), rtol=1e-12)
    lon = model.long_off + model.long_scale * np.array([-0.7, 0.0, 0.5])
    lat = model.lat_off + model.lat_scale * np.array([0.6, 0.0, -0.4])
    h = model.height_off + np.array([-500.0, 0.0, 400.0])
    with RPCTransformer(gdal_rpcs) as transformer:
        rows, cols = transformer.rowcol(lon, lat, zs=h, op=lambda x: x)
    np.testing.assert_allclose(np.stack(back.project(lon, lat, h)), np.stack([rows, cols]), rtol=0, atol=1e-9)

    block = tmp_path / "block"
    _write_rpc_block(block, "shift", GEOM, n=5)
    shutil.copy(ntf, block / "scene.ntf")
    images = (block / "images.csv").read_text().replace(os.path.basename(GEOM), "scene.ntf")
    (block / "images.csv").write_text(images)
    assert read_block(block).image_models["img"].line_off == 11469.0

    plain = tmp_path / "plain.ntf"
    with rasterio.open(plain, "w", driver="NITF", width=4, height=4, count=1, dtype="uint8",
                       transform=rasterio.Affine(1.0, 0.0, 0.0, 0.0, -1.0, 4.0)) as dst:
        dst.write(np.zeros((1, 4, 4), "uint8"))
    with pytest.raises(BlockError, match=r"plain\.ntf: the NITF has no RPC \(no RPC00B TRE\)"):
        read_rpc(plain)


# --- bad input --------------------------------------------------------------------------------------

def test_bad_requests_exit_with_two_and_write_nothing(rpc_results, tmp_path, capsys):
    """An image not in the results (alone or in a list), several images without {image} in --out, an --out that is
    neither .RPB, _RPC.TXT nor .tif, a .tif without --raster, a
    --raster that does not exist, --heights MAX below MIN, results whose camera.json is not the block's camera or has
    active APs: exit 2 naming the option or file, no file written (a frame camera, which has no RPC:
    tests/front_door.py)."""
    block, results = rpc_results["shift"]
    out = tmp_path / "x.RPB"
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "nope", "--out", str(out)) == 2
    assert "--image nope: not an image of" in capsys.readouterr().err
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img,nope",
                   "--out", str(tmp_path / "{image}.RPB")) == 2
    assert "--image img,nope: nope: not an image of" in capsys.readouterr().err
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img,img", "--out", str(out)) == 2
    assert "--out needs {image}" in capsys.readouterr().err
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img",
                   "--out", str(tmp_path / "x.jpg")) == 2
    assert ".RPB or _RPC.TXT" in capsys.readouterr().err
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img",
                   "--out", str(tmp_path / "x.tif")) == 2
    assert "--raster goes with --out NAME.tif" in capsys.readouterr().err
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img", "--raster",
                   str(tmp_path / "missing.tif"), "--out", str(tmp_path / "x.tif")) == 2
    assert "missing.tif" in capsys.readouterr().err
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img", "--heights", "5,1",
                   "--out", str(out)) == 2
    assert "--heights" in capsys.readouterr().err
    import json
    for change, message in ((lambda c: c.update(model="dimap"), "an adjustment of --block"),
                            (lambda c: c["ap"].update(n_active=3, spec="wavelet1d:db4"), "3 active additional")):
        other = tmp_path / "other_results"
        shutil.rmtree(other, ignore_errors=True)
        shutil.copytree(results, other)
        camera = json.loads((other / "camera.json").read_text())
        change(camera["cameras"]["sat"])
        (other / "camera.json").write_text(json.dumps(camera))
        assert run_cli("export", "rpc", str(other), "--block", str(block), "--image", "img", "--out", str(out)) == 2
        assert message in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "x.tif").exists() and not (tmp_path / "x.jpg").exists()
    assert not (tmp_path / "img.RPB").exists()
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".tmp-")]


# --- the fit (selfcal.sensors.rpc_fit) ----------------------------------------------------------------

@pytest.mark.parametrize("path", [os.path.join(SHARED_DATA, "pushbroom", "asp_dg_spot", "dg_example1.xml"), DIMAP_XML],
                         ids=["dg_example1", "pleiades_dimap_rpc"])
def test_fit_recovers_a_known_rpc(path):
    """The sensor *is* an RPC (DigitalGlobe's, 0-based; Pleiades', 1-based, whose denominators are not 1): the fit
    on the 21 x 21 x 7 grid over its image and height range reproduces it on 2000 random points of that cube within
    1e-3 px (measured 5e-6 and 4e-6 px), and its reported check-grid misfit is what an independent measurement on
    the check grid gives."""
    name = os.path.basename(path)
    truth = read_rpc(path)
    rows_px, cols_px = (truth.line_off + truth.pixel_shift + truth.line_scale,
                        truth.samp_off + truth.pixel_shift + truth.samp_scale)
    heights = (truth.height_off - truth.height_scale, truth.height_off + truth.height_scale)
    from selfcal.sensors.rpc_fit import fit_rpc
    fit = fit_rpc(truth.project, truth.localize, rows_px, cols_px, heights)
    rng = np.random.default_rng(4)
    row, col = rng.uniform(0, rows_px, 2000), rng.uniform(0, cols_px, 2000)
    h = rng.uniform(*heights, 2000)
    lon, lat = truth.localize(row, col, h)
    ok = np.isfinite(lon)
    assert ok.all()
    worst = np.max(np.hypot(*(np.stack(fit.model.project(lon[ok], lat[ok], h[ok])) - np.stack([row[ok], col[ok]]))))
    print(f"{name}: refitted RPC vs the RPC, max {worst:.2e} px; reported check grid {fit.check_max_px:.2e} px")
    assert worst < 1e-3 and fit.check_max_px < 1e-3 and fit.model.pixel_origin == 0.5
    c_row, c_col, c_h = check_grid(rows_px, cols_px, heights)
    c_lon, c_lat = truth.localize(c_row, c_col, c_h)
    d = np.hypot(*(np.stack(fit.model.project(c_lon, c_lat, c_h)) - np.stack(truth.project(c_lon, c_lat, c_h))))
    assert np.max(d) == pytest.approx(fit.check_max_px, rel=1e-9)
    assert np.sqrt(np.mean(d ** 2)) == pytest.approx(fit.check_rms_px, rel=1e-9)


def test_fit_refuses_what_it_cannot_fit():
    from selfcal.sensors.rpc_fit import fit_rpc
    truth = read_rpc(GEOM)
    with pytest.raises(ValueError, match="min < max"):
        fit_rpc(truth.project, truth.localize, 100.0, 100.0, (10.0, 10.0))
    with pytest.raises(ValueError, match="at least 4 nodes"):
        fit_rpc(truth.project, truth.localize, 100.0, 100.0, (0.0, 10.0), grid=(3, 21, 7))
    with pytest.raises(ValueError, match="localises only 0"):
        fit_rpc(truth.project, lambda r, c, h: (np.full(np.shape(r), np.nan),) * 2, 100.0, 100.0, (0.0, 10.0))


def test_an_rpc_cannot_follow_the_joins_of_prisms_ccd_chips():
    """Honest limit: the simulated PRISM nadir camera (14000 lines x 14496 detectors on three CCD chips offset by up
    to 0.6 px along and 0.5 px across track, seed 001's Fig. 1) is a smooth function of the ground only within each
    chip; a cubic RPC, smooth across the joins, misses the adjusted model by 0.3-0.4 px rms and about 1 px near the
    joins (measured 0.39 px rms, 1.24 px max on the check grid). The same camera without chip offsets is fitted
    to 1.5e-4 px. The pushbroom sensor's image_geometry is the model the adjustment uses (attitude corrections and
    focal length applied)."""
    from dataclasses import replace
    from selfcal.sensors import sensor_of
    from selfcal.sensors.rpc_fit import fit_rpc
    from selfcal.simulate.prism import prism_block, simulate_prism
    block = prism_block(simulate_prism(seed=1), seed=1)
    k = [str(i) for i in block.images.image_id].index("N")
    camera = block.cameras["N"]
    sensor = sensor_of(camera)
    corrections = np.array([2e-6, 0.0, -3e-6, 0.0, 1e-5, 0.0])
    misfits = {}
    for chips in (True, False):
        b = block if chips else replace(block, cameras={**block.cameras,
                                                       "N": replace(camera, chip_starts=(), chip_offsets_px=())})
        geometry = sensor.image_geometry(b, k, corrections, np.array([camera.focal_mm + 0.05, 0.0, 0.0, 0.0]))
        fit = fit_rpc(geometry.project, geometry.localize, geometry.rows_px, geometry.cols_px, (300.0, 1160.0))
        misfits[chips] = fit.check_rms_px, fit.check_max_px
    print(f"PRISM N: check grid rms / max with chips {misfits[True]}, without {misfits[False]} px")
    assert misfits[True][0] > 0.2 and misfits[True][1] > 0.5
    assert misfits[False][1] < 0.01


def test_geotiff_copy_carries_the_adjusted_rpc(tmp_path, capsys):
    """--out NAME.tif --raster IMAGE: a small image (the Pleiades RPC's image normalisation divided by 100: 229 x
    400 px) as the vendor delivers it, a GeoTIFF with the vendor RPC in its tags; after a shift adjustment the copy
    has the same pixels and, as GDAL reads its tags, the adjusted RPC: GDAL's transformer on it gives selfcal's
    adjusted (row, col) within 0.01 px (measured 1e-9 px) where the source's tags are 3.6 px off (the shift). A
    crop of the image (100 of its 400 columns) is refused: the RPC is in the full image's pixels."""
    from dataclasses import replace
    from selfcal.io.rpc_gdal import write_rpb
    vendor = read_rpc(GEOM)
    small = replace(vendor, **{n: getattr(vendor, n) / 100.0 for n in ("line_off", "line_scale", "samp_off",
                                                                       "samp_scale")})
    write_rpb(small, tmp_path / "small.RPB")
    block, results = tmp_path / "block", tmp_path / "results"
    _write_rpc_block(block, "shift", str(tmp_path / "small.RPB"))
    assert run_cli("adjust", str(block), "--out", str(results), "--no-report", "--quiet") == 0
    p = _parameters(results)
    bias = RpcBias.from_parameters("shift", [p[("img", "a0")][0], p[("img", "b0")][0]])

    rows_px, cols_px = 229, 400
    pixels = np.random.default_rng(2).integers(0, 4000, (1, rows_px, cols_px)).astype("uint16")
    source = tmp_path / "vendor.tif"
    with rasterio.open(source, "w", driver="GTiff", width=cols_px, height=rows_px, count=1, dtype="uint16",
                       rpcs=rasterio_rpcs(small)) as dst:
        dst.write(pixels)
    out = tmp_path / "adjusted.tif"
    crop = tmp_path / "crop.tif"
    with rasterio.open(crop, "w", driver="GTiff", width=100, height=rows_px, count=1, dtype="uint16",
                       rpcs=rasterio_rpcs(small)) as dst:
        dst.write(pixels[:, :, :100])
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img", "--raster", str(crop),
                   "--out", str(out)) == 2
    assert "crop.tif is 100 x 229 px, image img 400 x 230 px" in capsys.readouterr().err and not out.exists()
    assert run_cli("export", "rpc", str(results), "--block", str(block), "--image", "img", "--raster", str(source),
                   "--out", str(out)) == 0
    with rasterio.open(out) as src:
        assert src.driver == "GTiff" and (src.height, src.width) == (rows_px, cols_px)
        np.testing.assert_array_equal(src.read(), pixels)
        rpcs = src.rpcs
    row, col, h = _image_grid(rows_px, cols_px, (small.height_off - small.height_scale,
                                                 small.height_off + small.height_scale))
    lon, lat = bias.localize(small, row, col, h)
    with RPCTransformer(rpcs) as transformer:
        g_row, g_col = (np.asarray(v, float) for v in transformer.rowcol(lon, lat, zs=h, op=lambda x: x))
    worst = np.max(np.hypot(g_row - row, g_col - col))
    print(f"GeoTIFF copy: GDAL vs selfcal's adjusted model, max {worst:.2e} px")
    assert worst < 0.01
    with RPCTransformer(rasterio_rpcs(small)) as transformer:
        v_row, v_col = (np.asarray(v, float) for v in transformer.rowcol(lon, lat, zs=h, op=lambda x: x))
    assert np.min(np.hypot(v_row - row, v_col - col)) > 3.0
