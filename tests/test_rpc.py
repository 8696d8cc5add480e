"""The RPC sensor model (selfcal.sensors.rpc), its readers (selfcal.io.rpc) and the bias compensation
of Grodecki & Dial (the rpc sensor in the engine), on the Pleiades RPCs of CNES shareloc's tests
(../shared/data/pushbroom/pleiades; expected values in EXPECTED_VALUES.txt).

Pixel convention: shareloc's RPC image coordinates put the centre of the first pixel at (0.5, 0.5)
(its default ``topleftconvention``), as selfcal does; the expected values are therefore selfcal
(row, col). The files' own conventions differ: DIMAP is 1-based at pixel centres (LINE_OFF 11470.5),
OSSIM .geom 0-based (line_off 11469.5 for the same image); without the readers' pixel_origin the first
expected value would be off by 0.5 px (.geom) or -0.5 px (XML).
"""
import os
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest
from scipy.stats import chi2

from dataclasses import dataclass

from selfcal.adjust import adjust
from selfcal.block import Block, Images, Observations, Points
from selfcal.errors import AdjustmentError, BlockError
from selfcal.geometry.earth import ecef_from_geodetic
from selfcal.io.rpc import read_rpc
from selfcal.sensors.rpc import BIAS_PARAMETERS, RpcBias, RpcCamera, RpcModel, rpc00b_terms
from selfcal.stats import observation_tests

from conftest import SHARED_DATA

DATA = os.path.join(SHARED_DATA, "pushbroom", "pleiades")
RPC = os.path.join(DATA, "rpc")
IMAGE_178609 = "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001"
IMAGE_178608 = "PHR1B_P_201709281038045_SEN_PRG_FC_178608-001"
PHRDIMAP_2018 = "PHRDIMAP_P1BP--2018122638935449CP.XML"
PHRDIMAP_2017 = "PHRDIMAP_P1BP--2017030824934340CP.XML"


def setup_module():
    assert os.path.isdir(RPC), f"shared test data missing: {RPC}"


def _rpc(name: str) -> RpcModel:
    return read_rpc(os.path.join(RPC, name))


def _image_grid(model: RpcModel, n: int = 5, heights=(100.0, 700.0, 1250.0)):
    """Image points on an n x n grid over the scene (5 % .. 95 %) at each height, and their ground."""
    rows = model.line_off + model.pixel_shift + model.line_scale * np.linspace(-0.9, 0.9, n)
    cols = model.samp_off + model.pixel_shift + model.samp_scale * np.linspace(-0.9, 0.9, n)
    row, col, h = (a.ravel() for a in np.meshgrid(rows, cols, heights, indexing="ij"))
    lon, lat = model.localize(row, col, h)
    return row, col, h, lon, lat


# --- expected values (shareloc) --------------------------------------------------------------------

@pytest.mark.parametrize("name", [IMAGE_178609 + ".geom", "RPC_" + IMAGE_178609 + ".XML"])
def test_inverse_localisation_178609_matches_shareloc(name):
    """(lon 7.048662660737769592, lat 43.72774839443545858, h 0) -> col 100.5, row 200.5 within 1e-2 px.
    Measured: row 200.49995, col 100.49972 from both files (misfit 5e-5 and 2.8e-4 px)."""
    row, col = _rpc(name).project(7.048662660737769592, 43.72774839443545858, 0.0)
    assert abs(row - 200.5) < 1e-2 and abs(col - 100.5) < 1e-2


def test_inverse_localisation_178608_matches_shareloc():
    """(lon 7.1152608829..., lat 43.6842811793..., h 850) -> col 10121.5657, row 10236.4310 within 1e-2 px.
    Measured misfit: row 1.1e-5 px, col 2.7e-5 px."""
    row, col = _rpc(IMAGE_178608 + ".geom").project(7.11526088296757386331137240632,
                                                     43.684281179313565246502548689, 850.0)
    assert abs(row - 10236.4310) < 1e-2 and abs(col - 10121.5657) < 1e-2


