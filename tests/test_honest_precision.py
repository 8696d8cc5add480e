"""Honest precision (issue 44 item 5) on a simulated convergent close-range block with Strecha's camera (fx != fy,
no distortion; selfcal.simulate.close_range): a free network whose c trades with Brown's affinity b1.

* With the AP basis at the measured image coordinates (Eq. (1) read literally) the estimate is an errors-in-
  variables one: brown's c lands many sigma below the truth and BIC prefers brown by far; with the basis at the
  adjusted coordinates (the default) c and b1 meet the truth within their sigma.
* The jackknife over the images finds every sigma holding where the model is right, and flags the calibration
  where the focus changed between images (a model error no AP family represents); without a jackknife the
  statement names c as determined only through its correlation with b1.
"""
from __future__ import annotations

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, APOptions, adjust
from selfcal.report.calibration_precision import calibration_precision_section
from selfcal.report.page import Page
from selfcal.simulate.close_range import simulate_close_range
from selfcal.stats.calibration_precision import camera_precision, critical_ratio
from selfcal.workflows.jackknife import calibration_precision
from selfcal.workflows.tested import adjust_with_tests

#: the block: 11 images on a 70-degree arc, turned by 0.7 degrees at most about the wall's middle, 1 px of noise
BLOCK = dict(n_images=11, n_points=1500, image_sigma_px=1.0, turn_sd_deg=0.7)


def _errors(result, truth) -> dict[str, float]:
    """Error / sigma of c (against fy: selfcal's c with b1), x0, y0 and b1."""
    return truth.z_scores(result.state.cameras[0], result.camera_sigma()[0], result.problem.cameras[0].names)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_basis_at_the_adjusted_coordinates_removes_the_errors_in_variables_bias(seed):
    sim = simulate_close_range(seed, **BLOCK)
    measured = adjust(sim.block, AdjustOptions(ap=APOptions("brown", evaluated_at="measured")))
    adjusted = adjust(sim.block, AdjustOptions(ap=APOptions("brown")))
    none = adjust(sim.block, AdjustOptions(ap=APOptions("none")))
    at_measured, at_adjusted = _errors(measured, sim.truth), _errors(adjusted, sim.truth)
    # the failure mode of the issue: c many sigma below the truth, b1 above, and brown "better" by BIC
    assert at_measured["c"] < -6 and at_measured["b1"] > 6, at_measured
    bic = {r.problem.cameras[0].ap.spec: 2 * r.cost + r.n_unknowns * np.log(r.n_observations)
           for r in (measured, none)}
    assert bic["none"] - bic["brown"] > 50
    # the basis at the adjusted coordinates: every core parameter and b1 within 2.5 sigma of the truth
    assert all(abs(v) < 2.5 for v in at_adjusted.values()), at_adjusted
    assert adjusted.block.observations.ap_at_px is not None and measured.block.observations.ap_at_px is None
    # the fit is the model's, not the noise's: brown's cost is within a few units of the right model's
    assert adjusted.cost > measured.cost + 20


def test_the_jackknife_trusts_the_right_model_and_flags_a_focus_change():
    right = simulate_close_range(0, **BLOCK)
    moved = simulate_close_range(0, **BLOCK, focal_sd=0.003)
    options = AdjustOptions(ap=APOptions("brown"))
    verdicts = {}
    for label, sim in (("right", right), ("focus", moved)):
        tested = adjust_with_tests(sim.block, options, snooping=None)
        summary, note = calibration_precision(tested, options, groups=11)
        assert summary["jackknife"]["done"] and summary["jackknife"]["n_replicates"] == 11
        core = {p["name"]: p for p in summary["cameras"]["cam"] if p["core"]}
        verdicts[label] = (summary, core, note)
    summary, core, note = verdicts["right"]
    assert summary["trusted"] is True and not note
    assert all(p["ratio"] < critical_ratio(11) for p in core.values()), core
    # the c of the right model is within 2 of its (trusted) sigma
    assert abs(core["c"]["value"] - right.truth.fy_px) < 2 * core["c"]["sigma"]
    summary, core, note = verdicts["focus"]
    assert summary["trusted"] is False and note == summary["statement"]
    assert core["c"]["flagged"] and core["c"]["ratio"] > 2, core["c"]
    assert "does not hold" in summary["statement"] and "ρ(c, b1)" in summary["statement"]
    # the report's section says it, the flagged rows marked
    page = Page("t")
    calibration_precision_section(page, {"calibration_precision": summary})
    html = page.html()
    assert 'id="calibration-precision"' in html and "Not trusted" in html and 'class="flag"' in html


def test_without_a_jackknife_the_statement_names_what_the_aps_inflate():
    sim = simulate_close_range(1, **BLOCK)
    options = AdjustOptions(ap=APOptions("brown"))
    tested = adjust_with_tests(sim.block, options, snooping=None)
    precision = {p.name: p for p in camera_precision(tested.result)[0].parameters}
    c = precision["c"]
    # c's sigma with b1 and the rest held: its inflation is sigma / sigma_held = 1/sqrt(1 - R^2)
    assert c.partner == "b1" and c.rho < -0.85 and c.ap_inflation > 2.5
    assert c.sigma == pytest.approx(c.ap_inflation * c.sigma_aps_held)
    summary, note = calibration_precision(tested, options, groups=0)
    assert summary["trusted"] is None and summary["jackknife"] is None
    assert note == summary["statement"] and "c " in note and "ρ(c, b1)" in note and "--jackknife" in note
    # no APs: nothing inflated, no note
    plain = adjust_with_tests(sim.block, AdjustOptions(ap=APOptions("none")), snooping=None)
    summary, note = calibration_precision(plain, AdjustOptions(), groups=0)
    assert summary["trusted"] is None and not note
    assert all(p["ap_inflation"] is None for p in summary["cameras"]["cam"])
