"""Leave-one-out validation of the control (issue 40 item 3): each control point's error when it is left out,
equal to an explicit re-adjustment without it; a mis-surveyed target found and named; a control or check point
never left without rays unnamed."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, APOptions, SolverOptions, adjust
from selfcal.io.results import results_from_files
from selfcal.report import result_files
from selfcal.report.page import Page
from selfcal.simulate import simulate_uav
from selfcal.stats import SnoopingOptions
from selfcal.stats.loo import LeaveOneOut, critical_t3, downdate
from selfcal.stats.snooping import left_without_rays
from selfcal.workflows.adjust import AdjustRequest, adjust_block
from selfcal.workflows.tested import adjust_with_tests, prune_for

OPTIONS = AdjustOptions(ap=APOptions("none"))
#: the explicit re-adjustments the leave-one-out values are compared with: converged to 1e-7 of a sigma
TIGHT = replace(OPTIONS, solver=SolverOptions(function_tolerance=1e-7, step_tolerance=1e-9, cost_tolerance=1e-16))


@pytest.fixture(scope="module")
def block():
    """Seed 000's block, a seventh of its points (11,000 observations), Type 3: 27 control points (1.7 / 2.9 cm)."""
    return prune_for(simulate_uav(seed=2, points_per_mm2=0.5, distortion="none").blocks["type3"])


@pytest.fixture(scope="module")
def adjusted(block):
    t0 = time.perf_counter()
    out = adjust_block(block, AdjustRequest(options=OPTIONS))
    return out, time.perf_counter() - t0


def _explicit(adjusted, name):
    """The block the tests left, point ``name`` a check point, adjusted from its start values (no warm start)."""
    result = adjusted.tested.result
    b = result.block
    role = np.asarray(b.points.role).copy()
    role[b.points.point_id == name] = "chk"
    other = adjust(replace(b, points=replace(b.points, role=role)), TIGHT, free=adjusted.tested.ap_free,
                   ap_models={cam.camera_id: cam.ap for cam in result.problem.cameras})
    j = int(np.flatnonzero(other.block.points.point_id == name)[0])
    k = int(np.flatnonzero(b.points.point_id == name)[0])
    return other.state.points[j] - b.points.xyz_m[k], other.Q_points[j]


def test_the_downdate_is_the_deletion_of_the_group_for_a_linear_model():
    """Truth: a random linear Gauss-Markov model, a point's three coordinates observed with a full 3x3 weight: the
    rank-3 downdate gives the estimate and cofactor of the least squares without those three rows (1e-10)."""
    rng = np.random.default_rng(7)
    A = rng.normal(size=(30, 8))
    l = rng.normal(size=30)
    W = np.linalg.cholesky(np.linalg.inv(np.diag([0.4, 0.5, 0.9]) ** 2 + 0.01)).T      # W^T W = C^-1
    X_ref = rng.normal(size=3)
    J = np.hstack([W, np.zeros((3, 5))])
    N = A.T @ A + J.T @ J
    x = np.linalg.solve(N, A.T @ l + J.T @ (W @ X_ref))
    Q = np.linalg.inv(N)
    d, cov = downdate(W[None], Q[None, :3, :3], (x[:3] - X_ref)[None])
    N_without = A.T @ A
    x_without = np.linalg.solve(N_without, A.T @ l)
    Q_without = np.linalg.inv(N_without)
    C = np.linalg.inv(W.T @ W)
    np.testing.assert_allclose(d[0], x_without[:3] - X_ref, atol=1e-10)
    np.testing.assert_allclose(cov[0], Q_without[:3, :3] + C, atol=1e-10)


def test_statistics_of_a_leave_one_out_error():
    """w = d / sigma per axis; T = d^T C^-1 d; the critical T at Baarda's 3.0 (alpha 0.27 %) is chi2(3)'s 14.16."""
    cov = np.array([np.diag([4.0, 1.0, 9.0])])
    loo = LeaveOneOut(np.array(["P"], object), np.array(["gcp"], object), np.array([[2.0, -3.0, 3.0]]), cov, 3.0)
    np.testing.assert_allclose(loo.w, [[1.0, -3.0, 1.0]])
    assert loo.t3[0] == pytest.approx(1.0 + 9.0 + 1.0)
    assert critical_t3(3.0) == pytest.approx(14.156, abs=1e-3)
    assert not loo.fails[0] and loo.worst() == 0


