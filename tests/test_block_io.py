"""Block folder input: every defect is an error naming file, line and column (exit code 2);
conditions a real block has are warnings, counted in summary.json."""
import json
import os
import shutil

import numpy as np
import pytest

from selfcal.errors import BlockError
from selfcal.io import read_block, write_block

from conftest import run_cli, simulation


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    folder = tmp_path_factory.mktemp("template") / "block"
    write_block(simulation(seed=2, distortion="none", points_per_mm2=0.05).blocks["type3"], folder)
    return folder


@pytest.fixture
def block(template, tmp_path):
    folder = tmp_path / "block"
    shutil.copytree(template, folder)
    return folder


def _read(path) -> str:
    with open(path) as handle:
        return handle.read()


def _write(path, text: str) -> None:
    with open(path, "w") as handle:
        handle.write(text)


def edit(path, line: int, old: str, new: str):
    """Replace ``old`` by ``new`` on 1-based ``line`` of a file."""
    lines = _read(path).split("\n")
    assert old in lines[line - 1], (old, lines[line - 1])
    lines[line - 1] = lines[line - 1].replace(old, new, 1)
    _write(path, "\n".join(lines))


def expect_error(folder, file: str, line, column, reason: str, tmp_path):
    with pytest.raises(BlockError) as info:
        read_block(folder)
    err = info.value
    assert os.path.basename(err.path) == file
    assert err.line == line
    assert err.column == column
    assert reason in err.reason
    text = str(err)
    assert file in text and (line is None or f"line {line}" in text)
    # the command line reports the same and exits 2, writing nothing
    out = tmp_path / "results"
    assert run_cli("adjust", str(folder), "--out", str(out), "--quiet") == 2
    assert not out.exists()
    return err


def test_template_reads(template):
    block = read_block(template)
    assert len(block.images) == 28
    assert np.sum(block.points.role == "gcp") == 27


def test_missing_file(block, tmp_path):
    os.remove(block / "points.csv")
    expect_error(block, "points.csv", None, None, "file not found", tmp_path)


def test_missing_column(block, tmp_path):
    edit(block / "observations.csv", 1, "row_px", "row")
    # 'row' is unknown, reported before the missing 'row_px'
    expect_error(block, "observations.csv", 1, "row", "unknown column", tmp_path)


def test_missing_required_column(block, tmp_path):
    edit(block / "images.csv", 1, ",strip_id", "")
    lines = _read(block / "images.csv").split("\n")
    lines = [lines[0]] + [",".join(l.split(",")[:2] + l.split(",")[3:]) for l in lines[1:] if l]
    _write(block / "images.csv", "\n".join(lines) + "\n")
    expect_error(block, "images.csv", 1, "strip_id", "missing column", tmp_path)


def test_unknown_toml_key(block, tmp_path):
    text = _read(block / "block.toml").replace("focal_mm = 21.0", "focal_mm = 21.0\nfocal_lenght = 21.0")
    _write(block / "block.toml", text)
    line = text.split("\n").index("focal_lenght = 21.0") + 1
    expect_error(block, "block.toml", line, "cameras.ilce7m3.focal_lenght", "unknown key", tmp_path)


def test_bad_toml_value(block, tmp_path):
    text = _read(block / "block.toml").replace("image_sigma_px = 0.5", "image_sigma_px = -0.5")
    _write(block / "block.toml", text)
    line = text.split("\n").index("image_sigma_px = -0.5") + 1
    expect_error(block, "block.toml", line, "observations.image_sigma_px", "must be positive", tmp_path)


def test_non_numeric_value(block, tmp_path):
    line = _read(block / "observations.csv").split("\n")[6]
    fields = line.split(",")
    fields[2] = "12.5x"
    edit(block / "observations.csv", 7, line, ",".join(fields))
    expect_error(block, "observations.csv", 7, "col_px", "'12.5x' is not a number", tmp_path)


