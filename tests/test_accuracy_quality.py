"""The ASPRS Edition 2 accuracy statement and the quality check (issue 40 items 1 and 2): hand-computed Edition 2
figures; a simulated block whose a-priori image sigma is 4x too large fails the sigma0 check alone; the report
shows both tables with summary.json's numbers."""
import csv
import dataclasses
import json
import math

import numpy as np
import pytest

from selfcal.stats.asprs import CLASSES_CM, MIN_CHECKPOINTS, accuracy_class_cm, accuracy_statement
from selfcal.stats.quality import FAIL, PASS, WARN, quality_checks, worst_status
from selfcal.workflows.api import bundle_adjust

from conftest import pruned, simulation
from report_page import read_report


def _csv(path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_edition2_figures_equal_hand_computed_ones():
    # four check points: dx ±0.03, dy ±0.04, dz ±0.08 m; survey sigma 0.072, 0.096, 0.06 m
    d = np.array([[0.03, 0.04, 0.08], [-0.03, 0.04, -0.08], [0.03, -0.04, 0.08], [-0.03, -0.04, -0.08]])
    sigma = np.tile([0.072, 0.096, 0.06], (4, 1))
    a = accuracy_statement(d, sigma)
    # by hand: RMSE_x 0.03, RMSE_y 0.04, RMSE_H,measured sqrt(0.03² + 0.04²) = 0.05; survey sqrt(0.072² + 0.096²)
    # = 0.12; product sqrt(0.05² + 0.12²) = 0.13; V: sqrt(0.08² + 0.06²) = 0.10; 3-D sqrt(0.13² + 0.10²)
    assert a.rmse_x_m == pytest.approx(0.03, abs=1e-12) and a.rmse_y_m == pytest.approx(0.04, abs=1e-12)
    assert a.rmse_h_measured_m == pytest.approx(0.05, abs=1e-12)
    assert a.rmse_h_survey_m == pytest.approx(0.12, abs=1e-12)
    assert a.rmse_h_m == pytest.approx(0.13, abs=1e-12)
    assert a.rmse_v_measured_m == pytest.approx(0.08, abs=1e-12)
    assert a.rmse_v_survey_m == pytest.approx(0.06, abs=1e-12)
    assert a.rmse_v_m == pytest.approx(0.10, abs=1e-12)
    assert a.rmse_3d_m == pytest.approx(math.sqrt(0.0269), abs=1e-12)
    # classes: 13 cm meets the 15-cm class, 10 cm the 10-cm class
    assert a.horizontal_class_cm == 15.0 and a.vertical_class_cm == 10.0
    assert a.n_checkpoints == 4 and not a.enough_checkpoints
    assert any("at least 30" in w for w in a.warnings)


def test_survey_sigma_per_point_and_missing_and_the_thirty_point_rule():
    rng = np.random.default_rng(3)
    d = rng.normal(0.0, 0.02, (MIN_CHECKPOINTS, 3))
    sigma = rng.uniform(0.005, 0.02, (MIN_CHECKPOINTS, 3))
    sigma[0] = np.nan                                             # one point without a survey sigma
    a = accuracy_statement(d, sigma)
    known = sigma[1:]
    assert a.rmse_h_survey_m == pytest.approx(math.sqrt(np.mean(known[:, 0] ** 2 + known[:, 1] ** 2)), rel=1e-12)
    assert a.rmse_v_survey_m == pytest.approx(math.sqrt(np.mean(known[:, 2] ** 2)), rel=1e-12)
    assert a.rmse_v_m == pytest.approx(math.sqrt(np.mean(d[:, 2] ** 2) + np.mean(known[:, 2] ** 2)), rel=1e-12)
    assert a.enough_checkpoints and a.n_survey_sigma == MIN_CHECKPOINTS - 1
    assert not any("at least" in w for w in a.warnings) and any("no survey sigma" in w for w in a.warnings)
    none = accuracy_statement(d, None)
    assert none.rmse_h_m == none.rmse_h_measured_m and none.rmse_h_survey_m is None
    empty = accuracy_statement(np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.rmse_3d_m is None and empty.horizontal_class_cm is None and "no check points" in empty.warnings[0]
    # a class is the smallest listed at or above the RMSE; beyond the list the RMSE rounded up to a centimetre
    assert accuracy_class_cm(0.025) == 2.5 and accuracy_class_cm(0.0251) == 5.0
    assert accuracy_class_cm(CLASSES_CM[-1] / 100 + 2.341) == math.ceil(CLASSES_CM[-1] + 234.1)


def test_quality_check_grades_each_figure_against_its_threshold():
    base = dict(n_images=40, n_images_oriented=40, points_per_image=[150, 300], rays_per_point=[3, 4, 5],
                focal_change=(0.01, "camera A"), sigma0_ratio=1.1, n_rejected=5, n_observations=1000,
                gcp_ratio=(2.0, "point G1, axis Z"), camera_correlation=(0.9, "A: c with I1: Z0"))
    checks = {c.key: c.status for c in quality_checks(**base)}
    assert set(checks.values()) == {PASS}
    cases = {"n_images_oriented": (39, WARN, 37, FAIL), "points_per_image": ([50], WARN, [10], FAIL),
             "rays_per_point": ([2, 2, 3], WARN, [1, 1, 2], FAIL), "focal_change": ((0.1, ""), WARN, (0.3, ""), FAIL),
             "sigma0_ratio": (2.5, WARN, 4.0, FAIL), "n_rejected": (30, WARN, 60, FAIL),
             "gcp_ratio": ((4.0, ""), WARN, (6.0, ""), FAIL), "camera_correlation": ((0.995, ""), WARN, (0.9995, ""), FAIL)}
    keys = {"n_images_oriented": "images_oriented", "points_per_image": "points_per_image",
            "rays_per_point": "rays_per_point", "focal_change": "camera_change", "sigma0_ratio": "sigma0_ratio",
            "n_rejected": "observations_rejected", "gcp_ratio": "gcp_residuals", "camera_correlation": "weak_parameters"}
    for argument, (warn, w_status, fail, f_status) in cases.items():
        for value, status in ((warn, w_status), (fail, f_status)):
            got = {c.key: c for c in quality_checks(**(base | {argument: value}))}
            assert got[keys[argument]].status == status, (argument, value)
            assert worst_status(list(got.values())) == status
    assert {c.key: c.status for c in quality_checks(**(base | {"sigma0_ratio": 0.2}))}["sigma0_ratio"] == FAIL
    no_control = {c.key: c.status for c in quality_checks(**(base | {"gcp_ratio": None, "focal_change": None}))}
    assert no_control["gcp_residuals"] == no_control["camera_change"] == "n/a"


@pytest.fixture(scope="module")
def blocks(tmp_path_factory):
    """A small seed-000 block (Brown lens, blunders) adjusted as given (report written) and with its a-priori
    image sigma 4x too large (0.5 px measured, 2 px claimed)."""
    sim = simulation(seed=6, distortion="brown", points_per_mm2=0.25, blunder_rate=0.003)
    block = pruned(sim, "type1")
    folder = tmp_path_factory.mktemp("quality") / "brown"
    bundle_adjust(block, "brown").write(folder)
    wrong = dataclasses.replace(block, image_sigma_px=4 * block.image_sigma_px, observations=dataclasses.replace(
        block.observations, sigma_px=4 * block.observations.sigma_px))
    return block, folder, bundle_adjust(wrong, "brown").summary


def test_simulated_block_passes_and_a_wrong_apriori_sigma_fails_the_sigma0_check(blocks):
    block, folder, wrong = blocks
    s = json.loads((folder / "summary.json").read_text())
    right = s["quality_check"]["checks"]
    status = {k: c["status"] for k, c in right.items()}
    # the flat nadir block couples c with the images' Z0 (|rho| 0.99 to 0.999): a warning; every other check passes
    assert status.pop("weak_parameters") == WARN and "c with" in right["weak_parameters"]["detail"]
    assert set(status.values()) == {PASS}, status
    # the figures, recomputed from the files
    residuals = _csv(folder / "residuals.csv")
    kept = [r for r in residuals if r["rejected"] == "0" and r["vx_px"]]
    per_image = np.unique([r["image_id"] for r in kept], return_counts=True)[1]
    assert right["points_per_image"]["value"] == pytest.approx(float(np.median(per_image)))
    points = {p["point_id"]: p for p in _csv(folder / "points.csv")}
    rays = np.unique([r["point_id"] for r in kept if points[r["point_id"]]["role"] == "tie"], return_counts=True)[1]
    assert right["rays_per_point"]["value"] == pytest.approx(float(np.median(rays)))
    rejected = sum(r["rejected"] == "1" for r in residuals)
    # of the observations the adjustment kept or rejected (those of points that left it at pruning aside)
    assert right["observations_rejected"]["value"] == pytest.approx(rejected / (len(kept) + rejected), rel=1e-12)
    assert right["sigma0_ratio"]["value"] == pytest.approx(s["sigma0_px"] / block.image_sigma_px, rel=1e-9)
    c = next(p for p in _csv(folder / "parameters.csv") if p["parameter"] == "c")
    assert right["camera_change"]["value"] == pytest.approx(abs(float(c["value"]) - float(c["start"])) /
                                                            float(c["start"]), rel=1e-6, abs=1e-9)
    gcp = block.points.role == "gcp"
    sigma = dict(zip(block.points.point_id[gcp], block.points.sigma_m[gcp]))
    ratio = max(abs(float(points[p][f"d{a}_m"])) / sigma[p][k] for p in sigma for k, a in enumerate("XYZ"))
    assert right["gcp_residuals"]["value"] == pytest.approx(ratio, abs=5e-5 / min(min(v) for v in sigma.values()) + 1e-9)
    # the 4x too large a-priori sigma: sigma0 / sigma0_apriori near 1/4, a failure; no other check fails
    bad = wrong["quality_check"]["checks"]
    assert bad["sigma0_ratio"]["status"] == FAIL and bad["sigma0_ratio"]["value"] == pytest.approx(0.25, rel=0.1)
    assert wrong["quality_check"]["status"] == FAIL
    assert all(c["status"] != FAIL for k, c in bad.items() if k != "sigma0_ratio")
    print(f"sigma0 ratio right {right['sigma0_ratio']['value']:.3f}, 4x sigma {bad['sigma0_ratio']['value']:.3f}; "
          f"|rho| {right['weak_parameters']['value']:.4f} ({right['weak_parameters']['detail']})")


def test_report_shows_the_accuracy_statement_and_the_quality_check(blocks):
    block, folder, _ = blocks
    s = json.loads((folder / "summary.json").read_text())
    a = s["accuracy"]
    # Edition 2 by hand from points.csv and the block's survey sigmas of the check points
    chk = [p for p in _csv(folder / "points.csv") if p["role"] == "chk"]
    d = np.array([[float(p[f"d{c}_m"]) for c in "XYZ"] for p in chk])
    where = {pid: k for k, pid in enumerate(block.points.point_id)}
    sig = np.array([block.points.sigma_m[where[p["point_id"]]] for p in chk])
    h = math.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2) + np.mean(sig[:, 0] ** 2 + sig[:, 1] ** 2))
    v = math.sqrt(np.mean(d[:, 2] ** 2) + np.mean(sig[:, 2] ** 2))
    assert a["n_checkpoints"] == len(chk) == s["n_chk_used"] == 24
    assert a["rmse_h_m"] == pytest.approx(h, abs=1e-4) and a["rmse_v_m"] == pytest.approx(v, abs=1e-4)
    assert a["rmse_3d_m"] == pytest.approx(math.hypot(h, v), abs=1e-4)
    assert a["rmse_h_measured_m"] == pytest.approx(s["rmsd_chk_xy_m"], rel=1e-12)    # today's figures kept beside
    assert s["ce90_chk_m"] is not None and not a["enough_checkpoints"]
    page = read_report(folder / "report.html")
    html = (folder / "report.html").read_text(encoding="utf-8")
    # the quality check is the report's first table
    assert html.index("<table") == html.index('<table id="quality-check"')
    rows = page.tables["quality-check"]
    assert len(rows) == len(s["quality_check"]["checks"]) == 8
    for row, (key, c) in zip(rows, s["quality_check"]["checks"].items()):
        assert row[0][0] == c["check"] and row[1][0] == c["shown"] and row[2][0] == c["threshold"]
        assert row[1][1] == f"quality_check.checks.{key}.shown" and row[1][2] == repr(c["shown"])
        assert row[3][0] == c["status"]
    # the shown values are the numbers: sigma0's ratio to three decimals, a share in per cent
    shown = {k: c["shown"] for k, c in s["quality_check"]["checks"].items()}
    values = {k: c["value"] for k, c in s["quality_check"]["checks"].items()}
    assert float(shown["sigma0_ratio"]) == pytest.approx(values["sigma0_ratio"], abs=5e-4)
    assert float(shown["observations_rejected"].split(" %")[0]) == pytest.approx(
        100 * values["observations_rejected"], abs=0.05)
    cells = {key: (text, exact) for row in page.tables["accuracy"] for text, key, exact in row if key}
    for key in ("rmse_h_measured_m", "rmse_v_measured_m", "rmse_h_survey_m", "rmse_v_survey_m", "rmse_h_m", "rmse_v_m",
                "rmse_3d_m", "horizontal_class_cm", "vertical_class_cm"):
        text, exact = cells[f"accuracy.{key}"]
        assert exact == repr(a[key])
        assert float(text) == pytest.approx(a[key], abs=5e-5)
    assert "ASPRS Edition 2 asks for at least 30" in html
