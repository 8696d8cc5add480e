"""Issue 46, item 2: every foreign reader validates before it trusts.

One test per defect the issue found: the bad file gives exit 2 (or a BlockError from the reader) with a one-line
message that names the file and the key or line, never a traceback, an abort or a silent default.
"""
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from selfcal.errors import BlockError, UsageError

from front_door import SHARED_DATA, Workspace, run_main, run_main_streams


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    return Workspace(tmp_path_factory.mktemp("readers46"))


@pytest.fixture(scope="module")
def exported(ws):
    """The block's camera exported once to each tool's file: {name: path}."""
    folder = os.path.join(ws.root, "exported")
    out = {}
    for tool, name in (("opencv", "cal.yaml"), ("opencv", "cal.xml"), ("opencv", "cal.json"),
                       ("kalibr", "camchain.yaml"), ("opensfm", "cameras.json")):
        path = os.path.join(folder, name)
        code, err = run_main(["export", tool, ws.results, "--out", path, "--tolerance-px", "1"])
        assert code == 0, err
        out[name] = path
    return out


def _read(path) -> str:
    return Path(path).read_text()


def _fails(argv, *names):
    """Run ``selfcal ARGV``: exit 2, one line 'selfcal VERB: error: ...' naming every one of ``names``."""
    code, err = run_main(argv)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"selfcal {argv[0]}: error: "), err
    for name in names:
        assert name in lines[0], (name, err)
    return lines[0]


def _import_calibration(ws, path, tmp_path):
    return ["import", "calibration", path, "--block", ws.block, "--out", str(tmp_path / "out")]


# --- OpenCV FileStorage: never handed to cv2.FileStorage -------------------------------------------------

def _edit(source, target, old, new):
    text = _read(source)
    assert old in text, old
    Path(target).write_text(text.replace(old, new, 1))
    return str(target)


def _yaml_matrix_data(text: str) -> str:
    return re.search(r"camera_matrix: !!opencv-matrix.*?data: (\[[^\]]*\])", text, re.S).group(1)


def test_opencv_camera_matrix_with_5_numbers_names_the_key_and_line(ws, exported, tmp_path):
    source = exported["cal.yaml"]
    bad = _edit(source, tmp_path / "k5.yaml", _yaml_matrix_data(_read(source)), "[ 1., 2., 3., 4., 5. ]")
    message = _fails(_import_calibration(ws, bad, tmp_path), "k5.yaml", "line 9", "camera_matrix",
                     "rows x cols = 9 numbers expected in 'data', found 5")
    assert not os.path.exists(tmp_path / "out"), message


def test_opencv_unclosed_bracket_is_a_yaml_error_with_its_line(ws, exported, tmp_path):
    bad = _edit(exported["cal.yaml"], tmp_path / "open.yaml", "data: [ 0., 0., 0., 0. ]", "data: [ 0., 0., 0., 0.")
    _fails(_import_calibration(ws, bad, tmp_path), "open.yaml", "line ", "not OpenCV YAML")


def test_opencv_huge_rows_and_cols_allocate_nothing(ws, exported, tmp_path):
    """rows x cols of 10^10 (cv2.FileStorage asked for 86 GB of such a file): the count is compared first."""
    text = _read(exported["cal.yaml"])
    bad = tmp_path / "huge.yaml"
    bad.write_text(text.replace("rows: 3\n   cols: 3", "rows: 100000\n   cols: 100000", 1))
    _fails(_import_calibration(ws, str(bad), tmp_path), "huge.yaml", "camera_matrix", "10000000000 numbers expected")


@pytest.mark.parametrize("ext", ["xml", "json"])
def test_opencv_xml_and_json_are_checked_alike(ws, exported, tmp_path, ext):
    source = exported[f"cal.{ext}"]
    text = _read(source)
    bad = tmp_path / f"bad.{ext}"
    if ext == "xml":
        bad.write_text(text.replace("<cols>3</cols>", "<cols>4</cols>", 1))
    else:
        bad.write_text(re.sub(r'"cols": 3', '"cols": 4', text, count=1))
    _fails(_import_calibration(ws, str(bad), tmp_path), f"bad.{ext}", "camera_matrix",
           "rows x cols = 12 numbers expected")


