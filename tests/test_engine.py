"""The engine against a brute-force reference: dense finite-difference Jacobian of the whole problem.

On a small block, the Schur-complement step, the reduced normal matrix and the
cofactor blocks of points must equal those of the full, dense normal equations.
"""
import numpy as np
import pytest

from selfcal.adjust.covariance import point_cofactors
from selfcal.adjust.initial import initial_state
from selfcal.adjust.linalg import factorise
from selfcal.adjust.schur import back_substitute, linearise, reduce
from selfcal.adjust.problem import build_problem

from conftest import pruned, residual_vector, simulation, unpack
from selfcal.adjust import APOptions, AdjustOptions


#: "none", a physical and a polynomial family, and a wavelet family on a 2x2 grid
AP_CASES = ("none", "brown", "legendre:3", "wavelet:db2")


@pytest.fixture(scope="module", params=AP_CASES)
def small(request):
    sim = simulation(seed=5, distortion="local+brown", points_per_mm2=0.04)
    block = pruned(sim, "type2")          # control points and GNSS/IMU observations
    problem = build_problem(block, AdjustOptions(ap=APOptions(request.param, grid=(2, 2))), chunk_observations=500)   # several chunks
    state, _ = initial_state(problem, block)
    # a state with non-zero AP coefficients, so that their columns and the
    # cached Gram block are exercised away from zero
    rng = np.random.default_rng(3)
    x = np.zeros(problem.n_theta + 3 * problem.n_points)
    for cam, start in zip(problem.cameras, problem.d_offset):
        n_iop = int(cam.free[:3].sum())
        n_ap = int(cam.free[3:].sum())
        x[start + n_iop:start + n_iop + n_ap] = rng.normal(0.0, 0.3, n_ap)
    state = unpack(problem, state, x)
    return block, problem, state


def test_small_block_has_several_chunks(small):
    _, problem, _ = small
    assert len(problem.chunks) >= 3
    assert problem.n_points > 100


def test_schur_step_and_covariance_equal_dense_solution(small):
    block, problem, state = small
    n = problem.n_theta + 3 * problem.n_points
    r0 = residual_vector(problem, state)
    J = np.empty((r0.size, n))
    h = np.where(np.arange(n) < problem.n_theta, 1e-5, 1e-4)
    for k in range(n):
        e = np.zeros(n)
        e[k] = h[k]
        J[:, k] = -(residual_vector(problem, unpack(problem, state, e))
                    - residual_vector(problem, unpack(problem, state, -e))) / (2 * h[k])
    N = J.T @ J
    g = J.T @ r0
    dense_step = np.linalg.solve(N, g)

    lin = linearise(problem, state)
    np.testing.assert_allclose(lin.cost, 0.5 * r0 @ r0, rtol=1e-12)
    g_theta = lin.g_theta
    np.testing.assert_allclose(g_theta, g[:problem.n_theta], rtol=1e-5, atol=1e-6 * np.abs(g).max())
    S, g_red, v_inv = reduce(problem, lin, 0.0)
    n_t = problem.n_theta
    scale = np.sqrt(np.diag(N))
    # the reduced normal matrix is the Schur complement of the dense one
    S_ref = N[:n_t, :n_t] - N[:n_t, n_t:] @ np.linalg.solve(N[n_t:, n_t:], N[n_t:, :n_t])
    st = scale[:n_t]
    np.testing.assert_allclose(S / np.outer(st, st), S_ref / np.outer(st, st), atol=1e-6)
    # the Schur step solves the dense normal equations; checked by their residual,
    # which (unlike the step itself) does not amplify the finite-difference error
    # by the condition number (up to 1e7 with a 2x2 wavelet grid on this sparse block)
    d_theta = factorise(S).solve(g_red)
    d_p = back_substitute(problem, lin, v_inv, d_theta)
    step = np.concatenate([d_theta, d_p.ravel()])
    assert np.max(np.abs(N @ step - g) / scale) < 1e-5 * np.max(np.abs(g) / scale)
    # cofactors: Q_theta inverts the reduced matrix
    Q = factorise(S).inverse()
    np.testing.assert_allclose((S / np.outer(st, st)) @ (Q * np.outer(st, st)), np.eye(n_t), atol=1e-6)
    if np.linalg.cond(N / np.outer(scale, scale)) > 1e6:
        # only the wavelet case on this sparse block is that ill-conditioned; beyond here the
        # comparison would measure the finite differences
        assert problem.cameras[0].ap.family == "wavelet"
        return
    dense_step = np.linalg.solve(N, g)
    # in units of conditional sigma; the finite-difference reference limits the agreement
    assert np.max(np.abs((step - dense_step) * scale)) < 1e-3
    # and the point blocks equal those of the dense inverse
    Q_full = np.linalg.inv(N)
    np.testing.assert_allclose(Q, Q_full[:n_t, :n_t], rtol=1e-5, atol=1e-7 * np.abs(Q).max())
    Qp = point_cofactors(problem, lin, v_inv, Q)
    Qp_full = np.stack([Q_full[n_t + 3 * i:n_t + 3 * i + 3, n_t + 3 * i:n_t + 3 * i + 3]
                        for i in range(problem.n_points)])
    np.testing.assert_allclose(Qp, Qp_full, rtol=1e-5, atol=1e-7 * np.abs(Qp_full).max())