def test_nan_value(block, tmp_path):
    line = _read(block / "points.csv").split("\n")[3]
    fields = line.split(",")
    fields[4] = "nan"
    edit(block / "points.csv", 4, line, ",".join(fields))
    expect_error(block, "points.csv", 4, "Z", "not a finite number", tmp_path)


def test_duplicated_id(block, tmp_path):
    lines = _read(block / "images.csv").split("\n")
    first = lines[3].split(",")[0]
    lines[5] = first + "," + lines[5].split(",", 1)[1]
    _write(block / "images.csv", "\n".join(lines))
    err = expect_error(block, "images.csv", 6, "image_id", f"duplicated id '{first}'", tmp_path)
    assert "first on line 4" in err.reason


def test_observation_of_unknown_image(block, tmp_path):
    line = _read(block / "observations.csv").split("\n")[9]
    edit(block / "observations.csv", 10, line.split(",")[0] + ",", "S9_99,")
    expect_error(block, "observations.csv", 10, "image_id", "unknown image 'S9_99'", tmp_path)


def test_observation_of_unknown_point(block, tmp_path):
    line = _read(block / "observations.csv").split("\n")[11]
    point = line.split(",")[1]
    edit(block / "observations.csv", 12, "," + point + ",", ",NOPE,")
    expect_error(block, "observations.csv", 12, "point_id", "unknown point 'NOPE'", tmp_path)


def test_observation_outside_image_is_dropped_and_counted(block):
    """One observation outside the frame (a blunder, a border measurement) is left out with a warning."""
    n = len(read_block(block).observations)
    line = _read(block / "observations.csv").split("\n")[4]
    fields = line.split(",")
    fields[3] = "4004.8"                                       # 4.8 px below a 4000-px-high frame
    edit(block / "observations.csv", 5, line, ",".join(fields))
    read = read_block(block)
    assert len(read.observations) == n - 1
    assert read.dropped.observations_outside_frame == 1
    assert read.dropped.as_dict()["observations_outside_frame"] == 1
    assert any("line 5" in m and "outside" in m and fields[1] in m for m in read.dropped.messages)


def test_most_observations_of_an_image_outside_names_units(block, tmp_path):
    """Most of an image's observations outside its frame is a unit mistake: an error naming the image."""
    lines = _read(block / "observations.csv").split("\n")
    image = lines[1].split(",")[0]
    first = None
    for k, line in enumerate(lines[1:], start=2):
        fields = line.split(",")
        if fields[0] == image:
            fields[3] = str(float(fields[3]) * 1000.0 + 5000.0)   # "row in mm x 1000", all outside
            lines[k - 1] = ",".join(fields)
            first = first or k
    _write(block / "observations.csv", "\n".join(lines))
    err = expect_error(block, "observations.csv", first, "row_px", "outside the image", tmp_path)
    assert f"image '{image}'" in err.reason and "are the units pixels?" in err.reason


def test_wrong_field_count(block, tmp_path):
    line = _read(block / "points.csv").split("\n")[2]
    edit(block / "points.csv", 3, line, line + ",7")
    expect_error(block, "points.csv", 3, None, "expected 7 fields, found 8", tmp_path)


def test_fewer_than_three_gcps(block, tmp_path):
    lines = _read(block / "points.csv").split("\n")
    gcp_lines = [i for i, l in enumerate(lines) if ",gcp," in l]
    for i in gcp_lines[2:]:
        lines[i] = lines[i].replace(",gcp,", ",chk,")
    _write(block / "points.csv", "\n".join(lines))
    err = expect_error(block, "points.csv", None, "role", "only 2 usable gcp", tmp_path)
    assert "[gnss]" in err.reason