def test_phrdimap_localize_then_project_round_trips():
    """shareloc: direct_loc(row 200, col 600, h 125) then inverse_loc within 2e-2 px; ours: measured 2e-10 px."""
    model = _rpc(PHRDIMAP_2018)
    lon, lat = model.localize(200.0, 600.0, 125.0)
    row, col = model.project(lon, lat, 125.0)
    assert abs(row - 200.0) < 1e-6 and abs(col - 600.0) < 1e-6


@pytest.mark.parametrize("name", [PHRDIMAP_2018, PHRDIMAP_2017, "RPC_" + IMAGE_178609 + ".XML"])
def test_newton_inverse_agrees_with_the_vendor_direct_model(name):
    """The file's own image-to-ground RFM (Direct_Model, not read by selfcal) against localize at points
    over the scene and its height range: shareloc asks for 10 m; measured below 3 mm (a wrong term order
    or normalisation puts it at kilometres). Confirms the reading of the coefficients, not the pixel origin."""
    model = _rpc(name)
    row, col, h, lon, lat = _image_grid(model, n=6, heights=(model.height_off - model.height_scale,
                                                             model.height_off, model.height_off + model.height_scale))
    assert np.all(np.isfinite(lon)) and np.all(np.isfinite(lat))
    direct = ElementTree.parse(os.path.join(RPC, name)).getroot().find(".//Global_RFM/Direct_Model")
    if direct.find("F_LON") is not None:          # DIMAP v1: 20 numerator + 20 denominator coefficients
        lon_c, lat_c = (np.array(direct.find(k).text.split(), float) for k in ("F_LON", "F_LAT"))
    else:                                         # DIMAP v2: SAMP_* give the longitude, LINE_* the latitude
        def coefficients(prefix):
            return np.concatenate([[float(direct.find(f"{prefix}_{p}_COEFF_{k}").text) for k in range(1, 21)]
                                   for p in ("NUM", "DEN")])
        lon_c, lat_c = coefficients("SAMP"), coefficients("LINE")
    file_row, file_col = row - model.pixel_shift, col - model.pixel_shift
    terms = rpc00b_terms((file_col - model.samp_off) / model.samp_scale, (file_row - model.line_off) / model.line_scale,
                         (h - model.height_off) / model.height_scale)
    lon_direct = (terms @ lon_c[:20]) / (terms @ lon_c[20:]) * model.long_scale + model.long_off
    lat_direct = (terms @ lat_c[:20]) / (terms @ lat_c[20:]) * model.lat_scale + model.lat_off
    metres_per_deg = 111_320.0
    assert np.max(np.abs(lat_direct - lat)) * metres_per_deg < 0.01
    assert np.max(np.abs(lon_direct - lon) * np.cos(np.radians(lat))) * metres_per_deg < 0.01


# --- readers ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("geom, xml", [
    (os.path.join(RPC, IMAGE_178609 + ".geom"), os.path.join(RPC, "RPC_" + IMAGE_178609 + ".XML")),
    (os.path.join(RPC, IMAGE_178608 + ".geom"), os.path.join(RPC, "RPC_" + IMAGE_178608 + ".XML")),
    (os.path.join(DATA, "phr_ventoux", "left_image.geom"),
     os.path.join(DATA, "phr_ventoux", "RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML")),
])
def test_geom_and_dimap_xml_of_one_image_agree(geom, xml):
    """OSSIM (0-based) and DIMAP (1-based) give the same selfcal coordinates: the files' image offsets
    differ by exactly 1 px, the coefficients to their printed digits, the projections by < 1e-6 px
    (measured 1.6e-9 to 6.3e-9 px) over the scene and its height range."""
    a, b = read_rpc(geom), read_rpc(xml)
    assert (a.pixel_origin, b.pixel_origin) == (0.0, 1.0)
    assert b.line_off - a.line_off == pytest.approx(1.0, abs=1e-9)
    assert b.samp_off - a.samp_off == pytest.approx(1.0, abs=1e-9)
    for name in ("line_num", "line_den", "samp_num", "samp_den"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-12, atol=1e-18)
    row, col, h, lon, lat = _image_grid(b)
    np.testing.assert_allclose(np.stack(a.project(lon, lat, h)), np.stack(b.project(lon, lat, h)), rtol=0, atol=1e-6)