def test_sparse_and_dense_reductions_agree(small):
    _, problem, state = small
    lin = linearise(problem, state)
    S_dense, g1, _ = reduce(problem, lin, 1e-3, dense=True)
    S_sparse, g2, _ = reduce(problem, lin, 1e-3, dense=False)
    np.testing.assert_allclose(S_sparse.toarray(), S_dense, rtol=1e-12, atol=1e-9 * np.abs(S_dense).max())
    np.testing.assert_allclose(g1, g2)
    x1 = factorise(S_dense).solve(g1)
    x2 = factorise(S_sparse).solve(g2)
    np.testing.assert_allclose(x1, x2, rtol=1e-8, atol=1e-10 * np.abs(x1).max())


def test_the_sparse_reduced_matrix_is_the_dense_one_bit_for_bit():
    """The sparse assembly (its pattern worked out once per problem, then only filled) gives every entry of the
    dense assembly exactly, on a block with GNSS/IMU (observations of theta alone: their J_x^T J_x) and with
    damping; its pattern is the dense matrix's non-zeros, each column's rows sorted, kept for the next iteration."""
    from selfcal.adjust import AdjustOptions
    from selfcal.adjust.engine import problem_at
    block = pruned(simulation(seed=7, distortion="brown", points_per_mm2=0.3), "type2")
    problem, state = problem_at(block, AdjustOptions(ap=APOptions("brown")))
    lin = linearise(problem, state)
    assert lin.J_x.shape[0] and problem.n_extra
    kept = None
    for lam in (0.0, 1e-3):
        S_dense, _, _ = reduce(problem, lin, lam, dense=True)
        S_sparse, _, _ = reduce(problem, lin, lam, dense=False)
        assert np.array_equal(S_sparse.toarray(), S_dense)
        assert S_sparse.nnz == np.count_nonzero(S_dense)
        assert all(np.all(np.diff(S_sparse.indices[a:b]) > 0) for a, b in zip(S_sparse.indptr[:-1], S_sparse.indptr[1:]))
        assert kept is None or problem.sparse_pattern is kept        # the pattern of the first call, filled again
        kept = problem.sparse_pattern
    # entries that come out exactly zero (a pair's block cleared) are left out, as the sum of matrices left them
    from selfcal.adjust.schur import ReducedSums, add_point_schur, assemble
    sums = ReducedSums.start(problem, lin)
    add_point_schur(problem, lin.chunks, 0.0, sums)
    sums.off[0] = 0.0
    S_dense, S_sparse = assemble(problem, lin, sums, 0.0, True), assemble(problem, lin, sums, 0.0, False)
    assert np.array_equal(S_sparse.toarray(), S_dense)
    assert S_sparse.nnz == np.count_nonzero(S_dense) == len(kept.indices) - 2 * 36


