"""Contract tests over the AP registry: every family, every example spec."""
import functools

import numpy as np
import pytest

from selfcal.ap import AP_FAMILIES, ImageFrame, ap_from_dict, create_ap
from selfcal.ap.base import independent_functions

FRAME = ImageFrame(6000 * 0.0059, 4000 * 0.0059, 0.0059)
SPECS = [spec for cls in AP_FAMILIES.values() for spec in cls.examples]
RNG = np.random.default_rng(11)
SAMPLE = np.column_stack([RNG.uniform(-FRAME.width_mm / 2, FRAME.width_mm / 2, 6000),
                          RNG.uniform(-FRAME.height_mm / 2, FRAME.height_mm / 2, 6000)])


@functools.cache
def _model(spec):
    """The model of ``spec`` on SAMPLE, built once (sym4+details takes seconds); the tests only read it."""
    return create_ap(spec, FRAME, SAMPLE)


@pytest.mark.parametrize("spec", SPECS)
def test_basis_shapes_and_names(spec):
    ap = _model(spec)
    bx, by = ap.basis(SAMPLE[:50, 0], SAMPLE[:50, 1])
    assert bx.shape == by.shape == (50, ap.n_params)
    assert len(set(ap.parameter_names)) == ap.n_params
    assert np.all(np.isfinite(bx)) and np.all(np.isfinite(by))


@pytest.mark.parametrize("spec", SPECS)
def test_derivatives_match_finite_differences(spec):
    ap = _model(spec)
    x, y = SAMPLE[:200, 0], SAMPLE[:200, 1]
    derivs = ap.basis_derivatives(x, y)
    if ap.n_params == 0:
        assert all(d.shape == (200, 0) for d in derivs)
        return
    # wavelets are tabulated at 2^-12 of a grid cell (~1e-3 mm): difference over about one table step
    h = 1e-3 if spec.startswith("wavelet") else 1e-4
    fd = []
    for dx, dy in ((h, 0), (0, h)):
        bxp, byp = ap.basis(x + dx, y + dy)
        bxm, bym = ap.basis(x - dx, y - dy)
        fd.append(((bxp - bxm) / (2 * h), (byp - bym) / (2 * h)))
    expected = (fd[0][0], fd[1][0], fd[0][1], fd[1][1])          # dBx/dx, dBx/dy, dBy/dx, dBy/dy
    # wavelet tables are linear between 2^-12 steps: their derivative is a table too (tolerance 1e-3)
    rtol = 1e-3 if spec.startswith("wavelet") else 1e-6
    for got, want in zip(derivs, expected):
        scale = max(np.max(np.abs(want)), 1e-12)
        assert np.max(np.abs(got - want)) / scale < rtol


@pytest.mark.parametrize("spec", SPECS)
def test_serialises_and_reloads(spec):
    ap = _model(spec)
    again = ap_from_dict(ap.to_dict(), FRAME)
    assert again.spec == ap.spec and again.parameter_names == ap.parameter_names
    for a, b in zip(ap.basis(SAMPLE[:100, 0], SAMPLE[:100, 1]), again.basis(SAMPLE[:100, 0], SAMPLE[:100, 1])):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("spec", [s for s in SPECS if s != "none"])
def test_reproduces_a_field_it_can_represent(spec):
    ap = _model(spec)
    truth = RNG.normal(0, 1.0, ap.n_params)
    dx, dy = ap.displacement_px(SAMPLE[:, 0], SAMPLE[:, 1], truth)
    bx, by = ap.basis(SAMPLE[:, 0], SAMPLE[:, 1])
    A = np.vstack([bx, by])
    est = np.linalg.lstsq(A, np.concatenate([dx, dy]), rcond=None)[0]
    fitted = A @ est
    assert np.max(np.abs(fitted - np.concatenate([dx, dy]))) < 1e-8
    # and the basis has full column rank over the frame (a stated conditioning bound). The 730 functions of
    # sym4+details give 6.2e-5 to 1.8e-4 depending on which of the tied ones are left out (LAPACK's pivoted QR
    # chose among them by rounding), 9.8e-5 with the first listed kept, 1.1e-5 with none left out; bl4, whose
    # fields are reproduced exactly, 3.6e-10 with one of its six dependent functions kept
    s = np.linalg.svd(A / np.linalg.norm(A, axis=0), compute_uv=False)
    assert s[-1] / s[0] > 5e-5, s[-1] / s[0]


