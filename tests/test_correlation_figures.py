"""The correlation figures of seed 000's Table 4 (issue 44 item 7): what ``max_abs_corr`` is, and that an AP basis
orthonormal over the block's own observations is a reparametrisation — adjusted in it, the block gives the same
field, sigma0 and check points, and the figures :func:`orthonormal_ap_map` predicts (intra-AP 0) — while the
canonical correlations, which no basis of the same span can change, stay."""
from dataclasses import replace

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, APOptions, SolverOptions, adjust
from selfcal.ap import ImageFrame
from selfcal.ap.base import APModel
from selfcal.stats.correlation import (GROUPS, canonical_correlation_by_group, design_cosine_by_group,
                                       max_abs_correlation_by_group, orthonormal_ap_map, parameter_groups)

#: converged far beyond the default (corrections of 1e-3 sigma): both adjustments reach the same optimum
TIGHT = SolverOptions(max_iterations=40, step_tolerance=1e-11, function_tolerance=1e-11, cost_tolerance=0.0)


class Mapped(APModel):
    """An AP model's span in another basis: coefficients b with a = M b (the fields B M b)."""

    family = "mapped"

    def __init__(self, base: APModel, M: np.ndarray):
        super().__init__(base.frame)
        self.base, self.M = base, M

    @property
    def spec(self) -> str:
        return self.base.spec

    @property
    def parameter_names(self) -> list[str]:
        return [f"b{k}" for k in range(self.M.shape[1])]

    def basis(self, x_mm, y_mm):
        bx, by = self.base.basis(x_mm, y_mm)
        return bx @ self.M, by @ self.M

    @classmethod
    def from_spec(cls, option, frame: ImageFrame, observed_xy_mm=None, **settings):
        raise NotImplementedError("built from a model, not from a name")


@pytest.fixture(scope="module", params=["brown", "wavelet:db4"])
def pair(request):
    """The Type 2 block (GNSS/IMU) adjusted with an AP model, and again in the basis of orthonormal_ap_map."""
    from selfcal.simulate import simulate_uav
    block = simulate_uav(seed=3, distortion="local+brown", points_per_mm2=0.3).blocks["type2"]
    options = AdjustOptions(ap=APOptions(request.param, grid=(3, 2)), solver=TIGHT)
    first = adjust(block, options)
    T = orthonormal_ap_map(first.problem, first.Q_theta)
    cam = first.problem.cameras[0]
    second = adjust(block, options, ap_models={cam.camera_id: Mapped(cam.ap, np.linalg.inv(T))})
    return first, second, T


def test_the_orthonormal_basis_is_a_reparametrisation(pair):
    """The same sigma0 (1e-9 relative), object points (1e-9 m), distortion field (1e-9 px), b = T a; the figures of
    the adjustment in the new basis are those predicted from the first adjustment's cofactors (1e-9), intra-AP 0,
    and the canonical correlations are the same in both."""
    first, second, T = pair
    assert first.converged and second.converged
    assert abs(second.sigma0_px / first.sigma0_px - 1) < 1e-9
    assert np.abs(second.state.points - first.state.points).max() < 1e-9
    assert np.abs(second.state.image - first.state.image).max() < 1e-9
    cam1, cam2 = first.problem.cameras[0], second.problem.cameras[0]
    a, b = first.state.cameras[0][cam1.n_core:], second.state.cameras[0][cam2.n_core:]
    np.testing.assert_allclose(b, T @ a, atol=1e-9 * np.abs(T @ a).max())
    x, y = np.meshgrid(np.linspace(-17, 17, 9), np.linspace(-11, 11, 7))
    field1 = np.column_stack(cam1.ap.displacement_px(x.ravel(), y.ravel(), a))
    field2 = np.column_stack(cam2.ap.displacement_px(x.ravel(), y.ravel(), b))
    assert np.abs(field1 - field2).max() < 1e-9
    predicted = max_abs_correlation_by_group(first.problem, first.Q_theta, T)
    found = max_abs_correlation_by_group(second.problem, second.Q_theta)
    for name in GROUPS:
        assert abs(predicted[name] - found[name]) < 1e-9, name
    assert found["intra-AP"] < 1e-9
    before, after = canonical_correlation_by_group(first.problem, first.Q_theta), \
        canonical_correlation_by_group(second.problem, second.Q_theta)
    for name in before:
        assert abs(before[name] - after[name]) < 1e-9, name