@pytest.mark.parametrize("ap", ["none", "brown"])
def test_compact_camera_rows_equal_dense(ap, monkeypatch):
    """One camera per strip: the compact camera part (pair sums per camera) gives the same
    reduced system, back-substitution, point cofactors and leverages as the dense columns."""
    import dataclasses

    from selfcal.adjust import adjust, AdjustOptions, APOptions
    from selfcal.adjust.problem import Problem
    from selfcal.stats.reliability import observation_tests

    sim = simulation(seed=5, distortion="local+brown", points_per_mm2=0.04)
    block = pruned(sim, "type2")
    (camera,) = block.cameras.values()
    strips = sorted(set(block.images.strip_id))
    cameras = {f"cam_{s}": dataclasses.replace(camera, camera_id=f"cam_{s}") for s in strips}
    images = dataclasses.replace(block.images, camera_id=np.array([f"cam_{s}" for s in block.images.strip_id], object))
    block = dataclasses.replace(block, cameras=cameras, images=images)

    def run(compact: bool):
        monkeypatch.setattr(Problem, "compact_cameras", property(lambda self: compact))
        problem = build_problem(block, AdjustOptions(ap=APOptions(ap)), chunk_observations=500)
        state, _ = initial_state(problem, block)
        lin = linearise(problem, state)
        S, g, v_inv = reduce(problem, lin, 1e-3)
        d_theta = factorise(S).solve(g)
        d_p = back_substitute(problem, lin, v_inv, d_theta)
        result = adjust(block, AdjustOptions(ap=APOptions(ap)))
        h = 1.0 - observation_tests(result).image_redundancy
        return problem, lin, S, g, d_p, result.Q_points, h

    monkeypatch.undo()
    problem, lin_c, S_c, g_c, d_p_c, Qp_c, h_c = run(True)
    assert problem.n_d == 4 * int(problem.cameras[0].free.sum()) and lin_c.chunks[0].W_pd is None
    _, lin_d, S_d, g_d, d_p_d, Qp_d, h_d = run(False)
    assert lin_d.chunks[0].w_d is None
    scale = np.sqrt(np.diag(S_d))
    np.testing.assert_allclose(S_c / np.outer(scale, scale), S_d / np.outer(scale, scale), atol=1e-10)
    np.testing.assert_allclose(g_c, g_d, rtol=1e-9, atol=1e-9 * np.abs(g_d).max())
    np.testing.assert_allclose(d_p_c, d_p_d, rtol=1e-7, atol=1e-9 * np.abs(d_p_d).max())
    np.testing.assert_allclose(Qp_c, Qp_d, rtol=1e-6, atol=1e-9 * np.abs(Qp_d).max())
    np.testing.assert_allclose(h_c, h_d, atol=1e-8)