def test_real_block_conditions_are_warnings_counted_in_summary(block, tmp_path):
    # a tie point seen in one image, a GCP and a CHK seen in none, an image with too few points
    obs = _read(block / "observations.csv").split("\n")
    header, rows = obs[0], [r for r in obs[1:] if r]
    ties = {}
    for r in rows:
        ties.setdefault(r.split(",")[1], []).append(r)
    single = next(p for p, rs in ties.items() if p.startswith("T") and len(rs) >= 2)
    drop = set(ties[single][1:])
    gcp = next(p for p in ties if p.startswith("M"))
    pts = _read(block / "points.csv")
    role = next(l.split(",")[1] for l in pts.split("\n") if l.startswith(gcp + ","))
    drop |= set(ties[gcp])
    lonely_image = "S4_07"
    image_rows = [r for r in rows if r.startswith(lonely_image + ",")]
    drop |= set(image_rows[4:])
    kept = [r for r in rows if r not in drop]
    _write(block / "observations.csv", "\n".join([header] + kept) + "\n")
    out = tmp_path / "res"
    assert run_cli("adjust", str(block), "--out", str(out), "--quiet") == 0
    summary = json.loads(_read(out / "summary.json"))
    dropped = summary["dropped"]
    assert dropped["images_too_few_points"] == 1
    assert dropped["tie_points_one_image"] >= 1
    assert dropped["control_points_unobserved"] + dropped["check_points_one_image"] >= 1
    assert any(lonely_image in w for w in summary["warnings"])
    assert any(single in w for w in summary["warnings"])
    assert any(gcp in w for w in summary["warnings"]), role
    assert summary["n_images"] == 27


def test_ids_with_spaces_quotes_and_commas_round_trip(template, tmp_path):
    """block.toml is written by tomli-w and the CSVs quote: a camera called ``Canon "EOS" 450D`` (issue 23),
    image and point ids with commas, quotes and brackets come back exactly."""
    import dataclasses
    original = read_block(template)
    (old_camera,) = original.cameras
    new_camera = 'Canon "EOS" 450D, [x]'
    camera = dataclasses.replace(original.cameras[old_camera], camera_id=new_camera)
    images = dataclasses.replace(original.images, camera_id=np.array([new_camera] * len(original.images.image_id),
                                                                       dtype=object),
                                 image_id=np.array([f'IMG "{i}", left' for i in original.images.image_id],
                                                   dtype=object))
    points = dataclasses.replace(original.points,
                                 point_id=np.array([f"p'{p}\"" for p in original.points.point_id], dtype=object))
    renamed = dataclasses.replace(original, name='block "α", v2', cameras={new_camera: camera}, images=images,
                                  points=points)
    folder = tmp_path / "renamed"
    write_block(renamed, folder)
    back = read_block(folder)
    assert back.name == renamed.name
    assert list(back.cameras) == [new_camera] and back.cameras[new_camera].focal_mm == camera.focal_mm
    assert list(back.images.image_id) == list(images.image_id)
    assert list(back.points.point_id) == list(points.point_id)
    np.testing.assert_array_equal(back.observations.pixel, original.observations.pixel)
    # and the CLI adjusts it
    assert run_cli("adjust", str(folder), "--out", str(tmp_path / "res"), "--quiet", "--no-report",
                   "--snoop", "0") == 0


