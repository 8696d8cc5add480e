"""The adjustment report: figures, numbers equal to summary.json, re-rendering, and headless Chromium."""
import json
import math
import os
import shutil
import subprocess

import numpy as np
import pytest

from selfcal.batch import CellSettings, run_matrix
from selfcal.cli.compare import write_matrix
from selfcal.report import best_cells
from selfcal.report.compare import comparison_rows
from selfcal.report.figures import grid_mean_vectors, nice_length

from conftest import pruned, run_cli, simulation
from report_page import read_report

FIGURES = ["camera-layout", "distortion", "distortion-sigma", "residual-grid", "residual-histogram", "control-errors",
           "tie-precision", "correlation", "robust-weights", "rejection-map"]
#: every summary.json key that the summary section must print
PRINTED = ["sigma0_px", "variance_factor", "iterations", "redundancy", "n_observations", "n_unknowns",
           "rmsd_chk_xy_m", "rmsd_chk_z_m", "rmsd_chk_xy_gsd", "rmsd_chk_z_gsd", "ce90_chk_m", "le90_chk_m",
           "rms_sigma_tie_xy_m", "rms_sigma_tie_z_m", "n_gcp_used", "n_chk_used", "n_obs_rejected",
           "n_ap_initial", "n_ap_significant", "max_abs_corr.IOP", "max_abs_corr.EOP", "gsd_m", "selfcal_version",
           "options.ap_model", "options.image_sigma_px", "options.control_sigma_xy_m", "options.max_iterations"]


def _text(path) -> str:
    with open(path, encoding="utf-8") as handle:
        return handle.read()


def _lookup(summary, key):
    value = summary
    for part in key.split("."):
        value = value[part]
    return value


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    """A seed-000 block with a Brown lens and blunders, adjusted with Brown's APs; report rendered by adjust."""
    root = tmp_path_factory.mktemp("report")
    block = root / "block"
    assert run_cli("simulate", "uav", "--out", str(block), "--seed", "7", "--distortion", "brown",
                   "--blunder-rate", "0.002") == 0
    out = root / "results"
    assert run_cli("adjust", str(block / "type1"), "--out", str(out), "--ap", "brown", "--quiet") == 0
    return out


@pytest.mark.slow
def test_every_figure_is_written_and_embedded(adjusted):
    for name in FIGURES:
        for ext, magic in (("png", b"\x89PNG"), ("svg", b"<?xml")):
            path = adjusted / "figures" / f"{name}.{ext}"
            with open(path, "rb") as handle:
                head = handle.read(5)
            assert head.startswith(magic) and os.path.getsize(path) > 10_000, path
    report = read_report(adjusted / "report.html")
    assert len(report.images) == len(FIGURES)
    assert all(src.startswith("data:image/png;base64,") and len(src) > 10_000 for src in report.images)


@pytest.mark.slow
def test_report_numbers_equal_summary_json(adjusted):
    with open(adjusted / "summary.json") as handle:
        summary = json.load(handle)
    report = read_report(adjusted / "report.html")
    seen = {key for key, _, _ in report.cells}
    assert set(PRINTED) <= seen
    for key, exact, text in report.cells:
        value = _lookup(summary, key)
        if value is None:
            assert exact == "" and text == "–", key
            continue
        assert exact == repr(value), key                      # the page holds the very number of the JSON
        if isinstance(value, bool) or isinstance(value, str):
            assert text == str(value), key
            continue
        decimals = len(text.partition(".")[2])
        assert float(text) == pytest.approx(value, abs=0.5 * 10.0 ** -decimals + 1e-12), key


