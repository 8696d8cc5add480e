"""The images' maps from working columns to image parameters (selfcal.adjust.working): every product taken through the
diagonal and the few other rows equals the dense product."""
import numpy as np

from selfcal.adjust.working import ImageMaps, symmetrised


def _maps(seed=0, n=3, width=12):
    rng = np.random.default_rng(seed)
    T = np.zeros((n, width, width))
    for i in range(n):
        T[i] = np.diag(rng.choice([0.0, 1.0, 2.0], width))      # held columns zero, scaled ones
        T[i][[1, 4]] += rng.normal(size=(2, width))            # the rows that carry the powers
    return rng, T


def test_products_through_the_few_rows_equal_the_dense_ones():
    rng, T = _maps()
    n, width = T.shape[:2]
    maps = ImageMaps(T)
    assert list(maps.rows) == [1, 4]
    M = rng.normal(size=(n, width, width))
    P = rng.normal(size=(4, width, width))
    a, b = np.array([0, 1, 2, 0]), np.array([1, 2, 0, 0])
    v = rng.normal(size=(n, width))
    R = rng.normal(size=(n, width, 5))
    Tt = T.transpose(0, 2, 1)
    checks = [
        (maps.blocks_to_parameters(M), Tt @ M @ T),
        (maps.pairs_to_parameters(P, a, b), Tt[a] @ P @ T[b]),
        (maps.vectors_to_parameters(v), np.einsum("iwk,iw->ik", T, v)),
        (maps.rows_to_parameters(R.reshape(-1, 5)), (Tt @ R).reshape(-1, 5)),
        (maps.vectors_to_working(v), np.einsum("iwk,ik->iw", T, v)),
        (maps.rows_to_working(R), T @ R),
        (maps.blocks_to_working(M), T @ M @ Tt),
        (maps.pairs_to_working(P, a, b), T[a] @ P @ Tt[b]),
    ]
    for got, want in checks:
        assert np.allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    # a map that is not square takes the dense products
    wide = ImageMaps(T[:, :, :-1])
    assert np.allclose(wide.blocks_to_parameters(M), T[:, :, :-1].transpose(0, 2, 1) @ M @ T[:, :, :-1])


def test_symmetrised_sums_of_slot_pairs():
    rng = np.random.default_rng(1)
    full = rng.normal(size=(2, 6, 6))
    full = full + full.transpose(0, 2, 1)
    upper = np.triu(full)                              # what the kernels sum: slot pairs a <= b
    assert np.allclose(symmetrised(upper), full)