def test_loo_errors_equal_explicit_re_adjustments(adjusted, block):
    """Each control point's leave-one-out error and sigma equal those of the block re-adjusted without it from its
    start values to 1e-7 of a sigma: within 1e-6 m (three points: one at the edge, two inside). The linear
    downdate misses by the re-linearisation's share (printed); the cost of all 27 against the workflow."""
    out, seconds = adjusted
    loo = out.tested.loo
    assert loo is not None and len(loo) == int((block.points.role == "gcp").sum()) == 27
    assert np.isfinite(loo.t3).all()
    for name in (loo.point_id[0], loo.point_id[10], loo.point_id[20]):
        k = int(np.flatnonzero(loo.point_id == name)[0])
        d, Q = _explicit(out, name)
        result = out.tested.result
        p = int(np.flatnonzero(result.block.points.point_id == name)[0])
        C = np.diag(result.block.points.sigma_m[p] ** 2)
        assert np.abs(loo.d_m[k] - d).max() < 1e-6, (name, loo.d_m[k], d)
        np.testing.assert_allclose(loo.sigma_m[k], np.sqrt(np.diag(Q + C)), rtol=1e-4)
    result = out.tested.result
    control = result.problem.control
    linear, _ = downdate(control.W, result.Q_points[control.index],
                         result.state.points[control.index] - control.xyz)
    miss = float(np.abs(linear - loo.d_m).max())
    assert miss < 1e-3                                  # (the same errors to first order)
    print(f"\nlinear downdate against the re-adjustments: largest difference {miss:.2e} m; leave-one-out of "
          f"{len(loo)} control points {loo.seconds:.2f} s, the rest of the workflow {seconds - loo.seconds:.2f} s "
          f"(ratio {loo.seconds / (seconds - loo.seconds):.2f})")
    summary = out.summary_extra["control_loo"]
    assert summary["n_control"] == 27 and summary["method"] == "re-adjustment"


def test_a_gcp_moved_by_five_sigma_has_the_largest_loo_error_and_is_named(adjusted, block):
    """One control point moved by 5 sigma of its leave-one-out error in X: it has the largest T of the control,
    fails the test, and summary.json, the notes (stderr's warnings) and control_loo.csv name it."""
    base = adjusted[0].tested.loo
    k = 13
    name = str(base.point_id[k])
    p = int(np.flatnonzero(block.points.point_id == name)[0])
    xyz = block.points.xyz_m.copy()
    xyz[p, 0] += 5.0 * base.sigma_m[k, 0]
    moved = adjust_block(replace(block, points=replace(block.points, xyz_m=xyz)), AdjustRequest(options=OPTIONS))
    loo = moved.tested.loo
    t = loo.t3
    assert loo.point_id[loo.worst()] == name
    assert loo.fails[loo.worst()] and t[loo.worst()] > loo.critical_t3
    summary = moved.summary_extra["control_loo"]
    assert summary["worst_point_id"] == name and name in summary["failing"]
    assert any(f"'{name}' fails the leave-one-out test" in note for note in moved.tested.result.notes)
    files = result_files(moved.block, moved.tested, moved.summary_extra, None, moved.checks)
    table = results_from_files(files).tables["control_loo"]
    row = int(np.flatnonzero(table["point_id"] == name)[0])
    assert table["fails"][row] == 1 and table["T_3d"][row] == pytest.approx(t[loo.worst()], rel=1e-9)
    print(f"\n{name} moved {5.0 * base.sigma_m[k, 0]:.3f} m in X: T {t[loo.worst()]:.1f} (next {np.sort(t)[-2]:.1f}), "
          f"role {loo.role[loo.worst()]}")


def test_the_report_has_the_loo_table(adjusted):
    from selfcal.report.render import _control_loo_section
    out = adjusted[0]
    files = result_files(out.block, out.tested, out.summary_extra, None, out.checks)
    page = Page("t")
    _control_loo_section(page, results_from_files(files))
    markup = page.html()
    assert 'id="control-loo"' in markup and markup.count("<tr") == 1 + len(out.tested.loo)


def test_a_check_point_left_without_rays_is_named(block):
    """A check point seen in two images, one ray 30 px off: data snooping rejects a ray, the point has one left
    and goes; the tested adjustment's notes (the command line's warnings) name it."""
    obs = block.observations
    chk = [p for p in np.flatnonzero(block.points.role == "chk") if (obs.point_index == p).sum() >= 3]
    p = int(chk[0])
    rays = np.flatnonzero(obs.point_index == p)
    keep = np.setdiff1d(np.arange(len(obs)), rays[2:])
    pixel = obs.pixel.copy()
    pixel[rays[0]] += [30.0, -30.0]
    b = replace(block, observations=replace(obs, pixel=pixel).take(keep))
    tested = adjust_with_tests(b, OPTIONS, SnoopingOptions())
    name = str(block.points.point_id[p])
    assert name not in set(tested.result.block.points.point_id.tolist())
    notes = [n for n in tested.result.notes if f"check point '{name}' left without rays" in n]
    assert len(notes) == 1 and "1 of its 2 rays rejected" in notes[0]