def test_opencv_xml_with_a_doctype_is_refused(ws, exported, tmp_path):
    bad = _edit(exported["cal.xml"], tmp_path / "dtd.xml", '<?xml version="1.0"?>',
                '<?xml version="1.0"?>\n<!DOCTYPE opencv_storage [<!ENTITY a "aaaaaaaaaa">]>')
    _fails(_import_calibration(ws, bad, tmp_path), "dtd.xml", "DOCTYPE")


def test_opencv_old_yaml_directive_and_every_format_read_the_same(exported, tmp_path):
    from selfcal.io.opencv import read_opencv_calibration
    reference = read_opencv_calibration(exported["cal.yaml"])
    old = tmp_path / "old.yml"               # OpenCV 2/3: '%YAML:1.0' and no '---'
    old.write_text(_read(exported["cal.yaml"]).replace("%YAML 1.2\n---\n", "%YAML:1.0\n"))
    for path in (exported["cal.xml"], exported["cal.json"], str(old)):
        calibration = read_opencv_calibration(path)
        assert calibration.values == reference.values and calibration.camera_id == reference.camera_id == "ilce7m3"
        assert (calibration.width_px, calibration.height_px) == (6000, 4000)


def test_opencv_reader_never_calls_cv2_filestorage(exported, monkeypatch):
    import cv2

    def forbidden(*args, **kwargs):
        raise AssertionError("cv2.FileStorage must not read a user's file")

    monkeypatch.setattr(cv2, "FileStorage", forbidden)
    from selfcal.io.opencv import read_opencv_calibration
    for name in ("cal.yaml", "cal.xml", "cal.json"):
        read_opencv_calibration(exported[name])


# --- Kalibr, OpenSfM, camera.json -------------------------------------------------------------------------

def test_kalibr_file_with_a_byte_order_mark_is_read(ws, exported, tmp_path):
    bom = tmp_path / "bom.yaml"
    bom.write_bytes(b"\xef\xbb\xbf" + Path(exported["camchain.yaml"]).read_bytes())
    code, err = run_main(_import_calibration(ws, str(bom), tmp_path))
    assert code == 0 and "kalibr radtan calibration" in err, err


def test_kalibr_nan_intrinsics_are_an_error(ws, exported, tmp_path):
    text = _read(exported["camchain.yaml"])
    bad = tmp_path / "nan.yaml"
    bad.write_text(re.sub(r"intrinsics: \[[^,]+,", "intrinsics: [.nan,", text, count=1))
    _fails(_import_calibration(ws, str(bad), tmp_path), "nan.yaml", "cam0", "must be finite")


def test_opensfm_focal_abc_is_an_error_even_where_unused(ws, tmp_path):
    """A brown camera uses focal_x and focal_y; a 'focal' of "abc" beside them was taken without a word."""
    folder = ws.copy(ws.opensfm, str(tmp_path))
    path = os.path.join(folder, "reconstruction.json")
    data = json.loads(_read(path))
    camera = next(iter(data[0]["cameras"].values()))
    camera["focal"] = "abc"
    Path(path).write_text(json.dumps(data))
    _fails(["import", "opensfm", folder, "--out", str(tmp_path / "out")], "reconstruction.json", "'focal'", "'abc'",
           "not a number")
    assert not os.path.exists(tmp_path / "out")


def test_opensfm_cameras_json_focal_abc_is_an_error(ws, exported, tmp_path):
    data = json.loads(_read(exported["cameras.json"]))
    next(iter(data.values()))["focal"] = "abc"
    bad = tmp_path / "cameras.json"
    bad.write_text(json.dumps(data))
    _fails(_import_calibration(ws, str(bad), tmp_path), "cameras.json", "'focal'", "not a number")


