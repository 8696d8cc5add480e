"""The engine's public interface (issue 38): one result that everything above reads, its parameter table, its
leverages, a re-adjustment, how it ended, and the residual blocks' registry."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import pruned, simulation
from selfcal.adjust import adjust, AdjustOptions, APOptions, ParameterTable, Termination
from selfcal.adjust.residuals import RESIDUALS, ParameterResiduals, PointResiduals


@pytest.fixture(scope="module")
def result():
    """Seed 000's Type 2 block (GNSS/IMU with shift and drift), thinned, Brown APs."""
    return adjust(pruned(simulation(seed=5, distortion="brown", points_per_mm2=0.04), "type2"),
                  AdjustOptions(ap=APOptions("brown")))


def test_the_parameter_table_names_every_unknown_with_its_sigma(result):
    table = result.parameters()
    assert isinstance(table, ParameterTable)
    estimated = table.where(free=True)
    assert np.array_equal(np.sort(table.index[estimated]), np.arange(result.n_unknowns - 3 * result.problem.n_points))
    images = table.where(kind="image")
    np.testing.assert_array_equal(table.sigma[images].reshape(result.problem.n_images, -1), result.image_sigma())
    camera = np.concatenate([table.where(kind="core"), table.where(kind="ap")])
    np.testing.assert_array_equal(np.sort(table.sigma[camera]), np.sort(result.camera_sigma()[0]))
    assert set(table.group[table.where(kind="trajectory")]) == {"GNSS", "IMU"}
    c = table.where(name="c")[0]
    assert table.unit[c] == "mm" and table.value[c] == pytest.approx(20.962, abs=0.1)
    # the covariance of named parameters is the cofactor's block times the variance factor
    labels = table.labels()
    names = [labels[c], labels[table.where(name="k1")[0]]]
    C = result.covariance(names)
    assert C.shape == (2, 2) and np.sqrt(C[0, 0]) == pytest.approx(table.sigma[c], rel=1e-12)
    assert abs(C[0, 1]) <= np.sqrt(C[0, 0] * C[1, 1])
    with pytest.raises(KeyError):
        result.covariance(["nowhere: c"])


def test_leverages_add_up_to_the_number_of_unknowns(result):
    """trace(J Q Jᵀ) = u: the leverages of every observation (image, control, parameter observations) sum to
    the number of unknowns (the redundancy numbers to n - u)."""
    h_image, v = result.image_leverages()
    _, h_control, _ = result.control_leverages()
    h_parameters, _ = result.parameter_leverages()
    total = h_image.sum() + h_control.sum() + h_parameters.sum()
    assert total == pytest.approx(result.n_unknowns, rel=1e-8)
    assert h_image.shape == v.shape == (len(result.block.observations), 2)
    # at most 1 (to rounding: a tie point of two rays along the base has leverages 1 - 8e-7 and 1 + 1e-8 with the
    # AP basis at the measured and at the adjusted coordinates)
    assert 0.0 < h_image.min() and h_image.max() < 1.0 + 1e-6


def test_readjust_equals_a_fresh_adjustment_of_what_is_left(result):
    options = AdjustOptions(ap=APOptions("brown"))
    table = result.parameters()
    held = [table.labels()[k] for k in table.where(kind="ap")[-2:]]
    rows = result.block.observations.row[:25]
    again = result.readjust(options, without_rows=rows, hold=held)
    assert not np.isin(rows, again.block.observations.row).any()
    after = again.parameters()
    assert not after.free[[after.labels().index(h) for h in held]].any()
    free = {result.problem.cameras[0].camera_id: np.array([n not in held for n in
                                                           np.array(after.labels())[after.where(kind="ap")]])}
    fresh = adjust(again.block, options, free=free)
    assert again.sigma0_px == pytest.approx(fresh.sigma0_px, rel=1e-9)
    assert np.max(np.abs(again.state.points - fresh.state.points)) < 1e-5


def test_termination_says_how_it_ended(result):
    assert result.termination is Termination.CONVERGED
    from selfcal.adjust import SolverOptions
    short = adjust(result.block, AdjustOptions(ap=APOptions("brown"), solver=SolverOptions(max_iterations=1)))
    assert short.termination is Termination.ITERATION_LIMIT and not short.converged


def test_every_residual_kind_is_one_registry_line_behind_one_interface(result):
    """The registry builds the problem's blocks; each is a point or a parameter kind, and the problem's count of
    observations is the image coordinates plus what the blocks say."""
    assert list(RESIDUALS) == ["control", "terrain", "priors", "trajectory"]     # (terrain: issue 42, none without it)
    problem = result.problem
    assert problem.residuals and all(isinstance(b, (PointResiduals, ParameterResiduals)) for b in problem.residuals)
    n = 2 * problem.n_image_observations + sum(b.width * len(b) for b in problem.point_residuals)
    n += sum(b.n_rows(problem) for b in problem.parameter_residuals)
    assert n == result.n_observations