def test_left_without_rays_passes_over_what_never_had_rays_and_what_is_named(block):
    obs = block.observations
    gcp = int(np.flatnonzero(block.points.role == "gcp")[0])
    rows = obs.row[obs.point_index == gcp]
    after = prune_for(replace(block, observations=obs.take(np.flatnonzero(obs.point_index != gcp))))
    name = str(block.points.point_id[gcp])
    messages = left_without_rays(block, after, rows)
    assert messages == [f"control point '{name}' left without rays: {len(rows)} of its {len(rows)} rays rejected as "
                        f"blunders, too few left to determine it; it no longer controls the block"]
    assert left_without_rays(block, after, rows, named=(name,)) == []
    assert left_without_rays(after, after, rows) == []


def test_a_control_point_the_tests_check_instead_is_listed_with_its_own_error(block):
    """A control point 0.15 m off in X (9 of its sigmas): the control group's test checks it instead; the
    validation lists it as demoted with its error in that adjustment (about -0.15 m in X), the worst, failing."""
    gcp = np.flatnonzero(block.points.role == "gcp")
    p = int(gcp[5])
    name = str(block.points.point_id[p])
    xyz = block.points.xyz_m.copy()
    xyz[p, 0] += 0.15
    moved = adjust_block(replace(block, points=replace(block.points, xyz_m=xyz)), AdjustRequest(options=OPTIONS))
    loo = moved.tested.loo
    k = int(np.flatnonzero(loo.point_id == name)[0])
    assert name in dict(moved.tested.control_demoted) and loo.role[k] == "demoted"
    assert loo.worst() == k and loo.fails[k]
    assert loo.d_m[k, 0] == pytest.approx(-0.15, abs=0.05)
    assert len(loo) == len(gcp)


def test_no_control_loo_leaves_the_check_out(block, tmp_path):
    """``--no-control-loo`` (and ``bundle_adjust(control_loo=False)``): no control_loo.csv, no summary key; by
    default both are written."""
    from selfcal.io.block_folder import write_block
    from selfcal.workflows.api import bundle_adjust
    from conftest import run_cli
    write_block(block, tmp_path / "block")
    assert run_cli("adjust", str(tmp_path / "block"), "--out", str(tmp_path / "off"), "--ap", "none", "--no-report",
                   "--quiet", "--no-control-loo") == 0
    assert not (tmp_path / "off" / "control_loo.csv").exists()
    assert run_cli("adjust", str(tmp_path / "block"), "--out", str(tmp_path / "on"), "--ap", "none", "--no-report",
                   "--quiet") == 0
    assert (tmp_path / "on" / "control_loo.csv").exists()
    assert "control_loo.csv" not in bundle_adjust(block, "none", control_loo=False).files


def test_a_wavelet_block_evaluates_its_basis_once_for_every_control_point(monkeypatch):
    """The re-adjustments of the leave-one-out keep every observation of the tested adjustment: each takes the AP
    columns over and gives them back (``AdjustmentResult.take_back_ap_columns``), so that the 27 control points of a
    WAP block (db4 on 6x4) evaluate the basis no more, where each re-adjustment after the first used to evaluate it
    afresh; the errors are the same as with every basis evaluated afresh (to 1e-12 m). (On the quick start's db4 9x6
    block, 80,634 observations: the leave-one-out took 26 s instead of 41, the errors the same to the bit.)"""
    import selfcal.adjust.ap_columns as ap_columns
    from selfcal.adjust.result import AdjustmentResult
    from selfcal.workflows.loo import control_loo

    block = prune_for(simulate_uav(seed=3, points_per_mm2=0.2, distortion="local+brown").blocks["type3"])
    options = AdjustOptions(ap=APOptions("wavelet:db4", grid=(6, 4)))
    tested = adjust_with_tests(block, options, SnoopingOptions(3.0))
    evaluations = []
    bound_of = ap_columns.bound_of
    monkeypatch.setattr(ap_columns, "bound_of", lambda problem, o: evaluations.append(o.size) or bound_of(problem, o))
    kept = control_loo(tested, options)
    assert len(kept) == 27 and np.isfinite(kept.d_m).all()
    assert evaluations == []
    monkeypatch.setattr(AdjustmentResult, "take_back_ap_columns", lambda self, readjusted: None)
    afresh = control_loo(tested, options)
    assert len(evaluations) >= 26                  # (every re-adjustment after the first, the way it was)
    np.testing.assert_allclose(kept.d_m, afresh.d_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(kept.cov_m2, afresh.cov_m2, rtol=1e-12, atol=0)