def _without(path: str, out, pattern: str) -> str:
    """A copy of ``path`` in ``out`` without its lines containing ``pattern``."""
    with open(path) as handle:
        lines = handle.readlines()
    target = os.path.join(str(out), os.path.basename(path))
    with open(target, "w") as handle:
        handle.writelines(line for line in lines if pattern not in line)
    return target


def test_missing_coefficient_in_dimap_names_file_and_key(tmp_path):
    """LINE_NUM_COEFF_7 deleted (from both models): the error names the file and the element."""
    path = _without(os.path.join(RPC, "RPC_" + IMAGE_178609 + ".XML"), tmp_path, "<LINE_NUM_COEFF_7>")
    with pytest.raises(BlockError) as info:
        read_rpc(path)
    assert info.value.path == path and "Inverse_Model/LINE_NUM_COEFF_7" in str(info.value)
    assert info.value.exit_code == 2


def test_missing_coefficient_in_geom_names_file_and_key(tmp_path):
    path = _without(os.path.join(RPC, IMAGE_178609 + ".geom"), tmp_path, "samp_den_coeff_13:")
    with pytest.raises(BlockError, match=r"178609-001\.geom: missing key samp_den_coeff_13"):
        read_rpc(path)


def test_bad_values_are_located(tmp_path):
    """A non-number in a .geom gives its line; a PHRDIMAP F_ROW of 39 numbers and a zero scale are named."""
    source = os.path.join(RPC, IMAGE_178609 + ".geom")
    with open(source) as handle:
        lines = handle.read().splitlines()
    number = next(i for i, line in enumerate(lines) if line.startswith("lat_scale:"))
    bad = tmp_path / "bad.geom"
    bad.write_text("\n".join(lines[:number] + ["lat_scale:  n/a"] + lines[number + 1:]) + "\n")
    with pytest.raises(BlockError, match=r"bad\.geom, line %d: key lat_scale must be a number" % (number + 1)):
        read_rpc(bad)
    zero = tmp_path / "zero.geom"
    zero.write_text("\n".join(lines[:number] + ["lat_scale:  0"] + lines[number + 1:]) + "\n")
    with pytest.raises(BlockError, match=r"zero\.geom: lat_scale must be finite and non-zero"):
        read_rpc(zero)
    with open(os.path.join(RPC, PHRDIMAP_2018)) as handle:
        text = handle.read()
    start = text.index("<F_ROW>") + len("<F_ROW>")
    short = tmp_path / "short.XML"
    short.write_text(text[:start] + text[start:].split(" ", 1)[1])
    with pytest.raises(BlockError, match=r"short\.XML: Global_RFM/Inverse_Model/F_ROW must hold 40 numbers, found 39"):
        read_rpc(short)
    other = tmp_path / "other.XML"
    other.write_text("<Dimap_Document><Dataset_Identification/></Dimap_Document>")
    with pytest.raises(BlockError, match="no Global_RFM"):
        read_rpc(other)


# --- the model --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", [IMAGE_178609 + ".geom", PHRDIMAP_2017])
def test_jacobian_matches_central_differences(name):
    """d(row, col)/d(lon, lat, h) against central differences (1e-6 deg, 1 m) at 75 points over the scene:
    difference below 1e-6 of the largest entry (measured 2.5e-9 and 1.2e-8)."""
    model = _rpc(name)
    _, _, h, lon, lat = _image_grid(model)
    row, col, J = model.project(lon, lat, h, jacobian=True)
    np.testing.assert_array_equal(np.stack([row, col]), np.stack(model.project(lon, lat, h)))
    steps = (1e-6, 1e-6, 1.0)
    ground = np.stack([lon, lat, h])
    for k, step in enumerate(steps):
        plus, minus = ground.copy(), ground.copy()
        plus[k] += step
        minus[k] -= step
        numeric = (np.stack(model.project(*plus)) - np.stack(model.project(*minus))) / (2 * step)   # (2, n)
        scale = np.max(np.abs(J[:, :, :2])) if k < 2 else np.max(np.abs(J[:, :, 2]))
        assert np.max(np.abs(numeric.T - J[:, :, k])) < 1e-6 * scale