def _results_with(ws, tmp_path, change):
    folder = ws.copy(ws.results, str(tmp_path), "res")
    path = os.path.join(folder, "camera.json")
    Path(path).write_text(change(_read(path)))
    return folder


def test_camera_json_camera_entry_that_is_a_string(ws, tmp_path):
    def change(text):
        data = json.loads(text)
        data["cameras"]["ilce7m3"] = "frame"
        return json.dumps(data)
    folder = _results_with(ws, tmp_path, change)
    _fails(["export", "metashape", folder, "--out", str(tmp_path / "m.xml")], "camera.json", "'cameras.ilce7m3'",
           "must be an object")


def test_camera_json_nan_focal_length_names_its_line(ws, tmp_path):
    folder = _results_with(ws, tmp_path, lambda t: re.sub(r'("focal_mm": \{\s*"value": )[-0-9.e]+', r"\1NaN", t,
                                                          count=1))
    _fails(["export", "opencv", folder, "--out", str(tmp_path / "c.yaml")], "camera.json", "line 9",
           "NaN is not a finite number")


@pytest.mark.parametrize("key, value, expected", [
    ("focal_mm", {"value": -1.0}, "'cameras.ilce7m3.focal_mm.value' must be a positive number, found -1.0"),
    ("width_px", "6000", "'cameras.ilce7m3.width_px' must be a whole number of at least 1, found '6000'"),
    ("ap", None, "'cameras.ilce7m3.ap' is null"),
])
def test_camera_json_values_of_the_wrong_type(ws, tmp_path, key, value, expected):
    def change(text):
        data = json.loads(text)
        data["cameras"]["ilce7m3"][key] = value
        return json.dumps(data)
    folder = _results_with(ws, tmp_path, change)
    _fails(["export", "kalibr", folder, "--out", str(tmp_path / "k.yaml")], "camera.json", expected)


def test_progress_message_of_a_camera_without_aps(ws, capsys, monkeypatch):
    from selfcal.cli import calibrations as module
    cal = next(iter(module.calibrations(ws.results).values()))
    assert cal.ap.spec == "none"
    monkeypatch.setattr(module, "undistortion_maps", lambda c, progress=None: None)
    module.maps_of(cal)
    err = capsys.readouterr().err
    assert "none distortion" not in err and "AP model none, no distortion to invert" in err, err


# --- BAL ------------------------------------------------------------------------------------------------

def test_bal_header_count_of_10_to_the_12_is_refused_before_any_allocation(tmp_path):
    bad = tmp_path / "huge.txt"
    bad.write_text("1000000000000 1 1\n0 0 1.0 2.0\n" + "0\n" * 12)
    _fails(["import", "bal", str(bad), "--out", str(tmp_path / "out")], "huge.txt", "line 1",
           "the header's counts", "the file has")


@pytest.mark.parametrize("value, reason", [("nan", "NaN or infinite value 'nan'"), ("abc", "'abc' is not a number")])
def test_bal_parameter_errors_name_their_line(ws, tmp_path, value, reason):
    lines = _read(ws.bal).split("\n")
    lines[-5] = value
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join(lines))
    _fails(["import", "bal", str(bad), "--out", str(tmp_path / "out")], "bad.txt", f"line {len(lines) - 4}", reason)


# --- DEM, DIMAP, usgscsm ISD ----------------------------------------------------------------------------

def test_dem_with_nan_cells(tmp_path):
    from selfcal.geometry.terrain import GridDem
    from selfcal.io.dem import read_dem, write_dem
    heights = np.full((4, 5), 100.0)
    heights[2, 3] = np.nan
    path = tmp_path / "dem.tif"
    write_dem(path, GridDem(heights, (0.01, 0.0, 10.0, 0.0, -0.01, 45.0)))
    with pytest.raises(BlockError, match=r"dem\.tif: 1 cells are NaN or infinite \(the first at row 2, column 3\)"):
        read_dem(path)