def test_table_columns_at_once_equal_value_by_value(tmp_path):
    """read_table converts each number column in one pass (empty optional values read as NaN); a table it cannot
    (a word, a NaN written out) goes value by value, which says where. Both give the same values; the errors name
    line and column."""
    from selfcal.io.table import NUM, OPT_NUM, STR, Column, read_table

    columns = [Column("id", STR, True), Column("x", NUM, True), Column("s", OPT_NUM, False)]
    path = tmp_path / "t.csv"
    path.write_text("id,x,s\n a ,1.5, 2\nb, -3e2 ,1_0\n# comment\n\nc,+4,0.25\n")
    fast = read_table(path, columns)
    assert fast["id"].tolist() == ["a", "b", "c"] and fast.line.tolist() == [2, 3, 6]
    np.testing.assert_array_equal(fast["x"], [1.5, -300.0, 4.0])
    np.testing.assert_array_equal(fast["s"], [2.0, 10.0, 0.25])
    from selfcal.io import table as table_module
    rows = [(2, ["a", "1.5", ""]), (3, ["b", "-3e2", " 1 "]), (4, ["c", "2", "  "])]
    path.write_text("id,x,s\na,1.5,\nb,-3e2, 1 \nc,2,  \n")           # empty optional values: at once
    slow = table_module._columns_value_by_value(str(path), ["id", "x", "s"], rows, {c.name: c for c in columns})
    fast = read_table(path, columns)
    np.testing.assert_array_equal(fast["s"], slow["s"])
    np.testing.assert_array_equal(fast["x"], slow["x"])
    assert np.isnan(fast["s"][[0, 2]]).all() and fast["s"][1] == 1.0
    path.write_text("id,x,s\na,1.5,\nb,-3e2,\n")                         # a column of empty values only
    assert np.isnan(read_table(path, columns)["s"]).all()
    for body, line, column, words in (("a,1,2\nb,x,2\nc,1,y\n", 3, "x", "not a number"),
                                      ("a,1,2\nb,1,nan\n", 3, "s", "not a finite number"),
                                      ("a,1,\nb,1, inf\n", 3, "s", "not a finite number"),
                                      ("a,1,2\nb,,2\n", 3, "x", "empty value")):
        path.write_text("id,x,s\n" + body)
        with pytest.raises(BlockError) as error:
            read_table(path, columns)
        assert f"line {line}" in str(error.value) and column in str(error.value) and words in str(error.value)


TRICKY_TABLE = ('\ufeffid,x,s\r\n'
                'a,1.5,2\r\n'
                '# a comment\r\n'
                '\r\n'
                '"b, with\r\na line break",-3e2,\r\n'
                ' , ,\r\n'
                'c,+4,0.25\r\n'
                '  # an indented comment\r\n'
                '"#d",5,1\r\n'                  # a comment too: its first field starts with #
                'e,6,\r\n')
TRICKY_IDS = ["a", "b, with\r\na line break", "c", "e"]
TRICKY_LINES = [2, 6, 8, 11]


@pytest.mark.parametrize("rows_per_chunk", [1, 2, 3, 1000])
@pytest.mark.parametrize("bytes_per_block", [1, 7, 1 << 23])
def test_a_table_read_in_chunks_is_the_table_read_at_once(tmp_path, monkeypatch, rows_per_chunk, bytes_per_block):
    """read_table_chunks gives the rows of every chunk with their file lines (the last line of a row that a quoted line
    break spans), over comments, blank rows, a byte-order mark and CRLF endings, whatever the chunk and decoded block
    sizes; read_table is their concatenation."""
    from selfcal.io import table as table_module
    from selfcal.io.table import NUM, OPT_NUM, STR, Column, read_table, read_table_chunks

    monkeypatch.setattr(table_module, "BYTES_PER_BLOCK", bytes_per_block)
    columns = [Column("id", STR, True), Column("x", NUM, True), Column("s", OPT_NUM, False)]
    path = tmp_path / "t.csv"
    path.write_bytes(TRICKY_TABLE.encode("utf-8"))
    chunks = list(read_table_chunks(path, columns, rows_per_chunk))
    assert all(0 < len(chunk) <= rows_per_chunk for chunk in chunks)
    assert [i for chunk in chunks for i in chunk["id"].tolist()] == TRICKY_IDS
    assert [n for chunk in chunks for n in chunk.line.tolist()] == TRICKY_LINES
    whole = read_table(path, columns)
    assert whole["id"].tolist() == TRICKY_IDS and whole.line.tolist() == TRICKY_LINES
    np.testing.assert_array_equal(whole["x"], [1.5, -300.0, 4.0, 6.0])
    np.testing.assert_array_equal(whole["s"], [2.0, np.nan, 0.25, np.nan])
    path.write_text("id,x,s\n")                                    # a header alone: one empty chunk
    (empty,) = read_table_chunks(path, columns, rows_per_chunk)
    assert len(empty) == 0 and empty["x"].dtype == float


