"""Free networks (datum = "free"): minimum-norm Gauss-Newton steps, and what the rays cannot determine left out.

Truth: the pseudo-inverse step against NumPy's least-squares minimum-norm solution; a simulated tie-point
network against its simulation; a BAL problem against Ceres (pycolmap's bundle adjuster) on the same
observations from the same start.
"""
from __future__ import annotations

import importlib.util
import json
import os
import tempfile
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHARED_DATA, run_cli, simulation

BAL_SUBSET = os.path.join(SHARED_DATA, "bal", "bal-ladybug-problem-49-7776-pre-shrink-1800.txt")
BENCH_ENGINE = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "bench_engine.py")


def test_pseudo_factorise_gives_the_minimum_norm_solution_in_the_scaled_metric():
    """S = D A^T A D with a 7-dimensional null space: the solve is S's pseudo-inverse in the Jacobi-scaled
    metric (NumPy's lstsq minimum-norm solution of the scaled system), has no component along the null space,
    and the defect is counted."""
    from selfcal.adjust.linalg import pseudo_factorise

    rng = np.random.default_rng(4)
    n, defect = 40, 7
    null = np.linalg.qr(rng.normal(size=(n, defect)))[0]
    A = rng.normal(size=(90, n))
    A -= (A @ null) @ null.T                          # A null = 0
    D = np.diag(10.0 ** rng.uniform(-3, 3, n))        # units from mm to km
    S = D @ A.T @ A @ D
    b = S @ rng.normal(size=n)                        # a right-hand side in the range, as a gradient is
    factor = pseudo_factorise(S)
    x = factor.solve(b)
    assert factor.defect == defect
    assert np.allclose(S @ x, b, rtol=0, atol=1e-8 * np.abs(b).max())
    scale = 1.0 / np.sqrt(np.diag(S))
    y = np.linalg.lstsq(S * scale[:, None] * scale[None, :], scale * b, rcond=1e-10)[0]
    assert np.allclose(x, scale * y, rtol=1e-7, atol=1e-12 * np.abs(x).max())
    # no component along the null space of the scaled system (S D^-1 null = 0, and x = scale y)
    null_scaled = np.linalg.qr(np.linalg.solve(D, null) / scale[:, None])[0]
    assert np.abs(null_scaled.T @ (x / scale)).max() < 1e-8 * np.linalg.norm(x / scale)
    # the next iteration's path: the null basis passed back, a Cholesky factorisation of S_s + Z Z^T
    again = pseudo_factorise(S, factor.null)
    assert again.defect == defect and np.allclose(again.solve(b), x, rtol=1e-6, atol=1e-9 * np.abs(x).max())
    # a basis that is no longer null (the state moved the datum directions): inverse iteration follows them,
    # without a second eigendecomposition, to the same solution
    from unittest import mock
    off = factor.null + 1e-3 * rng.normal(size=factor.null.shape) * np.abs(factor.null).max()
    with mock.patch("numpy.linalg.eigh", side_effect=AssertionError("eigendecomposition repeated")):
        moved = pseudo_factorise(S, off)
    assert moved.defect == defect and np.allclose(moved.solve(b), x, rtol=1e-6, atol=1e-9 * np.abs(x).max())
    assert np.linalg.norm(null_scaled.T @ np.linalg.qr(moved.null / scale[:, None])[0], -2) > 1 - 1e-9   # spans it
    # a basis of the wrong size cannot be followed: the eigendecomposition again, the same solution
    fallback = pseudo_factorise(S, off[:, :3])
    assert fallback.defect == defect and np.allclose(fallback.solve(b), x, rtol=1e-7, atol=1e-12 * np.abs(x).max())