@pytest.mark.slow
def test_tables_list_points_flags_and_rejections(adjusted):
    with open(adjusted / "summary.json") as handle:
        summary = json.load(handle)
    report = read_report(adjusted / "report.html")
    # the rejected observations: data snooping's, largest |w| first, then the robust cleaning's, largest u first, up
    # to the 200-row cap (all are in residuals.csv)
    assert summary["n_obs_rejected"] > 0
    rejected = report.tables["rejected"]
    assert len(rejected) == min(summary["n_obs_rejected"], 200)
    by = [row[2][0] for row in rejected]
    assert by == sorted(by, key=lambda b: b == "robust") and "snooping" in by
    w = [abs(float(row[7][0])) for row in rejected if row[2][0] == "snooping"]
    assert min(w) > 3.0 and w == sorted(w, reverse=True)
    u = [float(row[8][0]) for row in rejected if row[2][0] == "robust"]
    assert all(x > summary["robust"]["reject_u"] for x in u) and u == sorted(u, reverse=True)
    lines = _text(adjusted / "residuals.csv").strip().split("\n")
    col_of = {h: i for i, h in enumerate(lines[0].split(","))}
    residuals = [r.split(",") for r in lines[1:]]
    w_file = sorted((abs(float(r[col_of["w_test"]])) for r in residuals if r[col_of["rejected_by"]] == "snooping"),
                    reverse=True)
    np.testing.assert_allclose(w, w_file[:len(w)], atol=0.006)
    n_robust = sum(r[col_of["rejected_by"]] == "robust" for r in residuals)
    assert n_robust == summary["robust"]["n_rejected"] and len(w_file) + n_robust == summary["n_obs_rejected"]
    # control and check points with their errors; a check point is flagged exactly when |d| > 3 sigma
    lines = _text(adjusted / "points.csv").strip().split("\n")
    header, data = lines[0].split(","), [line.split(",") for line in lines[1:]]
    col = {h: i for i, h in enumerate(header)}
    controls = [r for r in data if r[col["role"]] in ("gcp", "chk")]
    rows = {row[0][0]: row for row in report.tables["control-points"]}
    assert len(rows) == len(controls) == summary["n_gcp_used"] + summary["n_chk_used"]
    for r in controls:
        row = rows[r[col["point_id"]]]
        assert float(row[4][0]) == pytest.approx(float(r[col["dZ_m"]]), abs=5e-5)
        if r[col["role"]] == "chk":
            z = max(abs(float(r[col[f"d{c}_m"]])) / float(r[col[f"sigma_{c}_m"]]) for c in "XYZ")
            assert row.flag == (z > 3.0)
    # the AP table: one row per Brown coefficient, value as in camera.json
    camera = json.loads(_text(adjusted / "camera.json"))["cameras"]["ilce7m3"]
    ap_rows = report.tables["ap-ilce7m3"]
    assert [r[0][0] for r in ap_rows] == [c["name"] for c in camera["ap"]["coefficients"]]
    assert float(ap_rows[0][1][0]) == pytest.approx(camera["ap"]["coefficients"][0]["value_px"], abs=5e-5)
    assert len(report.tables["images"]) == summary["n_images"]


