"""The Apollo 15 Metric network of ISIS's tests through selfcal import isis and the one engine, side by side
with ISIS jigsaw's published results on it (../shared/data/isis/EXPECTED_VALUES.txt), with jigsaw's settings:
positions sigma 1000 m, RA/DEC/TWIST sigma 2 deg, point radii free, no rejection. The comparison is the
example's own (examples/apollo15/compare.py)."""
import importlib.util
import os

import numpy as np
import pytest

from selfcal.convert import block_from_isis
from selfcal.io import read_block
from selfcal.io.block_folder import write_block
from selfcal.io.isis import read_control_network, read_image_folder
from selfcal.io.results import write_results
from selfcal.report import result_files
from selfcal.workflows.adjust import AdjustRequest, adjust_block

from conftest import SHARED_DATA

FOLDER = os.path.join(SHARED_DATA, "isis", "apollo15_metric")
HERE = os.path.dirname(os.path.abspath(__file__))


def _compare_module(example: str = "apollo15"):
    """examples/EXAMPLE/compare.py: the side-by-side table is the example's own."""
    spec = importlib.util.spec_from_file_location(f"{example}_compare",
                                                  os.path.join(HERE, "..", "examples", example, "compare.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def jigsaw_run(tmp_path_factory):
    """Import, adjust as jigsaw did, write the results folder; (results folder, adjusted)."""
    assert os.path.isdir(FOLDER), f"shared test data missing: {FOLDER}"
    tmp = tmp_path_factory.mktemp("apollo")
    block, counts = block_from_isis(read_control_network(os.path.join(FOLDER, "apolloNet.pvl")),
                                    read_image_folder(FOLDER), 0.35, "apollo",
                                    {"sigma_position_m": 1000.0, "sigma_attitude_deg": 2.0})
    assert counts == {"ignored_points": 0, "ignored_measures": 0, "measures_without_image": 0}
    write_block(block, tmp / "block")
    block = read_block(tmp / "block")
    adjusted = adjust_block(block, AdjustRequest(snooping=None, robust=None))
    files = result_files(adjusted.block, adjusted.tested, {}, None, adjusted.checks)
    write_results(tmp / "jigsaw", files)
    return tmp / "jigsaw", adjusted


def test_the_network_is_imported_as_jigsaw_reads_it(jigsaw_run):
    _, adjusted = jigsaw_run
    block = adjusted.block
    assert len(block.images) == 7 and len(block.points) == 395 and len(block.observations) == 969
    assert int((block.points.role == "gcp").sum()) == 32 and adjusted.tested.result.converged


def test_image_residuals_corrections_and_sigmas_are_jigsaws(jigsaw_run):
    """Per image: residual RMS within 5 % of jigsaw's (cube7's 12.29 px included); the corrections of X/Y/Z and
    RA/DEC/TWIST within 10 % or 50 m / 0.05 deg, their adjusted sigmas within 10 % (measured: every ratio
    within 0.4 % of 1, the corrections within 1 m and 0.001 deg)."""
    results, _ = jigsaw_run
    compare = _compare_module()
    rows = compare.image_rows(str(results), compare.read_jigsaw())
    assert len(rows) == 7 * 15
    for name, theirs, mine in rows:
        if "RMS" in name:
            assert abs(mine / theirs - 1) < 0.05, (name, theirs, mine)
        elif "correction" in name:
            slack = 0.05 if "deg" in name else 0.050               # km
            assert abs(mine - theirs) < max(0.10 * abs(theirs), slack), (name, theirs, mine)
        else:
            assert abs(mine / theirs - 1) < 0.10, (name, theirs, mine)


def test_spot_checked_points_sigmas_are_jigsaws(jigsaw_run):
    """The six spot-checked points: sigma of latitude, longitude and radius within 10 % (measured 0.05 %)."""
    results, _ = jigsaw_run
    compare = _compare_module()
    rows = compare.point_rows(str(results), compare.read_jigsaw())
    assert len(rows) == 18
    for name, theirs, mine in rows:
        assert abs(mine / theirs - 1) < 0.10, (name, theirs, mine)


def test_data_snooping_finds_cube7s_inconsistent_measures(jigsaw_run):
    """jigsaw keeps every measure and cube7 stands out (12.29 px RMS); Baarda's data snooping rejects 8 of
    cube7's 10 measures (|w| 7 to 42) and fewer than 2 % of the others, and sigma0 falls by more than 3x."""
    _, adjusted = jigsaw_run
    block = adjusted.block
    from selfcal.stats import SnoopingOptions
    snooped = adjust_block(block, AdjustRequest(snooping=SnoopingOptions(3.0), robust=None)).tested
    rows = np.isin(block.observations.row, snooped.rejected_rows)
    cube7 = block.images.image_id[block.observations.image_index] == "apolloImage7"
    assert int(rows[cube7].sum()) >= 7 and rows[~cube7].mean() < 0.02
    assert snooped.result.sigma0_px < adjusted.tested.result.sigma0_px / 3


def test_check_points_on_the_moon_are_in_its_iau_crs(jigsaw_run, tmp_path):
    """check_points.geojson of a lunar block, read by GDAL/OGR (pyogrio): the Moon's IAU 2015 CRS (the body
    named by the ISDs' BODY301_RADII), planetocentric longitude and latitude and the height above the 1737.4 km
    sphere of each reference position (from points.csv's X - dX), the errors along east, north and radial at
    the centroid, their sigma as points.csv's (the total, which the rotation keeps). The network has no check
    points: its 32 Constrained points are taken as such, adjusted against their a-priori positions."""
    from pyogrio.raw import read
    from pyproj import CRS
    from selfcal.io.results import read_results, write_files
    from selfcal.stats.checks import CheckPoints, local_axes
    results, adjusted = jigsaw_run
    result = adjusted.tested.result
    pts = result.block.points
    gcp = np.flatnonzero(pts.role == "gcp")
    checks = CheckPoints(pts.point_id[gcp], pts.role[gcp], pts.xyz_m[gcp], result.state.points[gcp], "intersection",
                         local_axes(pts.xyz_m[gcp], "ECEF", result.block.crs))
    files = result_files(adjusted.block, adjusted.tested, {}, None, checks)
    write_files(str(tmp_path), {"check_points.geojson": files["check_points.geojson"]})
    meta, _, geometry, fields = read(str(tmp_path / "check_points.geojson"))
    crs = CRS.from_wkt(meta["crs"])
    assert meta["crs"].endswith('AUTHORITY["IAU","30100"]]') and crs.is_geographic      # GDAL's WKT1 of it
    assert crs.equals(CRS.from_authority("IAU_2015", "30100"), ignore_axis_order=True)
    assert crs.ellipsoid.semi_major_metre == crs.ellipsoid.semi_minor_metre == 1737400.0
    assert len(geometry) == len(gcp) == 32 and meta["geometry_type"] == "Point Z"
    field = dict(zip(meta["fields"], fields))
    points = read_results(str(results)).tables["points"]
    row = [{pid: k for k, pid in enumerate(points["point_id"])}[pid] for pid in field["point_id"]]
    d = np.column_stack([points[f"d{a}_m"][row] for a in "XYZ"])
    reference = np.column_stack([points[a][row] for a in "XYZ"]) - d
    r = np.linalg.norm(reference, axis=1)
    lon_lat_h = np.column_stack([np.degrees(np.arctan2(reference[:, 1], reference[:, 0])),
                                 np.degrees(np.arcsin(reference[:, 2] / r)), r - 1737400.0])
    np.testing.assert_allclose([np.frombuffer(wkb[-24:], "<f8") for wkb in geometry], lon_lat_h,
                               rtol=0, atol=2e-4)
    centre = reference.mean(axis=0)
    lon, lat = np.arctan2(centre[1], centre[0]), np.arcsin(centre[2] / np.linalg.norm(centre))
    axes = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                     [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)], centre / np.linalg.norm(centre)])
    np.testing.assert_allclose(np.column_stack([field[f"d{a}_m"] for a in "ENU"]), d @ axes.T, atol=2e-4)
    sigma = np.column_stack([field[f"sigma_d{a}_m"] for a in "ENU"])
    np.testing.assert_allclose(np.linalg.norm(sigma, axis=1),
                               np.linalg.norm(np.column_stack([points[f"sigma_{a}_m"][row] for a in "XYZ"]), axis=1),
                               atol=3e-5)