def test_localize_is_vectorised_and_flags_non_convergence():
    """localize on a (3, 25) array of image points round-trips to 1e-6 px (measured 1e-10); NaN where the
    input is NaN or Newton has too few iterations (measured 7.4e-10 px)."""
    model = _rpc(IMAGE_178609 + ".geom")
    row, col, h, _, _ = _image_grid(model)
    shape = (3, 25)
    lon, lat = model.localize(row.reshape(shape), col.reshape(shape), h.reshape(shape))
    assert lon.shape == shape
    back = np.stack(model.project(lon, lat, h.reshape(shape)))
    assert np.max(np.abs(back - np.stack([row.reshape(shape), col.reshape(shape)]))) < 1e-6
    lon_nan, lat_nan = model.localize([row[0], np.nan], [col[0], col[1]], 0.0)
    assert np.isfinite(lon_nan[0]) and np.isnan(lon_nan[1]) and np.isnan(lat_nan[1])
    assert np.all(np.isnan(model.localize(row, col, h, max_iterations=1)[0]))


# --- bias compensation ----------------------------------------------------------------------------

TRUE_BIAS = RpcBias(a=(3.2, 2e-5, -2e-5), b=(-1.7, -2e-5, -2e-5))
NOISE_PX = 0.3
#: 6 GCPs spread over the 5 x 5 x 3 grid of _image_grid: corners, centre, one more, at different heights
GCP_INDEX = np.ravel_multi_index(([0, 0, 4, 4, 2, 1], [0, 4, 0, 4, 2, 3], [0, 2, 1, 0, 2, 1]), (5, 5, 3))


@dataclass
class BiasFit:
    """What the tests read of an engine adjustment of one RPC image to GCPs."""

    bias: RpcBias
    parameter_names: tuple
    sigmas: np.ndarray
    sigma0: float
    redundancy: int
    redundancy_numbers: np.ndarray       # (n, 2) of the image coordinates
    residuals_px: np.ndarray             # (n, 2)


def adjust_rpc_bias(model, lon, lat, h, row, col, sigma_px=1.0, kind="affine") -> BiasFit:
    """The bias of one RPC image from GCPs taken as error-free (sigma 0.1 mm), through the engine: a block of
    one ``rpc`` camera whose image's sensor description is ``model``."""
    lon, lat, h, row, col = (np.atleast_1d(np.asarray(v, float)) for v in (lon, lat, h, row, col))
    n = len(lon)
    nan3 = np.full((1, 3), np.nan)
    block = Block("rpc", "EPSG:4978", {"cam": RpcCamera("cam", kind)},
                  Images(np.array(["img"], object), np.array(["cam"], object), np.array([""], object),
                         np.array([np.nan]), nan3, nan3, np.array([2])),
                  Points(np.array([f"g{k}" for k in range(n)], object), np.full(n, "gcp", object),
                         ecef_from_geodetic(np.radians(lat), np.radians(lon), h), np.full((n, 3), 1e-4), np.arange(n)),
                  Observations(np.zeros(n, np.int64), np.arange(n), np.column_stack([col, row]),
                               np.full(n, float(sigma_px)), np.arange(n)),
                  float(sigma_px), image_models={"img": model})
    result = adjust(block)
    tests = observation_tests(result)
    free = result.problem.image_free[0]
    values, sigmas = result.state.image[0][free], result.image_sigma()[0][free]
    residuals = result.residuals_px * [1.0, -1.0]                  # photo axes -> (col, row)
    return BiasFit(RpcBias.from_parameters(kind, values), BIAS_PARAMETERS[kind], sigmas,
                   float(np.sqrt(result.variance_factor)), result.redundancy, tests.image_redundancy,
                   residuals[:, ::-1])