def test_re_adjustment_carries_ap_columns_and_gram():
    """A re-adjustment on a subset (observations rejected, APs dropped) takes over the AP columns
    and their Gram matrix from the previous one: equal to building them afresh."""
    import dataclasses

    from selfcal.adjust import adjust, AdjustOptions
    from selfcal.block import prune

    sim = simulation(seed=5, distortion="local+brown", points_per_mm2=0.04)
    block = pruned(sim, "type2")
    # (the basis at the measured coordinates in both: a fresh adjustment would move it to its own adjusted ones)
    options = AdjustOptions(ap=APOptions("legendre:3", evaluated_at="measured"))
    first = adjust(block, options)
    rng = np.random.default_rng(2)
    keep = np.flatnonzero(rng.random(len(block.observations)) > 0.03)
    sub = prune(dataclasses.replace(block, observations=block.observations.take(keep)))
    cam = first.problem.cameras[0]
    free = {cam.camera_id: cam.free[3:].copy()}
    free[cam.camera_id][[1, 4]] = False
    models = {cam.camera_id: cam.ap}
    carried = adjust(sub, options, start=first, free=free, ap_models=models)
    fresh = adjust(sub, options, free=free, ap_models=models)
    gram_c, gram_f = carried.problem.ap_cache.gram, fresh.problem.ap_cache.gram
    assert gram_c is not None and gram_c.shape == (int(free[cam.camera_id].sum()),) * 2
    # the columns were compacted in place inside the first problem's array (no copy): the same values
    key = (0, free[cam.camera_id].tobytes())
    columns_c, columns_f = carried.problem.ap_cache.columns[key], fresh.problem.ap_cache.columns[key]
    assert columns_c.shape == columns_f.shape and not first.problem.ap_cache.columns
    # (the re-adjustment keeps the first one's point order, the fresh one orders its points afresh: compared
    # in the block's observation order)
    by_row_c, by_row_f = np.empty_like(columns_c), np.empty_like(columns_f)
    by_row_c[carried.problem.obs_order], by_row_f[fresh.problem.obs_order] = columns_c, columns_f
    np.testing.assert_allclose(by_row_c[:, :, 3:], by_row_f[:, :, 3:], rtol=1e-13, atol=0)
    # the first adjustment, whose array was taken over, evaluates its columns afresh when used again
    from selfcal.adjust.residuals.image import image_residuals
    v = -image_residuals(first.problem, first.state)
    np.testing.assert_allclose(v, first.residuals[first.problem.obs_order], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(gram_c, gram_f, rtol=1e-9, atol=1e-12 * np.abs(gram_f).max())
    # the same estimate, within the solver's tolerance (1 % of sigma) of each other
    problem = carried.problem
    d0, mask = problem.d_offset[0], problem.cameras[0].free
    sigma = np.sqrt(np.diag(carried.Q_theta)[d0:d0 + int(mask.sum())] * carried.variance_factor)
    diff = (carried.state.cameras[0] - fresh.state.cameras[0])[mask]
    assert np.max(np.abs(diff) / sigma) < 0.02


def test_banded_factorisation_with_a_border_solves_like_dense():
    """A strip-like sparse system (band of 6x6 blocks) with three columns coupling everything: the
    bordered banded Cholesky solves it as the dense factorisation does, and finds it singular when
    a border column depends on the others."""
    import scipy.sparse as sp

    from selfcal.adjust.linalg import SingularSystem
    from selfcal.adjust.selected import BandedCofactor

    rng = np.random.default_rng(4)
    n_img, k = 300, 3
    n = 6 * n_img + k
    J_rows = []
    for i in range(n_img):
        for j in (i + 1, i + 7):                       # neighbours along the strip and across
            if j < n_img:
                row = np.zeros(n)
                row[6 * i:6 * i + 6] = rng.normal(size=6)
                row[6 * j:6 * j + 6] = rng.normal(size=6)
                row[-k:] = rng.normal(size=k)
                J_rows.append(row)
    J = np.vstack(J_rows + [np.eye(n)[:n - k] * 0.5])
    S = sp.csc_matrix(J.T @ J)
    factor = factorise(S)
    assert factor.method == "banded"
    b = rng.normal(size=(n, 2))
    x = factor.solve(b)
    np.testing.assert_allclose(x, np.linalg.solve(S.toarray(), b), rtol=1e-8, atol=1e-10)
    # the selected inverse (Takahashi's recurrence on the band, the border's full columns) against the dense
    # inverse: the diagonal, every entry on S's pattern, and entries off it (by solves) within 1e-9 relative
    Q_dense = np.linalg.inv(S.toarray())
    assert isinstance(factor.cofactor(), np.ndarray)           # dense up to DENSE_LIMIT
    Q = factor.cofactor(dense_limit=0)                           # the selected inverse at any size
    assert isinstance(Q, BandedCofactor)
    np.testing.assert_allclose(Q.diagonal(), np.diag(Q_dense), rtol=1e-9)
    rows, cols = S.nonzero()
    scale = np.sqrt(np.outer(np.diag(Q_dense), np.diag(Q_dense)))
    assert np.max(np.abs(Q[rows, cols] - Q_dense[rows, cols]) / scale[rows, cols]) < 1e-9
    far = np.ix_([0, 5, 6 * 150], [6 * 299, n - 1, 3])
    assert np.max(np.abs(Q[far] - Q_dense[far]) / scale[far]) < 1e-9
    # a border column (camera parameter), scaled: relative to sqrt(Q_ii Q_jj) (entries near zero cancel)
    assert np.max(np.abs((2.0 * Q)[:, n - 2] - 2.0 * Q_dense[:, n - 2]) / scale[:, n - 2]) < 1e-9
    J[:, -1] = J[:, -2]                                  # two border columns alike: singular
    with pytest.raises(SingularSystem):
        factorise(sp.csc_matrix(J.T @ J))


def test_small_blocks_adjust_on_one_blas_thread(monkeypatch):
    """A block of at most SINGLE_THREAD_IMAGES images is adjusted and tested with BLAS on one thread (the calls
    are too small to share), whatever the caller's setting, which is restored afterwards; above the limit the
    caller's setting stands."""
    from threadpoolctl import threadpool_info, threadpool_limits

    import selfcal.adjust.linalg as linalg
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.stats.reliability import observation_tests

    def blas_threads():
        return {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}

    block = pruned(simulation(seed=5, distortion="brown", points_per_mm2=0.04), "type2")
    seen = []
    with threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() == {2}
        result = adjust(block, AdjustOptions(ap=APOptions("brown")), progress=lambda record: seen.append(blas_threads()))
        assert seen and all(threads == {1} for threads in seen)
        assert blas_threads() == {2}
        import selfcal.adjust.point_side as point_side
        original, inside = point_side.image_leverages, []
        monkeypatch.setattr(point_side, "image_leverages", lambda *args: inside.append(blas_threads())
                            or original(*args))
        observation_tests(result)
        assert inside == [{1}] and blas_threads() == {2}
        monkeypatch.setattr(linalg, "SINGLE_THREAD_IMAGES", len(block.images) - 1)
        seen.clear()
        adjust(block, AdjustOptions(ap=APOptions("brown")), progress=lambda record: seen.append(blas_threads()))
        assert seen and all(threads == {2} for threads in seen)
        # inside the one-thread limit a long dense product gets the caller's threads back, a short one does not
        with linalg.blas_threads(1):
            with linalg.shared_product(linalg.SHARED_PRODUCT_FLOPS):
                assert blas_threads() == {2}
            with linalg.shared_product(linalg.SHARED_PRODUCT_FLOPS - 1):
                assert blas_threads() == {1}
            assert blas_threads() == {1}
        with linalg.shared_product(linalg.SHARED_PRODUCT_FLOPS):
            assert blas_threads() == {2}
    with threadpool_limits(limits=1, user_api="blas"), linalg.blas_threads(1):
        with linalg.shared_product(linalg.SHARED_PRODUCT_FLOPS):
            assert blas_threads() == {1}                # a caller on one thread stays on one


def test_point_cofactors_from_the_tests_pass_equal_their_own():
    """The object points' cofactors are computed on first use; the observation tests compute them in their own
    pass over the points (sharing its products) and leave them on the result: both ways give the same blocks,
    and the leverages are the same whether the tests are given the blocks or compute them."""
    from selfcal.adjust import AdjustOptions, adjust
    from selfcal.adjust.leverage import image_leverages
    from selfcal.stats.reliability import observation_tests

    block = pruned(simulation(seed=5, distortion="local+brown", points_per_mm2=0.04), "type3")
    result = adjust(block, AdjustOptions(ap=APOptions("wavelet:db4")))
    assert result.point_cofactor_blocks is None
    tests = observation_tests(result)
    fused = result.point_cofactor_blocks
    assert fused is not None and result.Q_points is fused
    lin, v_inv = result.point_linearisation()
    own = point_cofactors(result.problem, lin, v_inv, result.Q_theta)
    scale = np.sqrt(np.einsum("pii->pi", own))
    # the two passes sum the same terms in another order: rounding, amplified by the WAPs' conditioning (1.5e-12
    # measured after the reduction's loops were reordered, below 1e-12 before)
    assert np.max(np.abs(fused - own) / (scale[:, :, None] * scale[:, None, :])) < 1e-11
    h_given = image_leverages(result.problem, result.state, lin, v_inv, result.Q_theta, own)[0]
    h_sorted = 1.0 - tests.image_redundancy[result.problem.obs_order]
    np.testing.assert_allclose(h_given, h_sorted, rtol=0, atol=1e-10)      # rounding: h sums terms larger than 1
    lazy = adjust(block, AdjustOptions(ap=APOptions("wavelet:db4")))
    np.testing.assert_allclose(lazy.Q_points, own, rtol=0, atol=1e-12 * np.abs(own).max())


def test_leverages_through_the_sparse_wavelet_rows_equal_the_dense_ones(monkeypatch):
    """A one-camera block with sym4 WAPs, snooped and screened: its last problem's sparse AP rows were carried
    through the re-adjustments and equal rows evaluated afresh, they rebuild its dense AP columns (a subset of
    the APs free), and the leverages through them equal those through the dense columns."""
    import selfcal.adjust.leverage as leverage
    from selfcal.adjust import AdjustOptions
    from selfcal.adjust.ap_columns import camera_jacobian, sparse_ap_rows
    from selfcal.stats.screening import ScreeningOptions
    from selfcal.workflows.tested import adjust_with_tests

    block = pruned(simulation(seed=5, distortion="local+brown", points_per_mm2=0.04, blunder_rate=0.003), "type3")
    # the screening by t-tests alone (issue 44's support test holds more WAPs of this sparse block, one of which an
    # observation then determines alone: h = 1 + 1e-7 by rounding, not a leverage to compare)
    screening = ScreeningOptions(min_effect_px=0.0, min_support=0, cross_validate=False, max_iop_move_sigma=0.0)
    tested = adjust_with_tests(block, AdjustOptions(ap=APOptions("wavelet:sym4")), screening=screening)
    result = tested.result
    problem = result.problem
    cam = problem.cameras[0]
    assert tested.rounds and not cam.free[cam.n_core:].all()        # re-adjusted, and some WAPs held
    sparse = sparse_ap_rows(problem)
    o = np.arange(problem.n_image_observations)
    fresh = problem.sensors[0].bound.sparse_ap_columns(0, o, cam.ap)
    np.testing.assert_array_equal(sparse.pattern, fresh.pattern)
    np.testing.assert_allclose(sparse.values, fresh.values / problem.obs_sigma[:, :, None], rtol=1e-15, atol=0)
    bx, by = sparse.dense()
    dense = camera_jacobian(problem, 0)[:, :, cam.n_core:]
    scale = np.abs(dense).max()
    np.testing.assert_allclose(np.stack([bx, by], axis=1), dense, rtol=0, atol=1e-13 * scale)
    args = (problem, result.state, *result.point_linearisation(), result.Q_theta)
    h_sparse, _, points_sparse = leverage.image_leverages(*args)
    monkeypatch.setattr(leverage, "sparse_ap_rows", lambda problem: None)
    h_dense, _, points_dense = leverage.image_leverages(*args)
    assert 0.0 < h_dense.min() and h_dense.max() < 1.0
    np.testing.assert_allclose(h_sparse, h_dense, rtol=0, atol=1e-10)      # rounding: h sums terms larger than 1
    np.testing.assert_allclose(points_sparse, points_dense, rtol=1e-9, atol=1e-12 * np.abs(points_dense).max())


def test_dense_ap_columns_from_the_sparse_rows_equal_the_basis():
    """Where the AP model gives sparse rows, the kept dense AP columns are those rows times their map (one
    product per pattern); they equal the whitened basis evaluated afresh, with all WAPs free and with some held."""
    from selfcal.adjust.ap_columns import camera_jacobian

    block = pruned(simulation(seed=5, distortion="local+brown", points_per_mm2=0.04), "type3")
    for held in (0, 40):
        columns = {}
        for source in ("sparse rows", "basis"):
            problem = build_problem(block, AdjustOptions(ap=APOptions("wavelet:sym4")))
            cam = problem.cameras[0]
            cam.free[cam.n_core + np.arange(held) * 3] = False
            if source == "basis":
                problem.ap_cache.columns[("sparse", 0)] = None            # the model's rows withheld
            columns[source] = camera_jacobian(problem, 0)[:, :, cam.n_core:]
            assert (problem.ap_cache.columns[("sparse", 0)] is None) == (source == "basis")   # the path meant was taken
        basis = columns["basis"]
        assert basis.shape[2] == 254 - held and np.count_nonzero(basis) > 0.9 * basis.size
        np.testing.assert_allclose(columns["sparse rows"], basis, rtol=0, atol=1e-14 * np.abs(basis).max())


def test_point_quadratic_through_the_cholesky_factor():
    """Z[p] Q Z[p]^T per point through Q = L L^T (the Gram matrices of the column blocks of Z L) equals the
    blocks computed one by one; a Q that is not positive definite has no factor (the plain product Z Q then)."""
    from selfcal.adjust.covariance import block_grams, lower_cholesky, times_lower

    rng = np.random.default_rng(3)
    Z = rng.normal(size=(3 * 40, 17))
    B = rng.normal(size=(17, 17))
    Q = B @ B.T + 0.1 * np.eye(17)
    expected = np.array([Z[3 * p:3 * p + 3] @ Q @ Z[3 * p:3 * p + 3].T for p in range(40)])
    L = lower_cholesky(Q)
    assert L is not None and lower_cholesky(-Q) is None
    np.testing.assert_allclose(block_grams(times_lower(Z, L), 40), expected, rtol=1e-12,
                               atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("environment, expected", [(None, "False"), ("1", "True")])
def test_keep_freed_memory_stops_numpys_huge_page_requests_unless_the_environment_decides(environment, expected):
    """`selfcal adjust` (keep_freed_memory) turns NumPy's madvise for transparent huge pages off (first touches of
    hundreds of MB cost 5x more with it on this project's VM), unless NUMPY_MADVISE_HUGEPAGE is set."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if environment is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = environment
    code = ("from selfcal.allocator import keep_freed_memory, _small_pages\n"
            "keep_freed_memory()\n"
            "try:\n    from numpy._core.multiarray import _set_madvise_hugepage\n"
            "except ImportError:\n    from numpy.core.multiarray import _set_madvise_hugepage\n"
            "print(_set_madvise_hugepage(True))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == expected


def test_point_block_inverse_equals_lu_and_falls_back_where_not_positive_definite():
    """The 3x3 point blocks are inverted through their Cholesky factor (selfcal.adjust.kernels.spd_inverse_3x3):
    equal to LU to rounding times the condition, even for weakly intersected points (condition 1e10); a block
    that is not positive definite sends the whole batch to LU, which names the singular points."""
    from selfcal.adjust.kernels import spd_inverse_3x3
    from selfcal.adjust.schur import SingularPoints, damped_inverse

    rng = np.random.default_rng(3)
    A = rng.normal(size=(500, 3, 3))
    V = A @ A.transpose(0, 2, 1)
    # two nearly parallel rays: a depth direction 1e-5 of the others
    Q = np.linalg.qr(rng.normal(size=(500, 3, 3)))[0]
    weak = Q @ (np.array([1.0, 1.0, 1e-10])[None, :, None] * Q.transpose(0, 2, 1))
    for blocks, cond in ((V, np.linalg.cond(V)), (weak, np.full(500, 1e10))):
        out = np.empty_like(blocks)
        assert spd_inverse_3x3(blocks, out) == -1
        lu = np.linalg.inv(blocks)
        scale = np.abs(lu).max(axis=(1, 2))
        assert np.all(np.abs(out - lu).max(axis=(1, 2)) <= 1e-14 * cond * scale)
        np.testing.assert_array_equal(out, out.transpose(0, 2, 1))
    singular = V.copy()
    singular[7] = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert spd_inverse_3x3(singular, np.empty_like(singular)) == 7
    with pytest.raises(SingularPoints) as error:
        damped_inverse(singular, 0.0, points=np.arange(100, 600))       # the block's point of each block
    assert 107 in error.value.indices.tolist()


def test_points_are_chunked_by_their_first_images_whatever_the_block_order():
    """The problem orders its points by the first image that observes them (Problem.point_order): with the
    block's points shuffled, a chunk of them still touches a few neighbouring images, not nearly all of them, and
    the adjustment is the same as that of the block in its own order (point by point, to rounding)."""
    import dataclasses

    from selfcal.adjust import AdjustOptions, adjust

    block = pruned(simulation(seed=5, points_per_mm2=0.5), "type3")
    shuffle = np.random.default_rng(8).permutation(len(block.points))        # new point i is old point shuffle[i]
    new_index = np.empty_like(shuffle)
    new_index[shuffle] = np.arange(len(shuffle))
    shuffled = dataclasses.replace(
        block, points=block.points.take(shuffle),
        observations=dataclasses.replace(block.observations, point_index=new_index[block.observations.point_index]))
    problem = build_problem(shuffled, chunk_observations=500)
    assert len(problem.chunks) >= 20
    touched = [np.unique(cs.img).size for cs in problem.structure().chunks]
    # the same chunk sizes over the points in the shuffled block's order
    by_block = np.argsort(shuffled.observations.point_index, kind="stable")
    images_in_block_order = [np.unique(shuffled.observations.image_index[by_block][cs.o0:cs.o1]).size
                             for cs in problem.structure().chunks]
    assert np.mean(touched) < 0.6 * np.mean(images_in_block_order), (touched, images_in_block_order)
    np.testing.assert_array_equal(problem.point_order[problem.point_positions()], np.arange(len(block.points)))

    own, mixed = adjust(block, AdjustOptions()), adjust(shuffled, AdjustOptions())
    assert own.iterations == mixed.iterations
    np.testing.assert_allclose(mixed.state.points, own.state.points[shuffle], rtol=0, atol=1e-9)
    np.testing.assert_allclose(mixed.Q_points, own.Q_points[shuffle], rtol=1e-7, atol=1e-12)
