"""The factorisation paths of large reduced systems, and the selected inverse the covariance reads.

Which path factorises S is named (``Factor.method``), never a silent fallback: CHOLMOD is an installed
dependency (``make install``: libsuitesparse-dev and the ``cholmod`` extra), and a test fails if it is
missing. The covariance of a large strip block comes from the selected inverse (a BandedCofactor: the
entries of S^-1 on S's pattern and the camera parameters' columns), and must equal the dense inverse's.
"""
from __future__ import annotations

import sys

import numpy as np
import scipy.sparse as sp

from selfcal.adjust import AdjustOptions
from selfcal.adjust.covariance import point_cofactors
from selfcal.adjust.initial import initial_state
from selfcal.adjust.linalg import CHOLMOD_AVAILABLE, band_structure, factorise
from selfcal.adjust.schur import linearise, reduce
from selfcal.adjust.problem import build_problem
from selfcal.adjust.selected import BandedCofactor
from selfcal.block import prune
from selfcal.simulate import simulate_uav
from selfcal.adjust.leverage import image_leverages


def _random_graph_system(n_img: int, links: int = 8, n_d: int = 3, seed: int = 0) -> sp.csc_matrix:
    """S = J^T J of a random image graph (each image linked to ``links`` random others, as in an
    unordered photo collection: no band), 6 unknowns an image and ``n_d`` coupling every image."""
    rng = np.random.default_rng(seed)
    a = np.repeat(np.arange(n_img), links)
    b = rng.integers(0, n_img, a.size)
    a, b = a[a != b], b[a != b]
    n = 6 * n_img + n_d
    rows, cols, vals = [], [], []
    for k, (i, j) in enumerate(zip(a, b)):
        for c0, width in ((6 * i, 6), (6 * j, 6), (6 * n_img, n_d)):
            r, c = np.meshgrid(np.arange(12 * k, 12 * k + 12), np.arange(c0, c0 + width), indexing="ij")
            rows.append(r.ravel())
            cols.append(c.ravel())
            vals.append(rng.normal(size=r.size))
    J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(12 * a.size, n))
    return (J.T @ J + 1e-3 * sp.eye(n)).tocsc()


def test_cholmod_is_installed_and_factorises_a_system_without_a_band():
    """A random image graph has no narrow band: CHOLMOD factorises it (the method says so) and its
    solution equals the dense LAPACK solution within 1e-10 relative."""
    assert CHOLMOD_AVAILABLE, "scikit-sparse is not installed: run `make install` (libsuitesparse-dev + selfcal[cholmod])"
    S = _random_graph_system(250)
    assert band_structure(S) is None
    factor = factorise(S)
    assert factor.method == "cholmod"
    b = np.random.default_rng(1).normal(size=(S.shape[0], 2))
    dense = factorise(S.toarray())
    assert dense.method == "dense"
    x, x_dense = factor.solve(b), dense.solve(b)
    assert np.max(np.abs(x - x_dense)) / np.max(np.abs(x_dense)) < 1e-10
    # the same pattern with other values (the next iteration) reuses the symbolic analysis, and solves exactly
    S2 = (S + sp.diags(np.linspace(1.0, 50.0, S.shape[0]))).tocsc()
    x2 = factorise(S2).solve(b)
    assert np.max(np.abs(x2 - np.linalg.solve(S2.toarray(), b))) / np.max(np.abs(x2)) < 1e-10
    # its cofactor is the dense inverse (no band to exploit)
    Q = factor.cofactor()
    assert isinstance(Q, np.ndarray)
    np.testing.assert_allclose(np.diag(Q), np.diag(dense.inverse()), rtol=1e-9)


def test_cholmod_factorises_on_an_optimised_blas():
    """CHOLMOD's supernodal factorisation runs on the system's libblas.so.3, which Debian resolves to the
    reference BLAS (or a generic ATLAS) unless OpenBLAS is installed; ``make install`` installs
    libopenblas0-pthread: the 5000-image strip block's reduced matrix factorises in 1.0 s on it against 3.2 s
    on ATLAS. threadpoolctl names the BLAS libraries loaded: NumPy's and SciPy's own lie inside the Python
    environment, the one CHOLMOD loaded outside it, and it must be an optimised one."""
    from threadpoolctl import threadpool_info

    assert CHOLMOD_AVAILABLE, "scikit-sparse is not installed: run `make install` (libsuitesparse-dev + selfcal[cholmod])"
    system = [lib for lib in threadpool_info()
              if lib["user_api"] == "blas" and not lib["filepath"].startswith(sys.prefix)]
    assert any(lib["internal_api"] in ("openblas", "mkl", "blis") for lib in system), (
        "CHOLMOD runs on an unoptimised BLAS (the reference BLAS or ATLAS): install libopenblas0-pthread "
        f"(`make install`); BLAS libraries outside the environment: {[lib['filepath'] for lib in system]}")