def _biased_block(seed: int = 8):
    model = _rpc(IMAGE_178609 + ".geom")
    _, _, h, lon, lat = _image_grid(model)
    row_rpc, col_rpc = model.project(lon, lat, h)
    row_true, col_true = TRUE_BIAS.apply(row_rpc, col_rpc)
    noise = np.random.default_rng(seed).normal(0.0, NOISE_PX, (2, len(h)))
    return model, lon, lat, h, np.stack([row_true, col_true]), np.stack([row_true, col_true]) + noise


def test_affine_bias_is_recovered_from_six_gcps():
    """Affine bias (shift 3.2 / -1.7 px, scale and rotation terms 2e-5) and 0.3 px noise: from 6 GCPs every
    parameter within 4 sigma of the truth, a-posteriori and a-priori (measured: largest |error|/sigma 2.4, at
    a0 = 2.58 +- 0.26 px), sigma0 inside the 99.9 % chi-square interval of 6 degrees of freedom (measured
    0.97); at the 69 check points the corrected model is within 0.5 px of the truth (2-D RMSE; measured 0.34)
    and of the measurements (per coordinate; 0.38), the uncorrected one more than 3 px off (3.85).

    Over 300 seeds: the 2-D RMSE to the truth has median 0.24 px (0.7 % of the seeds above 0.5); with sigma
    estimated from 6 degrees of freedom |error|/sigma follows Student's t, so 3 % of the seeds have one of
    the 6 parameters beyond 4 a-posteriori sigma (none beyond 4 a-priori sigma)."""
    model, lon, lat, h, truth, measured = _biased_block()
    fit = adjust_rpc_bias(model, lon[GCP_INDEX], lat[GCP_INDEX], h[GCP_INDEX], measured[0, GCP_INDEX],
                          measured[1, GCP_INDEX], sigma_px=NOISE_PX, kind="affine")
    assert fit.parameter_names == BIAS_PARAMETERS["affine"] and fit.redundancy == 6
    assert np.all(np.abs(fit.bias.parameters - TRUE_BIAS.parameters) < 4 * fit.sigmas)
    assert np.all(np.abs(fit.bias.parameters - TRUE_BIAS.parameters) < 4 * fit.sigmas / fit.sigma0)
    assert chi2.ppf(0.0005, 6) / 6 < fit.sigma0 ** 2 < chi2.ppf(0.9995, 6) / 6
    # the GCPs (sigma 0.1 mm) take a few millionths of the redundancy
    assert fit.redundancy_numbers.sum() == pytest.approx(fit.redundancy, abs=1e-4)
    assert fit.residuals_px.shape == (6, 2)

    check = np.setdiff1d(np.arange(len(h)), GCP_INDEX)
    corrected = np.stack(fit.bias.project(model, lon[check], lat[check], h[check]))
    uncorrected = np.stack(model.project(lon[check], lat[check], h[check]))

    def rmse_2d(a, b):
        return np.sqrt(np.mean(np.sum((a - b) ** 2, axis=0)))

    assert rmse_2d(corrected, truth[:, check]) < 0.5
    assert np.sqrt(np.mean((corrected - measured[:, check]) ** 2)) < 0.5
    assert rmse_2d(uncorrected, truth[:, check]) > 3.0


def test_sigma0_and_parameters_from_all_points():
    """With all 75 points (redundancy 144) sigma0 is within 20 % of 1 (measured 1.03; 0.84-1.14 over 300
    seeds) and the parameters within 4 sigma (largest 2.1); the shift-only model on the same data absorbs
    the shifts but not the drift of up to 0.8 px: its sigma0 is well above 1 (measured 1.45; 1.23-1.60
    over 300 seeds)."""
    model, lon, lat, h, _, measured = _biased_block()
    fit = adjust_rpc_bias(model, lon, lat, h, measured[0], measured[1], sigma_px=NOISE_PX)
    assert abs(fit.sigma0 - 1.0) < 0.2
    assert np.all(np.abs(fit.bias.parameters - TRUE_BIAS.parameters) < 4 * fit.sigmas)
    shift = adjust_rpc_bias(model, lon, lat, h, measured[0], measured[1], sigma_px=NOISE_PX, kind="shift")
    assert shift.parameter_names == ("a0", "b0") and shift.redundancy == 148
    assert shift.sigma0 > 1.2