@pytest.mark.slow
def test_report_command_renders_again_from_the_files(adjusted, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(adjusted, copy)
    os.unlink(copy / "report.html")
    shutil.rmtree(copy / "figures")
    with open(copy / "figures-stale.txt", "w") as handle:   # not in figures/: left alone
        handle.write("x")
    assert run_cli("report", str(copy)) == 0
    assert f"{len(FIGURES)} figures" in capsys.readouterr().out      # the outcome line: stdout
    first, again = read_report(adjusted / "report.html"), read_report(copy / "report.html")
    assert again.cells == first.cells
    assert sorted(os.listdir(copy / "figures")) == sorted(os.listdir(adjusted / "figures"))


@pytest.mark.slow
def test_report_of_a_bad_folder_exits_2_naming_the_file(adjusted, tmp_path, capsys):
    assert run_cli("report", str(tmp_path / "nowhere")) == 2
    assert "no such results folder" in capsys.readouterr().err
    broken = tmp_path / "broken"
    shutil.copytree(adjusted, broken)
    lines = _text(broken / "points.csv").split("\n")
    fields = lines[3].split(",")
    fields[4] = "12,5"                                       # a decimal comma: one field too many
    lines[3] = ",".join(fields)
    with open(broken / "points.csv", "w") as handle:
        handle.write("\n".join(lines))
    assert run_cli("report", str(broken)) == 2
    err = capsys.readouterr().err
    assert "points.csv, line 4" in err and "fields" in err
    os.unlink(broken / "camera.json")
    assert run_cli("report", str(broken)) == 2
    assert "camera.json: missing" in capsys.readouterr().err


@pytest.mark.slow
def test_no_report_option_writes_no_report(adjusted, tmp_path):
    block = adjusted.parent / "block" / "type3"
    out = tmp_path / "res"
    assert run_cli("adjust", str(block), "--out", str(out), "--ap", "none", "--snoop", "0", "--no-report",
                   "--quiet") == 0
    assert not (out / "report.html").exists() and not (out / "figures").exists()
    assert (out / "summary.json").exists()


def _chromium():
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    assert exe, "Debian's chromium is needed for this test; `make test` installs it (make browser)"
    return exe


@pytest.mark.slow
def test_report_opens_in_headless_chromium(adjusted, tmp_path):
    exe = _chromium()
    url = (adjusted / "report.html").as_uri()
    common = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
              f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1100,3000"]
    shot = tmp_path / "shot.png"
    subprocess.run(common + [f"--screenshot={shot}", url], check=True, capture_output=True, timeout=180)
    dom = subprocess.run(common + ["--virtual-time-budget=5000", "--dump-dom", url], check=True,
                         capture_output=True, text=True, timeout=180).stdout
    pdf = tmp_path / "report.pdf"                             # printable: Chromium's print to PDF
    subprocess.run(common + [f"--print-to-pdf={pdf}", "--no-pdf-header-footer", url], check=True,
                   capture_output=True, timeout=180)
    with open(pdf, "rb") as handle:
        assert handle.read(5) == b"%PDF-"
    assert os.path.getsize(pdf) > 200_000                     # the figures went to paper too
    # the page's own check: every <img> loaded (complete, with a natural width)
    assert f'data-images="{len(FIGURES)}"' in dom and 'data-broken-images="0"' in dom
    from PIL import Image
    pixels = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert pixels.shape == (3000, 1100)
    ink = pixels < 200
    assert ink.mean() > 0.05                                  # text and figures, not a blank page
    assert ink[1500:].mean() > 0.02                           # the figures further down rendered too


def test_grid_mean_vectors_average_each_cell():
    rng = np.random.default_rng(3)
    col = rng.uniform(0, 600, 5000)
    row = rng.uniform(0, 400, 5000)
    truth_c = np.arange(6)[None, :] * 0.1 + np.arange(4)[:, None] * 0.01     # (Gy=4, Gx=6)
    ix, iy = (col / 100).astype(int), (row / 100).astype(int)
    vcol = truth_c[iy, ix] + rng.normal(0, 0.001, col.size)
    vrow = -truth_c[iy, ix]
    cx, cy, mc, mr, count = grid_mean_vectors(col, row, vcol, vrow, 600, 400, (6, 4))
    assert count.sum() == 5000 and cx[0, 0] == 50 and cy[-1, 0] == 350
    np.testing.assert_allclose(mc, truth_c, atol=3e-4)
    np.testing.assert_allclose(mr, -truth_c, atol=1e-12)
    assert [nice_length(x) for x in (0.7, 3.4, 12.0, 0.05)] == [0.5, 2.0, 10.0, 0.05]


@pytest.mark.slow
def test_comparison_report_links_the_best_model_of_each_scenario(tmp_path):
    sim = simulation(seed=6, distortion="brown", points_per_mm2=0.25)
    blocks = {name: pruned(sim, name) for name in ("type1", "type3")}
    cells = run_matrix(blocks, ["none", "brown"], CellSettings(), scheduler=None)
    rows = comparison_rows(cells)
    best = best_cells(rows)
    for scenario in blocks:
        scores = {r["ap_model"]: math.hypot(r["rmsd_xy_m"], r["rmsd_z_m"]) for r in rows
                  if r["scenario"] == scenario}
        assert best[scenario]["ap_model"] == min(scores, key=scores.get) == "brown"
    write_matrix(str(tmp_path), cells, rows, "test")
    page = read_report(tmp_path / "report.html")
    assert len(page.images) == 3                              # Figs. 3, 4 and 5
    html = _text(tmp_path / "report.html")
    for scenario in blocks:
        assert f'href="{scenario}/brown/report.html"' in html
        assert (tmp_path / scenario / "brown" / "report.html").exists()
        assert not (tmp_path / scenario / "none" / "report.html").exists()