def test_dimap_ephemeris_nan(tmp_path):
    from selfcal.io.dimap import read_dimap_sensor
    source = os.path.join(SHARED_DATA, "pushbroom", "pleiades", "rpc", "PHRDIMAP_P1BP--2018122638935449CP.XML")
    text = _read(source)
    bad = tmp_path / "PHRDIMAP.XML"
    bad.write_text(re.sub(r'(<LOCATION_VALUES unit="m">)[-0-9.e+]+', r"\1NaN", text))   # every list of the file
    with pytest.raises(BlockError, match=r"PHRDIMAP\.XML, column 'Sensor_Ephemeris/Point_List/Point/LOCATION_VALUES'"
                                         r": must be finite numbers, found 'NaN "):
        read_dimap_sensor(bad)


def _line_isd():
    return json.loads(_read(os.path.join(SHARED_DATA, "pushbroom", "asp_dg_spot", "ctx.json")))


@pytest.mark.parametrize("change, expected", [
    (lambda isd: isd.update(image_lines="many"), "'image_lines' must be a whole number of at least 1, found 'many'"),
    (lambda isd: isd.update(detector_sample_summing=None), "'detector_sample_summing' is null"),
    (lambda isd: isd["focal_length_model"].update(focal_length=None), "'focal_length_model.focal_length' is null"),
    (lambda isd: isd.update(detector_center={"line": 0.5, "sample": [1]}),
     "'detector_center.sample' must be a finite number, found [1]"),
    (lambda isd: isd.update(radii="moon"), "'radii' must be an object"),
    (lambda isd: isd["instrument_position"].update(positions=None), "'instrument_position.positions' is null"),
])
def test_line_scan_isd_values_of_the_wrong_type_or_null(tmp_path, change, expected):
    from selfcal.io.sensor_files import read_usgscsm
    isd = _line_isd()
    change(isd)
    path = tmp_path / "ctx.json"
    path.write_text(json.dumps(isd))
    with pytest.raises(BlockError) as info:
        read_usgscsm(path)
    assert "ctx.json" in str(info.value) and expected in str(info.value), str(info.value)


def test_frame_isd_field_of_the_wrong_type(tmp_path):
    from selfcal.io.sensor_files import read_usgscsm
    isd = json.loads(_read(os.path.join(SHARED_DATA, "isis", "apollo15_metric", "apolloImage1.isd")))
    isd["image_samples"] = "wide"
    path = tmp_path / "apollo.isd"
    path.write_text(json.dumps(isd))
    with pytest.raises(BlockError, match=r"apollo\.isd: 'image_samples' must be a whole number of at least 1"):
        read_usgscsm(path)


# --- ISIS: a label that cannot be read is named, --strict makes it an error --------------------------------

def _isis_folder(tmp_path):
    folder = tmp_path / "apollo"
    shutil.copytree(os.path.join(SHARED_DATA, "isis", "apollo15_metric"), folder)
    for name in os.listdir(folder):
        os.chmod(folder / name, 0o644)
    label = folder / "apolloImage3.pvl"
    label.write_text(label.read_text().replace("Object = IsisCube", "Objoct = IsisCube", 1))
    return folder


def test_import_isis_names_the_label_it_leaves_out(tmp_path):
    folder = _isis_folder(tmp_path)
    code, out, err = run_main_streams(["import", "isis", folder / "apolloNet.pvl", "--images", folder, "--out",
                                       tmp_path / "out"])
    assert code == 0, err
    assert re.search(r"warning: \S*apolloImage3\.pvl: left out of the images: not an ISIS cube label", err), err
    assert "imported 6 images" in out and "serial numbers APOLLO15/METRIC/" in out       # the outcome, on stdout
    assert "left out: apolloImage3.pvl)" in out, out


def test_import_isis_strict_refuses_a_label_it_cannot_read(tmp_path):
    folder = _isis_folder(tmp_path)
    _fails(["import", "isis", folder / "apolloNet.pvl", "--images", folder, "--out", tmp_path / "out", "--strict"],
           "apolloImage3.pvl", "not an ISIS cube label", "--strict")
    assert not os.path.exists(tmp_path / "out")