# --- the LRO NAC pair (line-scan ISDs): jigsaw observations=yes cksolvedegree=3 camsolve=all twist=no radius=no --

LRO = os.path.join(SHARED_DATA, "isis", "lro_nac_pair")


@pytest.fixture(scope="module")
def lro_runs(tmp_path_factory):
    """The three runs of examples/lro_nac/run.sh: name -> (results folder, adjusted)."""
    from selfcal.adjust import AdjustOptions
    from selfcal.adjust import SolverOptions
    from selfcal.workflows.isis import hold_radii
    assert os.path.isdir(LRO), f"shared test data missing: {LRO}"
    tmp = tmp_path_factory.mktemp("lro")
    network, images = read_control_network(os.path.join(LRO, "observationPair.net")), read_image_folder(LRO)
    runs = {}
    for name, settings in (("no_twist", {"attitude_degree": 3, "twist": False}), ("twist", {"attitude_degree": 3}),
                           ("degree1", {"attitude_degree": 1, "twist": False})):
        block, counts = block_from_isis(network, images, 1.4, name, settings)
        assert counts == {"ignored_points": 0, "ignored_measures": 0, "measures_without_image": 0}
        write_block(block, tmp / f"block_{name}")
        block = hold_radii(read_block(tmp / f"block_{name}"), 0.001)
        request = AdjustRequest(AdjustOptions(solver=SolverOptions(max_iterations=200)), snooping=None, robust=None)
        adjusted = adjust_block(block, request)
        write_results(tmp / name, result_files(adjusted.block, adjusted.tested, {}, None, adjusted.checks))
        runs[name] = (tmp / name, adjusted)
    return runs