def test_shift_bias_is_recovered_from_one_and_more_gcps():
    """A pure shift (3.2, -1.7) px with 0.3 px noise: from 6 GCPs within 4 sigma (sigma = 0.3/sqrt(6) * sigma0;
    measured 3.31 +- 0.13, -1.85 +- 0.13); from two GCPs the mean measured shift, with sigma
    0.3/sqrt(2) * sigma0; one GCP leaves no redundancy and is refused."""
    model = _rpc(IMAGE_178609 + ".geom")
    _, _, h, lon, lat = _image_grid(model)
    row_rpc, col_rpc = model.project(lon, lat, h)
    rng = np.random.default_rng(3)
    row_obs = row_rpc + 3.2 + rng.normal(0, NOISE_PX, len(h))
    col_obs = col_rpc - 1.7 + rng.normal(0, NOISE_PX, len(h))
    i = GCP_INDEX
    fit = adjust_rpc_bias(model, lon[i], lat[i], h[i], row_obs[i], col_obs[i], sigma_px=NOISE_PX, kind="shift")
    assert fit.bias.kind == "shift" and fit.redundancy == 10
    assert np.all(np.abs(fit.bias.parameters - [3.2, -1.7]) < 4 * fit.sigmas)
    np.testing.assert_allclose(fit.sigmas, NOISE_PX / np.sqrt(6) * fit.sigma0, rtol=1e-6)
    two = adjust_rpc_bias(model, lon[:2], lat[:2], h[:2], row_obs[:2], col_obs[:2], sigma_px=NOISE_PX, kind="shift")
    np.testing.assert_allclose(two.bias.parameters, [np.mean(row_obs[:2] - row_rpc[:2]),
                                                     np.mean(col_obs[:2] - col_rpc[:2])], atol=1e-6)
    assert two.redundancy == 2
    np.testing.assert_allclose(two.sigmas, NOISE_PX / np.sqrt(2) * two.sigma0, rtol=1e-6)
    with pytest.raises(AdjustmentError, match="no redundancy"):
        adjust_rpc_bias(model, lon[:1], lat[:1], h[:1], row_obs[:1], col_obs[:1], sigma_px=NOISE_PX, kind="shift")


def test_too_few_or_collinear_gcps_are_refused():
    model, lon, lat, h, _, measured = _biased_block()
    with pytest.raises(AdjustmentError, match="no redundancy"):
        adjust_rpc_bias(model, lon[:3], lat[:3], h[:3], measured[0, :3], measured[1, :3], kind="affine")
    line = np.ravel_multi_index(([0, 1, 2, 3], [0, 1, 2, 3], [0, 0, 0, 0]), (5, 5, 3))   # the grid's diagonal
    with pytest.raises(AdjustmentError, match="singular"):
        adjust_rpc_bias(model, lon[line], lat[line], h[line], measured[0, line], measured[1, line])


@pytest.mark.slow
def test_bias_statistics_over_noise_draws():
    """200 noise draws on the 6 GCPs: sigma0² is unbiased (mean within 0.15 of 1: its standard error is
    0.04; measured 1.00), and the scatter of the estimates matches the a-priori covariance (each parameter's
    standard deviation within 15 % of sqrt(Q_xx) sigma_px; measured ratios 0.98-1.09)."""
    model, lon, lat, h, truth, _ = _biased_block()
    g = GCP_INDEX
    rng = np.random.default_rng(11)
    estimates, variance_factors = [], []
    for _ in range(200):
        measured = truth[:, g] + rng.normal(0.0, NOISE_PX, (2, len(g)))
        fit = adjust_rpc_bias(model, lon[g], lat[g], h[g], measured[0], measured[1], sigma_px=NOISE_PX)
        estimates.append(fit.bias.parameters)
        variance_factors.append(fit.sigma0 ** 2)
    a_priori_sigmas = fit.sigmas / fit.sigma0
    assert abs(np.mean(variance_factors) - 1.0) < 0.15
    np.testing.assert_allclose(np.std(estimates, axis=0) / a_priori_sigmas, 1.0, atol=0.15)
