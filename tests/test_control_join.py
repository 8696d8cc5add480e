"""Control joined to a block (issue 39, item 5): the rules of selfcal.convert.labels and selfcal.convert.control
that the importers' tests (tests/test_import_uav.py, test_import.py, test_gnss_import.py) do not reach through
their files: numbers, ambiguous labels, geographic coordinates, free networks."""
import numpy as np
import pytest

from selfcal.convert.control import block_control_swapped, swapped_axes
from selfcal.convert.labels import match_labels
from selfcal.errors import BlockError

TIES = [str(k) for k in range(1, 3000)]          # BINGO's and PAT-B's tie points are numbered


def test_a_number_is_joined_exactly_only():
    """'05' is not tie point '5', and 'GCP_05' without its prefix is no number to join: tie points are numbered."""
    match = match_labels(["M1", "05"], ["M1", "5", "6"], path="a.csv", other_path="b.txt")
    assert match.partner == {"M1": "M1"} and match.unmatched == ["05"]
    assert match.messages == ["1 of the 2 control labels of a.csv matches nothing in b.txt: '05' (nearest there: "
                              "'5')"]
    with pytest.raises(BlockError) as info:
        match_labels(["GCP_05", "GCP_06"], TIES, path="a.csv", other_path="b.txt")
    assert info.value.path == "a.csv"
    assert info.value.reason.startswith("none of its 2 control labels matches one of the 2999 labels of b.txt")
    assert "the labels of b.txt are numbers: '1', '2', '3', '4', '5' and more" in info.value.reason


def test_ambiguous_labels_are_left_unmatched_and_named():
    """GCP5 could be GCP05 or gcp_5: neither is taken; the closer tier wins where there is one (case before zeros)."""
    match = match_labels(["GCP5", "M1"], ["GCP05", "gcp_5", "M1"] + TIES, path="a.csv", other_path="b.txt")
    assert match.partner == {"M1": "M1"}
    assert ("not matched, as they are the same ignoring case, separators and leading zeros: 'GCP5' of a.csv and "
            "'GCP05', 'gcp_5' of b.txt") in match.messages
    match = match_labels(["GCP5"], ["gcp5", "GCP05"], path="a.csv", other_path="b.txt")
    assert match.partner == {"GCP5": "gcp5"}
    assert match.messages == ["control labels matched ignoring case (a.csv to b.txt): 1 of 1 (GCP5 = gcp5)"]


def test_a_suffix_of_the_measured_labels_and_the_exact_labels_first():
    match = match_labels(["P1", "P2", "P3"], ["P1", "P2_chk", "P3_chk"] + TIES, path="a.csv", other_path="b.txt")
    assert match.partner == {"P1": "P1", "P2": "P2_chk", "P3": "P3_chk"}
    assert match.renamed == {"P2_chk": "P2", "P3_chk": "P3"}
    assert match.messages == ["control labels matched after removing the suffix '_chk' of b.txt's labels (a.csv to "
                              "b.txt): 2 of 3 (P2 = P2_chk, P3 = P3_chk)"]


def test_latitude_beyond_90_is_certain_without_any_camera():
    reason = swapped_axes([[25.0301, 121.5651, 10.0], [25.0302, 121.5652, 11.0]], np.zeros((0, 3)), geographic=True,
                          point_ids=["a", "b"], lines=[4, 5])
    assert reason.startswith("the control points' longitude and latitude look swapped: selfcal reads X as the "
                             "longitude and Y as the latitude of a geographic CRS, and Y (the latitude) is 121.5652 "
                             "(point 'b', line 5), beyond +-90 degrees, while every X is a valid latitude")
    assert swapped_axes([[95.0, 121.0, 0.0]], np.zeros((0, 3)), geographic=True) == \
        "the control points are not longitude, latitude: Y (the latitude) is 121 (point number 1), beyond +-90 degrees"


def test_latitude_and_longitude_swapped_by_the_cameras_extent():
    """Mont Ventoux (5.28 E, 44.17 N): both orders are valid coordinates; the cameras tell them apart."""
    rng = np.random.default_rng(3)
    cameras = np.column_stack([5.27 + 0.02 * rng.random(20), 44.16 + 0.02 * rng.random(20), np.full(20, 2000.0)])
    control = np.column_stack([5.27 + 0.02 * rng.random(6), 44.16 + 0.02 * rng.random(6), np.full(6, 1800.0)])
    assert swapped_axes(control, cameras, geographic=True) is None
    reason = swapped_axes(control[:, [1, 0, 2]], cameras, geographic=True)
    assert reason.startswith("the control points' longitude and latitude look swapped (the file in latitude, "
                             "longitude order?): as given they lie ")
    far = float(reason.split("they lie ")[1].split(" m")[0])
    assert 4.5e6 < far < 6.5e6              # (44.17 E, 5.28 N) from (5.28 E, 44.17 N): 5750 km on a great circle
    assert "with longitude and latitude swapped 0 m" in reason
    # a projected block: both orders near the cameras (a local frame at the origin) say nothing
    local = (cameras[:, :2] - cameras[:, :2].mean(axis=0)) * 1e5
    assert swapped_axes(np.column_stack([local[:6, 1], local[:6, 0], np.zeros(6)]),
                        np.column_stack([local, np.full(20, 200.0)])) is None


def test_a_free_network_is_checked_for_latitudes_only(tmp_path):
    """A free network's camera positions are in an arbitrary frame: control swapped against them says nothing."""
    from dataclasses import replace

    from conftest import simulation
    block = simulation(seed=5, distortion="none", points_per_mm2=0.3).blocks["type1"]
    d = np.array([251000.0, 2690000.0, 0.0])
    xyz = block.points.xyz_m + d
    marked = block.points.role != "tie"
    xyz[marked] = xyz[marked][:, [1, 0, 2]]
    block = replace(block, points=replace(block.points, xyz_m=xyz),
                    images=replace(block.images, position_m=block.images.position_m + d))
    assert "X and Y look swapped" in block_control_swapped(block)
    assert block_control_swapped(replace(block, datum="free")) is None
    assert block_control_swapped(replace(block, crs="EPSG:4978")) is None          # geocentric: no plan