def _lro_values(folder):
    return {name: (theirs, ours) for name, theirs, ours in _compare_module("lro_nac").rows(str(folder))}


def test_lro_pair_is_imported_with_its_two_fixed_points(lro_runs):
    _, adjusted = lro_runs["no_twist"]
    block = adjusted.block
    assert len(block.images) == 2 and len(block.points) == 46 and len(block.observations) == 92
    assert int((block.points.sigma_m.max(axis=1) < 0.01).sum()) == 2 and adjusted.tested.result.converged


def test_lro_pair_with_jigsaws_options_leaves_degrees_2_and_3_undetermined(lro_runs):
    """jigsaw's options (RA, DEC of degree 3, no twist, no prior): the two Fixed points and the tie points of the
    narrow overlap anchor the bias and the drift only; the engine converges and says so: every coefficient of
    degree 2 and 3 has a sigma above 0.1 deg (measured 0.42 - 0.91 deg), and a note (and `selfcal adjust`'s
    warning) names them as weakly determined. The residuals are larger than jigsaw's
    (measured: mean 0.186 px = 1.51 x, maximum 0.421 px = 1.10 x; the issue asked for 10 % and 15 %: not met, see
    examples/lro_nac/README.md)."""
    _, adjusted = lro_runs["no_twist"]
    result = adjusted.tested.result
    sigma_deg = np.degrees(result.image_sigma())
    assert result.converged and np.all(sigma_deg[:, [2, 3, 6, 7]] > 0.1)
    # and the engine says it: the 16 coefficients' sigmas are inflated > 1000x by their correlation (measured
    # 2.4e4 - 2.6e4x); bias and drift alone are not (2.5x)
    weak = [n for n in result.notes if n.startswith("weakly determined: 16 parameters")]
    assert weak and "dec_0" in weak[0], result.notes
    assert not any(n.startswith("weakly") for n in lro_runs["degree1"][1].tested.result.notes)
    values = _lro_values(lro_runs["no_twist"][0])
    theirs, ours = values["mean residual [px]"]
    assert 1.0 < ours / theirs < 1.8
    theirs, ours = values["maximum residual [px]"]
    assert abs(ours / theirs - 1) < 0.15, (ours, theirs)


def test_lro_pair_with_twist_reaches_jigsaws_residuals(lro_runs):
    """With the twist polynomial free as well: mean residual within 3 % of jigsaw's, maximum within 10 %
    (measured 0.1244 vs 0.1231 px, 0.362 vs 0.381 px)."""
    values = _lro_values(lro_runs["twist"][0])
    theirs, ours = values["mean residual [px]"]
    assert abs(ours / theirs - 1) < 0.03, (ours, theirs)
    theirs, ours = values["maximum residual [px]"]
    assert abs(ours / theirs - 1) < 0.10, (ours, theirs)


