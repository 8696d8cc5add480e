"""Results others can consume (issue 23 item 6): ``selfcal --version``, ``import selfcal``, the JSON Schema of
summary.json, check points as GeoJSON and object points as PLY, each read by the other tool's own reader
(jsonschema, GDAL/OGR through pyogrio, plyfile), and the progress on ``logging.getLogger("selfcal")``."""
import dataclasses
import importlib.metadata
import json
import logging
import subprocess

import jsonschema
import numpy as np
import pytest
from plyfile import PlyData

from conftest import run_cli, simulation
from selfcal.io import write_block
from selfcal.io.results import read_results, summary_schema


def _block():
    """A small UAV block (Type 1: 15 GCP, 24 CHK) placed in UTM zone 11N."""
    block = simulation(seed=2, distortion="none", points_per_mm2=0.05).blocks["type1"]
    return dataclasses.replace(block, crs="EPSG:32611")


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    """The block adjusted with Brown by the CLI."""
    root = tmp_path_factory.mktemp("exchange")
    write_block(_block(), root / "block")
    assert run_cli("adjust", str(root / "block"), "--out", str(root / "res"), "--ap", "brown", "--quiet",
                   "--no-report") == 0
    return root / "res"


def _column(table, name):
    return np.asarray(table[name])


def test_version_from_the_command_line_and_the_package(selfcal_exe):
    import selfcal
    assert selfcal.__version__ == importlib.metadata.version("selfcal")
    done = subprocess.run([selfcal_exe, "--version"], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == f"selfcal {selfcal.__version__}"


def test_summary_json_is_valid_against_its_schema(adjusted):
    schema = summary_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    with open(adjusted / "summary.json") as handle:
        summary = json.load(handle)
    jsonschema.validate(summary, schema, cls=jsonschema.Draft202012Validator)
    import selfcal
    assert summary["selfcal_version"] == selfcal.__version__ and summary["crs"] == "EPSG:32611"
    # the schema can fail: a missing key, a wrong type, a negative count, an unknown method are refused
    for broken in ({k: v for k, v in summary.items() if k != "sigma0_px"}, summary | {"converged": "yes"},
                   summary | {"n_obs_rejected": -1}, summary | {"check_method": "guess"}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(broken, schema, cls=jsonschema.Draft202012Validator)


def _geojson_as_gdal_reads_it(folder):
    """check_points.geojson of a results folder as GDAL/OGR reads it (pyogrio): (layer metadata, fields by name,
    x y z of each point), each feature's numbers checked against points.csv: at the reference position X - dX,
    dX_m dY_m dZ_m as points.csv's, sigma_dX_m ... its sigma_X_m ... (a frame block: errors along X, Y, Z)."""
    from pyogrio.raw import read
    meta, _, geometry, fields = read(str(folder / "check_points.geojson"))
    assert meta["geometry_type"] == "Point Z"
    field = dict(zip(meta["fields"], fields))
    xyz = np.array([np.frombuffer(wkb[-24:], "<f8") for wkb in geometry])     # WKB Point Z ends with x, y, z
    points = read_results(str(folder)).tables["points"]
    chk = np.flatnonzero(points["role"] == "chk")
    assert len(geometry) == len(chk) == 24
    row = [{pid: k for k, pid in enumerate(points["point_id"])}[pid] for pid in field["point_id"]]
    d = np.column_stack([points[f"d{a}_m"][row] for a in "XYZ"])
    np.testing.assert_allclose(np.column_stack([field[f"d{a}_m"] for a in "XYZ"]), d, atol=6e-5)
    np.testing.assert_allclose(xyz, np.column_stack([points[a][row] for a in "XYZ"]) - d, atol=2e-4)
    np.testing.assert_allclose(np.column_stack([field[f"sigma_d{a}_m"] for a in "XYZ"]),
                               np.column_stack([points[f"sigma_{a}_m"][row] for a in "XYZ"]), atol=6e-6)
    np.testing.assert_allclose(field["error_xy_m"], np.hypot(d[:, 0], d[:, 1]), atol=1e-4)
    assert set(field["role"]) == {"chk"}
    return meta, field, xyz


def test_check_points_as_geojson_read_by_gdal(adjusted):
    """A UTM block: GDAL reads EPSG:32611 from the GeoJSON 2008 crs member."""
    meta, _, _ = _geojson_as_gdal_reads_it(adjusted)
    assert meta["crs"] == "EPSG:32611"


def test_check_points_of_a_local_frame_in_an_engineering_crs(tmp_path):
    """A block in a local frame: GDAL reads the crs member as an engineering CRS in metres (not longitude and
    latitude, GeoJSON's default), named as the block's crs."""
    from pyproj import CRS
    import selfcal
    block = dataclasses.replace(_block(), crs="local")
    selfcal.bundle_adjust(block, ap="brown").write(tmp_path / "res", report=False)
    meta, _, xyz = _geojson_as_gdal_reads_it(tmp_path / "res")
    crs = CRS.from_wkt(meta["crs"])
    assert meta["crs"].startswith('LOCAL_CS["local"') and crs.is_engineering and not crs.is_geographic
    assert [a.unit_name for a in crs.axis_info] == ["metre"] * 3 and [a.name for a in crs.axis_info] == list("XYZ")
    assert np.abs(xyz[:, :2]).max() > 360.0                     # what would be out of range as degrees


def test_object_points_as_ply_read_by_plyfile(adjusted):
    vertex = PlyData.read(str(adjusted / "points.ply"))["vertex"]
    points = read_results(str(adjusted)).tables["points"]
    assert vertex.count == len(points["point_id"])
    np.testing.assert_allclose(np.column_stack([vertex["x"], vertex["y"], vertex["z"]]),
                               np.column_stack([points["X"], points["Y"], points["Z"]]), atol=6e-5)
    np.testing.assert_allclose(np.column_stack([vertex["sigma_x_m"], vertex["sigma_y_m"], vertex["sigma_z_m"]]),
                               np.column_stack([points["sigma_X_m"], points["sigma_Y_m"], points["sigma_Z_m"]]),
                               atol=6e-6, rtol=1e-6)
    np.testing.assert_array_equal(vertex["n_images"], points["n_images"])
    roles = {0: "tie", 1: "gcp", 2: "chk"}
    assert [roles[int(r)] for r in vertex["role"]] == list(points["role"])
    assert vertex["x"].dtype == np.dtype("<f8")                    # metres of a projected CRS kept exactly


def test_geojson_of_an_earth_fixed_block_is_longitude_latitude_height():
    """An Earth-fixed block: RFC 7946's longitude, latitude, height (no crs member), errors east, north, up with
    their sigma (null where the method gives none); a body-fixed block of an unknown body gets an engineering
    CRS (its Cartesian metres), never WGS 84 degrees."""
    from selfcal.geometry.earth import geodetic_from_ecef
    from selfcal.report.exchange import check_points_geojson
    from selfcal.stats.checks import CheckPoints, check_point_sigmas_m
    lat, lon, h = np.radians(44.17), np.radians(5.27), 1500.0        # Mont Ventoux
    a, e2 = 6378137.0, 6.69437999014e-3
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    ecef = np.array([[(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                      (n * (1 - e2) + h) * np.sin(lat)]])
    checks = CheckPoints(np.array(["c1"]), np.array(["chk"]), ecef, ecef + [[1.0, 0, 0]], "intersection",
                         np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    doc = check_points_geojson(checks, "EPSG:4978", True, np.array([[0.1, 0.2, 0.3]]))
    assert "crs" not in doc
    feature = doc["features"][0]
    np.testing.assert_allclose(feature["geometry"]["coordinates"], [5.27, 44.17, 1500.0], atol=1e-9)
    assert feature["properties"] | {"error_xy_m": 1.0} == {
        "point_id": "c1", "role": "chk", "dE_m": 0.0, "dN_m": 1.0, "dU_m": 0.0, "sigma_dE_m": 0.1,
        "sigma_dN_m": 0.2, "sigma_dU_m": 0.3, "error_xy_m": 1.0}
    assert check_points_geojson(checks, "EPSG:4978", True)["features"][0]["properties"]["sigma_dU_m"] is None
    assert check_point_sigmas_m(dataclasses.replace(checks, method="restitution"), None) is None   # no covariance
    assert np.allclose(np.degrees(geodetic_from_ecef(ecef[0])[:2]), [44.17, 5.27])
    unknown = check_points_geojson(checks, "body-fixed", True)
    assert unknown["crs"]["properties"]["name"].startswith('ENGCRS["body-fixed"')
    np.testing.assert_allclose(unknown["features"][0]["geometry"]["coordinates"], ecef[0])


def test_python_api_adjusts_like_the_cli_and_logs_its_progress(adjusted, tmp_path, caplog):
    import selfcal
    block = _block()
    with caplog.at_level(logging.INFO, logger="selfcal"):
        outcome = selfcal.bundle_adjust(block, ap="brown")
    assert any("iteration  1" in r.getMessage() for r in caplog.records if r.name == "selfcal")
    assert any(r.getMessage().startswith("tests round") for r in caplog.records if r.name == "selfcal")
    with open(adjusted / "summary.json") as handle:
        cli = json.load(handle)
    # the CLI read the block from its files (pixels to 5 decimals), the API took it from memory
    for key in ("sigma0_px", "rmsd_chk_xy_m", "rmsd_chk_z_m"):
        assert outcome.summary[key] == pytest.approx(cli[key], rel=1e-5), key
    for key in ("n_obs_rejected", "n_ap_significant", "n_chk_used", "n_gcp_used"):
        assert outcome.summary[key] == cli[key], key
    outcome.write(tmp_path / "res", report=False)
    back = selfcal.read_results(str(tmp_path / "res"))
    assert back.summary["sigma0_px"] == pytest.approx(outcome.summary["sigma0_px"], rel=1e-12)
    # the outcome's result is the adjustment the files describe: its sigma0 is summary.json's
    assert outcome.result.sigma0_px == pytest.approx(outcome.summary["sigma0_px"], rel=1e-12)