def test_isis_label_sizes_must_be_positive(tmp_path):
    from selfcal.io.isis import read_cube_label
    source = os.path.join(SHARED_DATA, "isis", "apollo15_metric", "apolloImage1.pvl")
    text = _read(source)
    bad = tmp_path / "label.pvl"
    bad.write_text(re.sub(r"(?m)^(\s*)Samples\s*=\s*\d+", r"\1Samples = -5", text, count=1))
    with pytest.raises(BlockError, match=r"label\.pvl, line \d+, column 'Samples': 'Samples' must be an integer 1\.\."):
        read_cube_label(bad)


# --- Metashape ------------------------------------------------------------------------------------------

def test_metashape_calibration_covariance_of_unknown_parameters(ws, tmp_path):
    path = tmp_path / "cal.xml"
    code, err = run_main(["export", "metashape", ws.results, "--out", path, "--tolerance-px", "1"])
    assert code == 0, err
    text = path.read_text()
    path.write_text(re.sub(r"<params>\w+", "<params>zz", text, count=1))
    _fails(_import_calibration(ws, str(path), tmp_path), "cal.xml", "<covariance><params>")


def test_metashape_marker_accuracy_must_be_positive(tmp_path):
    from selfcal.io.metashape import read_markers_xml
    path = tmp_path / "markers.xml"
    path.write_text('<?xml version="1.0"?><document><chunk><cameras><camera id="0" label="A"/></cameras><markers>'
                    '<marker id="0" label="G1"><reference x="1" y="2" z="3" sx="-0.1" sy="0.1" sz="0.1" '
                    'enabled="true"/></marker></markers><frames><frame><markers><marker marker_id="0">'
                    '<location camera_id="0" x="10" y="20"/></marker></markers></frame></frames></chunk></document>')
    with pytest.raises(BlockError, match=r"markers\.xml, line 1: marker 'G1': the reference accuracies"):
        read_markers_xml(path)
    path.write_text(path.read_text().replace('sx="-0.1"', 'sx="0.1"').replace('enabled="true"', 'enabled="maybe"'))
    with pytest.raises(BlockError, match=r"markers\.xml, line 1: <reference enabled=...> must be true or false"):
        read_markers_xml(path)


# --- the Python API -------------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, names", [
    ({"snoop": -1}, "bundle_adjust(snoop=-1)"),
    ({"snoop": float("nan")}, "bundle_adjust(snoop=nan)"),
    ({"max_iterations": 0}, "bundle_adjust(max_iterations=0)"),
    ({"robust": "bogus"}, "bundle_adjust(robust='bogus')"),
    ({"nonsense": 1}, "bundle_adjust(nonsense=...)"),
])
def test_api_arguments_are_usage_errors_naming_them(ws, kwargs, names):
    import selfcal
    with pytest.raises(UsageError) as info:
        selfcal.bundle_adjust(ws.block, **kwargs)
    assert names in str(info.value), str(info.value)


def test_pvl_is_read_up_to_its_end_line_only(tmp_path):
    """A cube's label is read, not its pixels; an 'End_Object' cut by the 1 MB read boundary after 'End' is not
    taken for the label's 'End'."""
    from selfcal.io.pvl import read_pvl
    head = "Object = IsisCube\n  # " + "x" * 100 + "\n"
    body = "  Group = Dimensions\n    Samples = 5\n  End_Group\n"
    pad = 2**20 - len(head) - len(body) - len("End")
    text = head + body + " " * pad + "End_Object\nEnd\n"
    assert text.index("End_Object") + 3 == 2**20
    path = tmp_path / "cube.cub"
    path.write_bytes(text.encode() + b"\xff\x00" * 2**20)          # binary pixels after the label
    root = read_pvl(path)
    assert root.find("Object", "IsisCube").find("Group", "Dimensions").keyword("Samples").value == "5"