@pytest.mark.slow
def test_lro_pair_bias_and_drift_are_determined_and_points_land_where_jigsaws_do(lro_runs):
    """RA and DEC of degree 1: every coefficient determined to 1 arcsec (measured 0.3"), biases RA 0.31 deg and
    DEC 0.57 deg alike in L and R (the two Fixed points sit 1.7 km from where the ISDs put them); the adjusted
    points' mean X, Y, Z within 1 km of jigsaw's (measured 0.15, 0.13, 0.73 km) and their spread in X and Z within
    10 % (measured -5.6 %, +3.8 %)."""
    folder, adjusted = lro_runs["degree1"]
    result = adjusted.tested.result
    sigma_arcsec = np.degrees(result.image_sigma()) * 3600
    active = result.problem.image_free
    assert result.converged and np.all(sigma_arcsec[active] < 1.0)
    ra_deg, dec_deg = np.degrees(result.state.image[:, 0]), np.degrees(result.state.image[:, 4])
    assert np.all(np.abs(ra_deg - 0.31) < 0.03) and np.all(np.abs(dec_deg - 0.575) < 0.03), (ra_deg, dec_deg)
    # attitude_corrections.csv: at the image centre (s = 0) the corrections are the constant terms, and so are
    # their sigmas; the report draws them
    from selfcal.io.results import read_results
    from selfcal.report import render_report
    results = read_results(folder)
    table = results.tables["attitude_corrections"]
    sigma = result.image_sigma()
    for i, image_id in enumerate(result.block.images.image_id):
        mine = np.flatnonzero(table["image_id"] == image_id)
        centre = mine[np.argmin(np.abs(table["time_s"][mine]))]
        assert abs(table["time_s"][centre]) < 1e-9
        np.testing.assert_allclose([table["ra_urad"][centre], table["dec_urad"][centre]],
                                   result.state.image[i, [0, 4]] * 1e6, rtol=1e-6)
        np.testing.assert_allclose([table["sigma_ra_urad"][centre], table["sigma_dec_urad"][centre]],
                                   sigma[i, [0, 4]] * 1e6, rtol=1e-3)
        assert np.all(table["twist_urad"][mine] == 0) and np.all(table["sigma_twist_urad"][mine] == 0)
    assert "figures/attitude-corrections.png" in render_report(results)
    values = _lro_values(folder)
    for axis in "XYZ":
        theirs, ours = values[f"points {axis} mean [km]"]
        assert abs(ours - theirs) < 1.0, (axis, ours, theirs)
    for axis in "XZ":
        theirs, ours = values[f"points {axis} sd [km]"]
        assert abs(ours / theirs - 1) < 0.10, (axis, ours, theirs)


def test_lro_pair_with_the_radii_free(tmp_path):
    """jigsaw held the radii on a DEM that the shared data lack: with the radii free, bias and drift adjust (mean
    residual 0.094 px, below jigsaw's 0.123 with three more unknowns per point; points' mean X, Y, Z within 1 km of
    jigsaw's, measured 0.46, 0.02, 0.55 km; tie points' sigma 78 m in plan, 310 m in height), and degree 3 is
    singular: the engine stops and names RA/DEC coefficients instead of returning a solution."""
    from selfcal.errors import AdjustmentError
    network, images = read_control_network(os.path.join(LRO, "observationPair.net")), read_image_folder(LRO)
    for degree in (1, 3):
        block, _ = block_from_isis(network, images, 1.4, "free", {"attitude_degree": degree, "twist": False})
        write_block(block, tmp_path / f"d{degree}")
        block = read_block(tmp_path / f"d{degree}")
        if degree == 3:
            with pytest.raises(AdjustmentError, match=r"(ra|dec)_[0-3]"):
                adjust_block(block, AdjustRequest(snooping=None, robust=None))
            continue
        adjusted = adjust_block(block, AdjustRequest(snooping=None, robust=None))
        assert adjusted.tested.result.converged
        write_results(tmp_path / "res", result_files(adjusted.block, adjusted.tested, {}, None, adjusted.checks))
        values = _lro_values(tmp_path / "res")
        theirs, ours = values["mean residual [px]"]
        assert 0.6 < ours / theirs < 1.0, (ours, theirs)
        for axis in "XYZ":
            theirs, ours = values[f"points {axis} mean [km]"]
            assert abs(ours - theirs) < 1.0, (axis, ours, theirs)


def test_import_isis_from_the_command_line(tmp_path):
    """selfcal import isis with jigsaw's LRO options writes a block folder that says them (attitude_degree 3,
    twist false, the Free points held at their radius); a line-scan option on frame ISDs is an error (exit 2)
    that writes nothing."""
    from conftest import run_cli
    out = tmp_path / "lro"
    assert run_cli("import", "isis", os.path.join(LRO, "observationPair.net"), "--images", LRO, "--out", str(out),
                   "--attitude-degree", "3", "--no-twist", "--hold-radii", "0.001") == 0
    text = (out / "block.toml").read_text()
    assert "attitude_degree = 3" in text and "twist = false" in text and "position_offsets = false" in text
    block = read_block(out)
    assert (block.points.role == "gcp").all() and np.allclose(block.points.sigma_m[:, 2], 0.001, atol=1e-9)
    assert run_cli("import", "isis", os.path.join(FOLDER, "apolloNet.pvl"), "--images", FOLDER, "--out",
                   str(tmp_path / "apollo"), "--no-twist") == 2
    assert not os.path.exists(tmp_path / "apollo")