def test_free_tie_point_network_converges_by_gauss_newton_without_drift():
    """The simulated Type-1 block without its control, datum = "free": the adjustment ends with undamped
    (minimum-norm) steps and converges; the adjusted perspective centres equal the truth up to a 3-D similarity
    within a few cm (the image noise, 0.5 px at 3 cm ground sample distance), and sigma0 matches the simulated
    0.5 px within 5 %; nothing is left out."""
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.block import leave_out, prune

    sim = simulation()
    block = sim.blocks["type1"]
    block = prune(replace(leave_out(block, points=block.points.role != "tie"), datum="free"))
    result = adjust(block, AdjustOptions())
    assert result.converged, result.reason
    assert result.iterations <= 12
    assert result.history[-1].damping == 0.0
    assert result.block.dropped.points_undetermined == 0 and result.block.dropped.observations_behind_camera == 0
    assert abs(result.sigma0_px / 0.5 - 1) < 0.05
    # a similarity from the adjusted to the true perspective centres (Umeyama), residuals in metres
    lookup = {i: k for k, i in enumerate(sim.truth.image_id)}
    true_xyz = sim.truth.eop[[lookup[i] for i in result.block.images.image_id], :3]
    est = result.state.image[:, :3]
    a, b = est - est.mean(0), true_xyz - true_xyz.mean(0)
    U, s, Vt = np.linalg.svd(b.T @ a)
    E = np.array([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ np.diag(E) @ Vt
    k = np.sum(s * E) / np.sum(a * a)
    misfit = b - k * a @ R.T
    assert np.sqrt(np.mean(np.sum(misfit**2, axis=1))) < 0.05


def test_similarity_directions_span_the_free_networks_null_space():
    """The seven directions of a shift, rotation and scale of the object frame, fitted image by image from the
    points' move, are the null space of a free network's reduced normal equations (the eigenvalues find seven
    below 1e-10 of the largest, and the directions lie in their span); the step from them equals the step from
    the eigendecomposition. With one direction missing the factorisation does not take the guess."""
    from selfcal.adjust.datum import similarity_directions
    from selfcal.adjust.initial import initial_state
    from selfcal.adjust.linalg import pseudo_factorise
    from selfcal.adjust.schur import linearise, reduce
    from selfcal.adjust.problem import build_problem
    from selfcal.block import leave_out, prune

    block = simulation().blocks["type1"]
    block = prune(replace(leave_out(block, points=block.points.role != "tie"), datum="free"))
    problem = build_problem(block)
    state, _ = initial_state(problem, block)
    lin = linearise(problem, state)
    S, g, _ = reduce(problem, lin, 0.0, True)
    Z = similarity_directions(problem, state, lin)
    scale = 1.0 / np.sqrt(np.diag(S))
    Ss = S * scale[:, None] * scale[None, :]
    w, V = np.linalg.eigh(Ss)
    null = V[:, w < 1e-10 * w.max()]
    assert null.shape[1] == 7
    Zs = np.linalg.qr(Z / scale[:, None])[0]
    assert np.linalg.norm(Zs - null @ (null.T @ Zs)) < 1e-6                # within the eigenvectors' span
    guessed, found = pseudo_factorise(S, Z), pseudo_factorise(S)
    assert guessed.defect == found.defect == 7 and guessed.method == found.method == "pseudo-inverse"
    step, reference = guessed.solve(g), found.solve(g)
    np.testing.assert_allclose(step, reference, rtol=0, atol=1e-8 * np.abs(reference).max())
    assert pseudo_factorise(S, Z[:, :6]).defect == 7                      # too few: found afresh


def _bench_engine():
    spec = importlib.util.spec_from_file_location("bench_engine", BENCH_ENGINE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_bal_subset_from_the_command_line_converges_to_ceres_cost(tmp_path, capsys):
    """``selfcal import bal`` + ``selfcal adjust --snoop 0`` on the 1,800-point BAL subset: exit 0, converged;
    the 31 observations behind their camera (BAL's own test, P_z > 0 at the file's values) are left out, and
    the 10 points they leave with one ray; no point is undetermined. The final cost equals pycolmap's (Ceres)
    on the same observations from the same start within 1e-6 (measured 2.7e-10: 2945.2420930 vs 2945.2420923)."""
    import pycolmap
    from selfcal.convert import bal_behind_camera
    from selfcal.io.bal import BalProblem, read_bal

    assert os.path.exists(BAL_SUBSET), f"shared test data missing: {BAL_SUBSET}"
    block, out = str(tmp_path / "b"), str(tmp_path / "r")
    assert run_cli("import", "bal", BAL_SUBSET, "--out", block) == 0
    assert run_cli("adjust", block, "--snoop", "0", "--robust", "none", "--no-report", "--quiet", "--out", out) == 0
    err = capsys.readouterr().err
    assert "left out 31 observations of 10 points behind their camera" in err
    with open(os.path.join(out, "summary.json")) as handle:
        summary = json.load(handle)
    assert summary["converged"] and summary["iterations"] <= 20
    assert summary["dropped"]["observations_behind_camera"] == 31
    assert summary["dropped"]["tie_points_one_image"] == 10
    assert summary["dropped"]["points_undetermined"] == 0
    cost = 0.5 * summary["sigma0_px"] ** 2 * summary["redundancy"]          # image sigma 1 px
    # the reference: BAL's own cheirality test, then the points left with fewer than two rays, then Ceres
    problem = read_bal(BAL_SUBSET)
    keep = ~bal_behind_camera(problem)
    assert int((~keep).sum()) == 31
    rays = np.bincount(problem.obs_point[keep], minlength=len(problem.points))
    keep &= rays[problem.obs_point] >= 2
    points = np.unique(problem.obs_point[keep])
    assert len(problem.points) - len(points) == 10
    assert summary["n_image_observations"] == int(keep.sum())
    new = np.full(len(problem.points), -1)
    new[points] = np.arange(len(points))
    sub = BalProblem(problem.cameras, problem.points[points], problem.obs_camera[keep], new[problem.obs_point[keep]],
                     problem.obs_xy[keep])
    bench = _bench_engine()
    with tempfile.TemporaryDirectory() as folder:
        bench._colmap_model(sub, folder)
        reconstruction = pycolmap.Reconstruction(folder)
    bench._pycolmap_adjust(reconstruction, refine_principal_point=False)
    reference = bench._colmap_cost(reconstruction)
    assert abs(cost / reference - 1) < 1e-6, (cost, reference)


def test_undetermined_points_by_closed_forms_match_the_eigenvalues():
    """points_not_determined_by_rays decides most 3 x 3 blocks by a determinant bound and computes sigma from
    the principal minors: the same points as the eigenvalue test (well conditioned, rank one, a smallest
    eigenvalue 1e-13 of the largest, blocks 1e8 larger) and the same sigma as trace(V^-1) to 1e-10."""
    from selfcal.adjust.datum import POINT_BLOCK_RCOND, points_not_determined_by_rays

    rng = np.random.default_rng(0)
    A = rng.normal(size=(5000, 3, 5))
    V = A @ A.transpose(0, 2, 1)
    u = rng.normal(size=(50, 3))
    V[:50] = np.einsum("ni,nj->nij", u, u)                                 # rank one: singular
    V[50:60] *= 1e8
    V[60:70] = np.diag([1.0, 1.0, 1e-13])                                 # below rcond
    V[70:80] = np.diag([1.0, 1.0, 1e-11])                                 # above rcond, far above the median sigma
    indices, sigma = points_not_determined_by_rays(V, 100.0)
    w = np.linalg.eigvalsh(V)
    singular = ~(w[:, 0] > POINT_BLOCK_RCOND * np.abs(w[:, 2]))
    assert singular[:50].all() and singular[60:70].all() and not singular[70:].any()
    assert np.array_equal(np.isinf(sigma), singular)
    reference = np.sqrt(np.trace(np.linalg.inv(V[~singular]), axis1=1, axis2=2))
    np.testing.assert_allclose(sigma[~singular], reference, rtol=1e-10)
    full = np.full(len(V), np.inf)
    full[~singular] = reference
    expected = np.flatnonzero(full > 100 * np.median(reference))
    assert np.array_equal(indices, expected) and set(range(70, 80)) <= set(indices.tolist())
