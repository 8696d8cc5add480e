"""The report's opening sections (issue 45 item 7): camera layout and overlap, processing parameters, the camera's
initial against adjusted values; long AP tables folded with every row in parameters.csv."""
import csv
import json
import shutil
from collections import Counter

import numpy as np
import pytest

from selfcal.report.figures import OVERLAP_TOP, camera_layout_figure
from selfcal.report.render import MAX_AP_ROWS
from selfcal.workflows.api import bundle_adjust

from conftest import pruned, run_cli, simulation
from report_page import ReportPage, read_report

CAMERA = "ilce7m3"


def _page(folder) -> ReportPage:
    return read_report(folder / "report.html")


def _csv(path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _close(text: str, value: float) -> bool:
    """A printed number equals ``value`` to half its last decimal."""
    decimals = len(text.partition(".")[2])
    return abs(float(text) - value) <= 0.5 * 10.0 ** -decimals + 1e-12


@pytest.fixture(scope="module")
def simulated():
    """A small seed-000 block (Brown lens, blunders; 1,000 points) with known camera."""
    sim = simulation(seed=6, distortion="brown", points_per_mm2=0.25, blunder_rate=0.003)
    return sim, pruned(sim, "type1")


@pytest.fixture(scope="module")
def brown(simulated, tmp_path_factory):
    folder = tmp_path_factory.mktemp("sections") / "brown"
    bundle_adjust(simulated[1], "brown").write(folder)
    return folder


@pytest.fixture(scope="module")
def wavelet(simulated, tmp_path_factory):
    folder = tmp_path_factory.mktemp("sections") / "wavelet"
    bundle_adjust(simulated[1], "wavelet:db4", grid=(5, 4)).write(folder)
    return folder


def test_overlap_table_counts_the_images_of_each_point_from_the_observations(brown):
    page = _page(brown)
    assert "Camera layout and overlap" in page.alts
    assert (brown / "figures" / "camera-layout.png").stat().st_size > 10_000
    assert (brown / "figures" / "camera-layout.svg").exists()
    # the images of each point, counted here from residuals.csv: distinct images of its observations kept
    residuals = _csv(brown / "residuals.csv")
    kept = {(r["image_id"], r["point_id"]) for r in residuals if r["rejected"] == "0" and r["vx_px"]}
    counted = Counter(point for _, point in kept)
    every = Counter(r["point_id"] for r in residuals)
    assert any(counted[p] < every[p] for p in every)          # rejections lower some counts: they are excluded
    points = _csv(brown / "points.csv")
    expected: dict[int, list[int]] = {}
    for p in points:
        row = expected.setdefault(counted.get(p["point_id"], 0), [0, 0])
        row[p["role"] in ("gcp", "chk")] += 1
    table = page.tables["overlap"]
    assert {int(r[0][0]): [int(r[1][0]), int(r[2][0])] for r in table} == expected
    assert sum(float(r[3][0]) for r in table) == pytest.approx(100.0, abs=0.05 * len(table))
    assert min(expected) >= 2 and max(expected) >= OVERLAP_TOP       # the block's overlap: 2 to more than 9


def test_layout_figure_colours_each_point_by_its_count_and_draws_the_centres():
    rng = np.random.default_rng(1)
    xy = rng.uniform(-100, 100, (50, 2))
    counts = np.arange(50) % 14                                # 0 (grey) to 13 (drawn as 9+)
    role = np.array(["gcp", "chk"] + ["tie"] * 48, dtype=object)
    centres = np.array([[-50.0, 0.0], [0.0, 0.0], [50.0, 0.0], [-50.0, 60.0]])
    fig = camera_layout_figure(xy, counts, role, centres, ["S1", "S1", "S1", "S2"], ["a", "b", "c", "d"], "t")
    ax = fig.axes[0]
    tie = (role == "tie") & (counts > 0)
    coloured = ax.collections[1]
    np.testing.assert_array_equal(coloured.get_array(), np.minimum(counts[tie], OVERLAP_TOP))
    np.testing.assert_allclose(coloured.get_offsets(), xy[tie] - xy.mean(axis=0))
    assert fig.axes[1].get_ylabel() == "images per point"
    assert fig.axes[1].get_yticklabels()[-1].get_text() == f"{OVERLAP_TOP}+"
    cross = next(line for line in ax.lines if line.get_label() == "projection centres")
    np.testing.assert_allclose(np.column_stack(cross.get_data()), centres - xy.mean(axis=0))
    assert f"median {np.median(counts[counts > 0]):g} images per point" in ax.get_title(loc="left")


def test_processing_parameters_hold_the_run_options(simulated, brown):
    block = simulated[1]
    summary = json.loads((brown / "summary.json").read_text())
    options = summary["options"]
    gcp = block.points.role == "gcp"
    assert options["ap_model"] == "brown" and options["image_sigma_px"] == block.image_sigma_px == 0.5
    assert options["control_sigma_xy_m"] == pytest.approx(float(np.median(block.points.sigma_m[gcp, :2])))
    assert options["control_sigma_z_m"] == pytest.approx(float(np.median(block.points.sigma_m[gcp, 2])))
    assert options["snooping"]["critical"] == 3.0 and options["robust"]["loss"] == "danish"
    assert options["screening"] is None and options["max_iterations"] == 50
    rows = {r[0][0]: r[1:] for r in _page(brown).tables["processing"]}
    assert rows["AP model asked for"][0][0] == rows["AP model used"][0][0] == "brown"
    assert rows["a-priori σ of an image coordinate [px]"][0][0] == "0.5"
    assert rows["selfcal version"][0][0] == summary["selfcal_version"]
    assert rows["parameter screening"][0][0].startswith("off")
    assert rows["robust cleaning"][0][0].startswith("danish loss")
    xy, z = (rows[f"a-priori σ of the control points {axis} [m] (median)"] for axis in ("XY", "Z"))
    assert _close(xy[0][0], options["control_sigma_xy_m"]) and _close(z[0][0], options["control_sigma_z_m"])
    assert rows["iteration limit"][0][0] == "50" and int(rows["iterations"][0][0]) == summary["iterations"]
    # every cell that names a summary.json key holds its very value
    cells = [c for r in rows.values() for c in r if c[1]]
    assert len(cells) >= 10
    for text, key, exact in cells:
        value = summary
        for part in key.split("."):
            value = value[part]
        assert exact == repr(value), key


def test_camera_table_is_initial_against_adjusted_from_the_files(simulated, brown):
    sim, block = simulated
    page = _page(brown)
    table = page.tables["camera-change"]
    parameters = {r["parameter"]: r for r in _csv(brown / "parameters.csv") if r["owner"] == CAMERA}
    camera = json.loads((brown / "camera.json").read_text())["cameras"][CAMERA]
    names = [r[0][0] for r in table]
    assert names == ["c", "x0", "y0"] + [c["name"] for c in camera["ap"]["coefficients"]]
    for row in table:
        p = parameters[row[0][0]]
        initial, adjusted, difference, sigma = (c[0] for c in row[2:6])
        assert row[1][0] == p["unit"]
        assert _close(initial, float(p["start"])) and _close(adjusted, float(p["value"]))
        assert _close(difference, float(p["value"]) - float(p["start"]))
        assert float(sigma) == pytest.approx(float(p["sigma"]), rel=1e-12)
    by_name = {r[0][0]: r for r in table}
    # the initial values are the block's camera, the adjusted ones camera.json's; within 4 sigma of the truth
    start = block.cameras[CAMERA]
    truth = sim.truth.camera
    for name, key, first, true in (("c", "focal_mm", start.focal_mm, truth.focal_mm),
                                   ("x0", "x0_mm", start.x0_mm, truth.x0_mm),
                                   ("y0", "y0_mm", start.y0_mm, truth.y0_mm)):
        cells = [c[0] for c in by_name[name]]
        assert _close(cells[2], first) and _close(cells[3], camera[key]["value"])
        assert float(cells[5]) == pytest.approx(camera[key]["sigma"], rel=5e-3)
        assert abs(camera[key]["value"] - true) < 4 * camera[key]["sigma"], name
    assert abs(camera["focal_mm"]["value"] - start.focal_mm) > 3 * camera["focal_mm"]["sigma"] or \
        abs(camera["x0_mm"]["value"]) > 3 * camera["x0_mm"]["sigma"]          # the table shows a real change
    k1 = next(c for c in camera["ap"]["coefficients"] if c["name"] == "k1")
    assert _close(by_name["k1"][3][0], k1["value_px"])
    # Brown's seven coefficients: the AP table is not folded
    assert len(page.tables[f"ap-{CAMERA}"]) == 7 and f"ap-{CAMERA}" not in page.folded


def test_long_ap_table_is_folded_with_every_row_in_the_csv(wavelet):
    page = _page(wavelet)
    html = (wavelet / "report.html").read_text(encoding="utf-8")
    camera = json.loads((wavelet / "camera.json").read_text())["cameras"][CAMERA]
    coefficients = camera["ap"]["coefficients"]
    summary = json.loads((wavelet / "summary.json").read_text())
    assert len(coefficients) == summary["n_ap_initial"] == 138 > MAX_AP_ROWS
    # every coefficient is in parameters.csv, with its value
    rows = [r for r in _csv(wavelet / "parameters.csv") if r["owner"] == CAMERA and r["group"] == "AP"]
    assert [r["parameter"] for r in rows] == [c["name"] for c in coefficients]
    np.testing.assert_allclose([float(r["value"]) for r in rows], [c["value_px"] for c in coefficients],
                               rtol=1e-8, atol=1e-9)
    # the page: the MAX_AP_ROWS coefficients with the largest t, in their order, in a <details> fold
    table = page.tables[f"ap-{CAMERA}"]
    assert f"ap-{CAMERA}" in page.folded and len(table) == MAX_AP_ROWS
    t = np.array([abs(c["value_px"]) / c["sigma_px"] for c in coefficients])
    largest = sorted(np.argsort(-t, kind="stable")[:MAX_AP_ROWS])
    assert [r[0][0] for r in table] == [coefficients[i]["name"] for i in largest]
    assert min(float(r[3][0]) for r in table) >= np.sort(t)[-MAX_AP_ROWS] - 0.05
    assert f"all {len(coefficients)} coefficients" in html and "parameters.csv (group AP)" in html
    # the camera table keeps to c, x0, y0 and says where the APs are
    assert [r[0][0] for r in page.tables["camera-change"]] == ["c", "x0", "y0"]
    assert f"{CAMERA}: {len(coefficients)} APs, in the AP table below (folded)" in html
    processing = {r[0][0]: r[1:] for r in page.tables["processing"]}
    assert processing["AP grid Gx × Gy"][0][0] == "5 × 4"


def test_results_without_options_render_and_say_so(brown, tmp_path, capsys):
    old = tmp_path / "old"
    shutil.copytree(brown, old)
    summary = json.loads((old / "summary.json").read_text())
    del summary["options"]
    (old / "summary.json").write_text(json.dumps(summary))
    assert run_cli("report", str(old), "--quiet") == 0
    capsys.readouterr()
    page = _page(old)
    rows = {r[0][0]: r[1:] for r in page.tables["processing"]}
    assert rows["AP model used"][0][0] == "brown" and "AP model asked for" not in rows
    assert "does not record the run" in (old / "report.html").read_text(encoding="utf-8")
    assert len(page.tables["overlap"]) == len(_page(brown).tables["overlap"])