@pytest.mark.parametrize("family", [f for f in AP_FAMILIES if f not in ("none",)])
def test_unknown_options_are_rejected(family):
    with pytest.raises(ValueError):
        create_ap(f"{family}:nonsense", FRAME, SAMPLE)


def test_unknown_family_lists_the_known_ones():
    with pytest.raises(ValueError, match="known families: none, brown"):
        create_ap("zernike", FRAME)


@pytest.mark.parametrize("spec", SPECS)
def test_sparse_rows_rebuild_the_basis(spec):
    """Where a family gives its basis as sparse rows (wavelets of compact support: a window of translations
    per axis, the same for every point of a cell), the rows times their map are the basis, also at the nodes of
    the translation grid (where the window's edge values vanish) and at the corners of the frame; the
    compactly supported ones have far fewer non-zeros per row than parameters."""
    ap = _model(spec)
    w, h = FRAME.width_mm / 2, FRAME.height_mm / 2
    nodes = np.column_stack([np.linspace(-w, w, 19), np.linspace(-h, h, 19)])     # every 1/9 of x, 1/9 of y
    corners = np.array([[-w, -h], [w, h], [-w, h], [w, -h], [0.0, 0.0]])
    xy = np.vstack([SAMPLE[:500], nodes, corners])
    sparse = ap.sparse_basis(xy[:, 0], xy[:, 1])
    compact = spec.startswith("wavelet:") and "+" not in spec and spec.split(":")[1][:2] in ("db", "sy")
    if sparse is None:
        assert not compact
        return
    bx, by = ap.basis(xy[:, 0], xy[:, 1])
    dx, dy = sparse.dense()
    np.testing.assert_allclose(dx, bx, rtol=0, atol=1e-13)
    np.testing.assert_allclose(dy, by, rtol=0, atol=1e-13)
    assert sparse.values.shape == (len(xy), 2, sparse.columns.shape[2])
    if compact:
        assert sparse.columns.shape[2] < 0.3 * ap.n_params


# --- the functions left out as dependent --------------------------------------------------------------------

def test_independent_functions_choose_as_a_pivoted_qr_does_without_ties():
    """Without ties, the greedy orthogonalisation keeps what LAPACK's pivoted QR keeps: 40 random functions, 4 of
    them combinations of others."""
    import scipy.linalg
    rng = np.random.default_rng(3)
    A = rng.normal(size=(500, 40)) * rng.uniform(0.5, 2.0, 40)
    A[:, [5, 17, 23, 38]] = A[:, :36] @ rng.normal(size=(36, 4))
    A /= np.linalg.norm(A, axis=0)
    pivots = scipy.linalg.qr(A, mode="r", pivoting=True)[1]
    want = np.ones(40, bool)
    want[pivots[-4:]] = False
    np.testing.assert_array_equal(independent_functions(A.T @ A, 4), want)


def test_independent_functions_keep_the_first_of_tied_ones():
    """Functions that tie (here mirror images with the same norm) are kept in the order listed, and a change at the
    level of rounding does not move the choice."""
    t = np.linspace(-1.0, 1.0, 201)
    functions = np.column_stack([np.ones_like(t), t, -t, t ** 2, (1 - t) ** 2, (1 + t) ** 2])   # 3 dependent
    gram = functions.T @ functions
    kept = independent_functions(gram, 3)
    np.testing.assert_array_equal(kept, [True, True, False, True, False, False])
    noise = 1.0 + 1e-13 * np.random.default_rng(1).standard_normal(gram.shape)
    np.testing.assert_array_equal(independent_functions(gram * (noise + noise.T) / 2, 3), kept)
    # asked to keep more than are independent: the first listed of the dependent ones, whose remaining norms are
    # rounding (of either sign)
    assert independent_functions(gram, 1).sum() == 5 and independent_functions(gram, 0).all()


@pytest.mark.parametrize("spec", ["wavelet:sym4", "wavelet:db4", "wavelet:meyer", "wavelet:bl4"])
def test_wap_functions_left_out_do_not_depend_on_rounding(spec):
    """The same camera with its frame width rounded otherwise (1e-13 apart) keeps the same functions: the
    sample of the frame that chooses them rounds differently, as it does on another machine. LAPACK's pivoted QR
    (which chose them before) left out other functions of meyer and bl4 here."""
    names = _model(spec).parameter_names
    for change in (3e-14, 1e-13, -1e-13):
        frame = ImageFrame(FRAME.width_mm * (1.0 + change), FRAME.height_mm, FRAME.pixel_size_mm)
        assert create_ap(spec, frame, SAMPLE).parameter_names == names, change