def test_what_the_figures_measure(pair):
    """max_abs_corr is the largest |Q_ij| / sqrt(Q_ii Q_jj) of an AP and a group member, recomputed here from the
    cofactors by hand; the canonical correlation of a group is never below it (the best combination of each
    side); the design cosines of the trajectory terms are 0 (no image observation carries them); the orthonormal
    basis concentrates the IOP correlation in its first coefficients, the others are uncorrelated with every IOP."""
    first, _, T = pair
    Q = np.asarray(first.Q_theta)
    groups = parameter_groups(first.problem)
    ap = groups["AP"]
    rho = Q / np.sqrt(np.outer(np.diag(Q), np.diag(Q)))
    figures = max_abs_correlation_by_group(first.problem, first.Q_theta)
    for name in ("IOP", "EOP", "GNSS", "IMU"):
        assert abs(figures[name] - np.abs(rho[np.ix_(ap, groups[name])]).max()) < 1e-12
    intra = np.abs(rho[np.ix_(ap, ap)]) - np.eye(ap.size)
    assert abs(figures["intra-AP"] - intra.max()) < 1e-12
    canonical = canonical_correlation_by_group(first.problem, first.Q_theta)
    for name in ("IOP", "EOP", "GNSS", "IMU"):
        assert canonical[name] >= figures[name] - 1e-12
    cosine = design_cosine_by_group(first.problem, first.linearisation)
    assert cosine["GNSS"] == 0.0 and cosine["IMU"] == 0.0 and 0 < cosine["IOP"] <= 1
    iop = groups["IOP"]
    Qb = T @ Q[np.ix_(ap, ap)] @ T.T
    cross = T @ Q[np.ix_(ap, iop)]
    rho_b = cross / np.sqrt(np.diag(Qb))[:, None] / np.sqrt(np.diag(Q)[iop])[None, :]
    assert np.abs(rho_b[len(iop):]).max() < 1e-9
    # against the IOP whitened, the first coefficient's correlations are the first canonical correlation
    whitened = cross @ np.linalg.inv(np.linalg.cholesky(Q[np.ix_(iop, iop)])).T / np.sqrt(np.diag(Qb))[:, None]
    assert abs(np.linalg.norm(whitened[0]) - canonical["IOP"]) < 1e-9


def test_selfcal_adjust_orthonormal_writes_the_figures_and_the_report_says_them(tmp_path):
    """``selfcal adjust --orthonormal``: summary.json holds the four readings (valid against its schema), the
    orthonormal basis has no intra-AP correlation, the canonical correlation is never below max_abs_corr, and the
    report's Table 4 shows a row for each with what the figure is."""
    import json

    import jsonschema

    from conftest import run_cli, simulation
    from selfcal.io import write_block
    from selfcal.io.results import summary_schema
    from selfcal.report.page import Page
    from selfcal.report.render import _summary_section
    write_block(simulation(seed=2, distortion="brown", points_per_mm2=0.05).blocks["type2"], tmp_path / "block")
    assert run_cli("adjust", str(tmp_path / "block"), "--out", str(tmp_path / "res"), "--ap", "brown",
                   "--orthonormal", "--no-report", "--no-control-loo", "--quiet") == 0
    with open(tmp_path / "res" / "summary.json") as handle:
        s = json.load(handle)
    jsonschema.validate(s, summary_schema(), cls=jsonschema.Draft202012Validator)
    assert s["options"]["orthonormal"] is True
    assert s["max_abs_corr_orthonormal"]["intra-AP"] < 1e-9 < s["max_abs_corr"]["intra-AP"]
    for name in ("IOP", "EOP", "GNSS", "IMU"):
        assert s["canonical_corr"][name] >= s["max_abs_corr"][name] - 1e-12
    assert s["design_cosine"]["GNSS"] == 0.0
    page = Page("t")
    _summary_section(page, s)
    html = "".join(page.parts)
    assert "canonical correlation" in html and "orthonormal AP basis" in html and "belongs to the AP basis" in html