def test_selected_inverse_gives_the_dense_point_cofactors_and_leverages():
    """A two-strip block of 240 images through the sparse path: the point cofactors Q_pp and the
    observation leverages h from the selected inverse equal those from the dense inverse within 1e-9
    relative, and so does the sigma of every unknown of theta."""
    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=0.3, n_strips=2, images_per_strip=120)
    block = prune(sim.blocks["type3"])
    options = AdjustOptions()
    problem = build_problem(block, options)
    state, _ = initial_state(problem, block, None)
    lin = linearise(problem, state)
    S, _, v_inv = reduce(problem, lin, 0.0, False)
    factor = factorise(S)
    assert factor.method == "banded"
    Q = factor.cofactor(dense_limit=0)   # the selected inverse at any size
    assert isinstance(Q, BandedCofactor)
    Q_dense = factorise(S.toarray()).inverse()
    np.testing.assert_allclose(Q.diagonal(), np.diag(Q_dense), rtol=1e-9)
    covariance = np.float64(2.0) * Q                      # a covariance (variance factor x cofactor) stays selected
    assert isinstance(covariance, BandedCofactor)
    np.testing.assert_allclose(covariance.diagonal(), 2.0 * np.diag(Q_dense), rtol=1e-9)
    Qp, Qp_dense = point_cofactors(problem, lin, v_inv, Q), point_cofactors(problem, lin, v_inv, Q_dense)
    scale = np.sqrt(np.einsum("pii->pi", Qp_dense))
    assert np.max(np.abs(Qp - Qp_dense) / (scale[:, :, None] * scale[:, None, :])) < 1e-9
    h = image_leverages(problem, state, lin, v_inv, Q, Qp)[0]
    h_dense = image_leverages(problem, state, lin, v_inv, Q_dense, Qp_dense)[0]
    assert np.max(np.abs(h - h_dense)) < 1e-9 * np.max(np.abs(h_dense))
    assert 0.0 < h.min() and h.max() < 1.0


def test_mid_size_blocks_are_reduced_sparse_to_the_dense_path_s_result(monkeypatch):
    """Beyond DENSE_ASSEMBLY_LIMIT unknowns the reduced matrix is assembled sparse (CHOLMOD or banded: 4.6x
    faster an iteration at 504 images), and Q_theta is still the dense inverse up to DENSE_LIMIT: a two-strip
    block of 264 images (1587 unknowns) adjusts to the dense path's cost within 1e-10 relative, its sigmas
    within 1e-9, and its reduced matrix is kept (dense) for the downdated start of a re-adjustment."""
    import selfcal.adjust.linalg as linalg_module
    import selfcal.adjust.point_side as point_side_module
    from selfcal.adjust import adjust
    from selfcal.adjust.linalg import DENSE_ASSEMBLY_LIMIT, DENSE_LIMIT
    from selfcal.adjust.schur import assemble

    paths = []

    def assemble_spy(problem, lin, sums, lam, dense):         # the solver's reduced matrix, through its point side
        paths.append(dense)
        return assemble(problem, lin, sums, lam, dense)

    monkeypatch.setattr(point_side_module, "assemble", assemble_spy)
    sim = simulate_uav(seed=1, distortion="none", points_per_mm2=0.2, n_strips=2, images_per_strip=132)
    block = prune(sim.blocks["type3"])
    sparse = adjust(block, AdjustOptions())
    assert DENSE_ASSEMBLY_LIMIT < sparse.problem.n_theta <= DENSE_LIMIT
    assert paths and not any(paths)
    paths.clear()
    assert isinstance(sparse.Q_theta, np.ndarray) and isinstance(sparse.reduced_matrix, np.ndarray)
    monkeypatch.setattr(linalg_module, "DENSE_ASSEMBLY_LIMIT", DENSE_LIMIT)
    dense = adjust(block, AdjustOptions())
    assert paths and all(paths)
    assert sparse.iterations == dense.iterations
    assert abs(sparse.cost - dense.cost) < 1e-10 * dense.cost
    np.testing.assert_allclose(np.diag(sparse.Q_theta), np.diag(dense.Q_theta), rtol=1e-9)
    np.testing.assert_allclose(sparse.reduced_matrix, dense.reduced_matrix, rtol=1e-9, atol=1e-9 * np.abs(
        dense.reduced_matrix).max())
