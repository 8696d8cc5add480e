"""Diagnosis of what an adjustment left systematic (issue 40 item 4): the residual-field and dome tests.

Truth first: the tests on synthetic numbers with a known field or dome (found, its size recovered) and without
(not found); then whole seed-000 blocks: a right model (nothing found), a local lens defect of 0.3 px that no AP
family represents (the field found, in its zone), a radial error left in a nadir block with GNSS-only control
(the dome found); and summary.json / report.html carry the same numbers. The 30-seed rates are in
benchmarks/study_diagnosis.py (closing note of issue 40).
"""
from dataclasses import replace

import numpy as np
import pytest

from selfcal.simulate import simulate_uav
from selfcal.stats.diagnosis import ALPHA, PRACTICAL_FIELD_PX, dome_test, findings, residual_field_test
from selfcal.workflows.api import bundle_adjust

from conftest import pruned, run_cli, simulation
from report_page import read_report

W, H = 6000.0, 4000.0


def synthetic_residuals(rng, n=40000, sigma=0.5, redundancy=0.7, bump_px=0.0):
    """Independent residuals of variance sigma^2 r over a 6000 x 4000 frame; ``bump_px``: a Gaussian
    displacement of that peak (x only) centred at (4750, 1250), 400 px wide."""
    col, row = rng.uniform(0, W, n), rng.uniform(0, H, n)
    v = rng.normal(0.0, sigma * np.sqrt(redundancy), (n, 2))
    v[:, 0] += bump_px * np.exp(-((col - 4750) ** 2 + (row - 1250) ** 2) / (2 * 400.0 ** 2))
    return col, row, v, np.full(n, sigma), np.full((n, 2), redundancy)


def test_field_test_holds_its_level_and_finds_a_local_defect():
    rng = np.random.default_rng(3)
    alarms = sum(residual_field_test("c", *synthetic_residuals(rng), W, H, (12, 8), seed=k).found
                 for k in range(100))
    print(f"right model: {alarms} alarms in 100 draws (alpha {ALPHA:g} for each of two statistics)")
    assert alarms <= 1                                           # 0.2 expected; 2 or more: p < 0.02
    found = residual_field_test("c", *synthetic_residuals(rng, bump_px=0.3), W, H, (12, 8))
    print(f"0.3 px defect: T {found.statistic:.0f} / {found.critical:.0f}, largest zone "
          f"{found.largest_zone_statistic:.0f} / {found.largest_zone_critical:.0f} at {found.largest_zone}, "
          f"{found.largest_zone_mean_px:.3f} px; detectable RMS {found.detectable_rms_px:.3f} px")
    assert found.found and found.largest_zone == (9, 2)          # the zone of (4750, 1250) on 500 px zones
    assert found.largest_zone_mean_px >= PRACTICAL_FIELD_PX


def test_a_significant_but_tiny_field_is_not_found():
    """At 400 000 observations a 0.02 px shift everywhere is significant; it is below the practical size."""
    col, row, v, s, r = synthetic_residuals(np.random.default_rng(4), n=400000)
    v[:, 0] += 0.02
    test = residual_field_test("c", col, row, v, s, r, W, H, (6, 4))
    assert test.statistic > test.critical and not test.found


def test_dome_test_recovers_a_known_dome():
    rng = np.random.default_rng(5)
    xy = rng.uniform(-300, 300, (30, 2))
    r2 = np.sum(xy ** 2, axis=1)
    b_true = -2e-6                                             # 0.36 m at 424 m
    dz = 0.01 + b_true * r2 + rng.normal(0, 0.03, 30)
    dome = dome_test(xy, dz, np.zeros(2))
    assert dome.found and abs(dome.b_per_m2 - b_true) < 3 * dome.sigma_b_per_m2
    assert dome.dome_height_m == pytest.approx(dome.b_per_m2 * dome.radius_m ** 2)
    assert "dome" in findings([], dome)[0] and "James & Robson" in findings([], dome)[0]
    flat = dome_test(xy, 0.01 + rng.normal(0, 0.03, 30), np.zeros(2))
    assert not flat.found and flat.detectable_height_m > 0
    assert findings([], flat)[0].startswith("no systematic error found")
    assert dome_test(xy[:5], dz[:5], np.zeros(2)) is None


def gnss_only(block):
    """Every control point a check point: the datum from the GNSS camera positions alone."""
    role = np.where(block.points.role == "gcp", "chk", block.points.role)
    return replace(block, points=replace(block.points, role=role))


def diagnosis_of(block, ap, **options):
    return bundle_adjust(block, ap, max_iterations=30, **options).files["summary.json"]["diagnosis"]


def test_right_model_finds_nothing():
    d = diagnosis_of(pruned(simulation(seed=2, distortion="brown"), "type1"), "brown")
    assert not any(f["found"] for f in d["residual_field"]) and not d["dome"]["found"], d
    assert [tuple(f["grid"]) for f in d["residual_field"]] == [(6, 4), (12, 8)]
    assert d["findings"][0].startswith("no systematic error found")


def test_local_lens_defect_of_a_third_of_a_pixel_is_found():
    """The simulator's two Gaussian bumps scaled to 0.3 px, adjusted with no AP: the field is found on the 12 x 8
    grid, in a zone of the stronger bump (x 12.5 mm, y 7 mm from the centre: column 10, row 1)."""
    sim = simulate_uav(seed=2, distortion="local", distortion_scale=0.3 / 2.88)
    d = diagnosis_of(pruned(sim, "type1"), "none")
    fine = next(f for f in d["residual_field"] if tuple(f["grid"]) == (12, 8))
    print(fine)
    assert fine["found"] and fine["largest_zone"][1] <= 2 and fine["largest_zone"][0] >= 8
    assert any("field" in s for s in d["findings"])


def test_radial_error_in_a_nadir_gnss_block_is_a_dome(tmp_path):
    """A radial distortion of 2.2 px in the corners left unmodelled (--ap none), nadir images, the datum from the
    GNSS positions only: the check points' heights form a dome the test finds, and the report shows it."""
    from selfcal.io.block_folder import write_block
    sim = simulate_uav(seed=2, distortion="brown", distortion_scale=0.2)
    block = gnss_only(pruned(sim, "type2"))
    write_block(block, tmp_path / "block")
    assert run_cli("adjust", str(tmp_path / "block"), "--out", str(tmp_path / "res"), "--ap", "none",
                   "--gnss-drift", "none", "--imu-drift", "none", "--quiet") == 0
    import json
    d = json.loads((tmp_path / "res" / "summary.json").read_text())["diagnosis"]
    dome = d["dome"]
    print(dome)
    assert dome["found"] and dome["dome_height_m"] < -0.2 and dome["n_points"] == int((block.points.role == "chk").sum())
    assert "dome" in d["findings"][0]
    page = read_report(tmp_path / "res" / "report.html")
    (row,) = page.tables["diagnosis-dome"]
    assert row.flag and float(row[1][0]) == pytest.approx(dome["dome_height_m"], abs=5e-5)
    assert len(page.tables["diagnosis-field"]) == len(d["residual_field"])
