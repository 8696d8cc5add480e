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


def _compare_module():
    spec = importlib.util.spec_from_file_location("apollo15_compare",
                                                  os.path.join(HERE, "..", "examples", "apollo15", "compare.py"))
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
    adjusted = adjust_block(block, AdjustRequest(snooping=None))
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
    snooped = adjust_block(block, AdjustRequest(snooping=SnoopingOptions(3.0))).tested
    rows = np.isin(block.observations.row, snooped.rejected_rows)
    cube7 = block.images.image_id[block.observations.image_index] == "apolloImage7"
    assert int(rows[cube7].sum()) >= 7 and rows[~cube7].mean() < 0.02
    assert snooped.result.sigma0_px < adjusted.tested.result.sigma0_px / 3