@pytest.mark.parametrize("rows_per_chunk", [1, 4, 1000])
def test_a_defect_in_a_later_chunk_names_its_line(tmp_path, monkeypatch, rows_per_chunk):
    """Read a chunk at a time and a block of bytes at a time, a defect far into the file still names its line (and
    the first defect in line order is the one named)."""
    from selfcal.io import table as table_module
    from selfcal.io.table import NUM, STR, Column, read_table

    monkeypatch.setattr(table_module, "BYTES_PER_BLOCK", 16)
    columns = [Column("id", STR, True), Column("x", NUM, True)]
    good = "".join(f"p{i},{i}.5\n" for i in range(30))                # lines 2-31
    path = tmp_path / "t.csv"
    for tail, line, words in (("q,x\nr,1,2\n", 32, "'x' is not a number"),
                              ("q,1,2\nr,x\n", 32, "expected 2 fields, found 3"),
                              ("q,1\nr,\n", 33, "empty value where a number is required"),
                              ("q,1\nr,nan\n", 33, "not a finite number")):
        path.write_text("id,x\n" + good + tail)
        with pytest.raises(BlockError) as error:
            read_table(path, columns)
        assert error.value.line == line and words in error.value.reason, (tail, error.value)
    path.write_bytes(("id,x\n" + good).encode() + b"q\xe9,1\n")           # Latin-1, not UTF-8
    with pytest.raises(BlockError) as error:
        read_table(path, columns)
    assert error.value.line == 32 and "byte 0xe9 at character 2" in error.value.reason


def test_observations_are_read_a_chunk_at_a_time(template, tmp_path, monkeypatch):
    """observations.csv read in chunks of 2048 rows (and 64 kB of text) holds one chunk's texts at a time: the block is
    the same as read in one chunk, and the memory the reading holds at its peak (traced) is less than half of it read in
    one (3.7 MB against 13.5 MB: the texts of 22,758 rows); an unknown id in a later chunk names its line, the first in
    line order whether image or point."""
    import tracemalloc

    from selfcal.io import table as table_module

    folder = tmp_path / "block"
    write_block(simulation(seed=2, distortion="none", points_per_mm2=1.0).blocks["type3"], folder)
    peaks, blocks = {}, {}
    whole = os.path.getsize(folder / "observations.csv") + 1        # one block (a larger read buffer is traced too)
    for rows in (2048, 1 << 30):
        monkeypatch.setattr(table_module, "ROWS_PER_CHUNK", rows)
        monkeypatch.setattr(table_module, "BYTES_PER_BLOCK", 1 << 16 if rows == 2048 else whole)
        tracemalloc.start()
        blocks[rows] = read_block(folder)
        peaks[rows] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    small, whole = blocks[2048].observations, blocks[1 << 30].observations
    assert len(small) > 20_000
    for name in ("image_index", "point_index", "pixel", "sigma_px", "line"):
        np.testing.assert_array_equal(getattr(small, name), getattr(whole, name))
    assert peaks[2048] < 0.5 * peaks[1 << 30], peaks
    monkeypatch.setattr(table_module, "ROWS_PER_CHUNK", 2048)
    path = folder / "observations.csv"
    lines = _read(path).split("\n")
    image, point = lines[9000].split(",")[:2]
    lines[9000] = lines[9000].replace(point, "nowhere", 1)
    lines[12000] = lines[12000].replace(lines[12000].split(",")[0], "no-image", 1)
    _write(path, "\n".join(lines))
    with pytest.raises(BlockError) as error:
        read_block(folder)
    assert error.value.line == 9001 and error.value.column == "point_id" and "'nowhere'" in error.value.reason
    lines[9000] = f"{image},{point}," + ",".join(lines[9000].split(",")[2:])
    lines[9000] = lines[9000].replace(image, "no-image", 1)
    _write(path, "\n".join(lines))
    with pytest.raises(BlockError) as error:
        read_block(folder)
    assert error.value.line == 9001 and error.value.column == "image_id"
