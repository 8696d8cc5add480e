"""1-D wavelet APs along the detector line of a pushbroom camera (issue 8): the basis, and the recovery of a
simulated chip-wise error of the PRISM nadir line (chip misalignment up to 0.9 px and a 1 px bow)."""
import json

import numpy as np
import pytest

from selfcal.adjust import AdjustOptions, APOptions
from selfcal.ap.line import create_line_ap
from selfcal.sensors.pushbroom import LineImage, line_images
from selfcal.workflows.seed001 import choose_gcps, run_case, with_focal
from selfcal.simulate.prism import LINE_ERROR_PX, TRUE_FOCAL_MM, detector_error, prism_block, simulate_prism


@pytest.mark.parametrize("wavelet", ["db4", "sym4", "meyer", "bl4"])
def test_line_basis_is_chip_wise_and_free_of_the_attitude_fields(wavelet):
    """Each function lives on one chip; none has a constant or linear part along the line (those are
    attitude and focal length); the constant and the line each cost one function."""
    ap = create_line_ap(f"wavelet1d:{wavelet}", 14496, 7300.0, (4832, 9664), grid=12)
    cols = np.arange(0.5, 14496, 4.0)
    B = ap.basis(cols)
    s = (cols - 7300.0) / 14496
    # orthogonal over the line (exactly on the construction's samples, to the discretisation here)
    assert np.abs(B.T @ np.column_stack([np.ones_like(s), s])).max() / len(cols) < 1e-2 * np.abs(B).mean()
    assert ap.size == 2 * len(ap.keep) and len(ap.keep) == sum(len(k) for k in ap.translations) - 2
    assert ap.cells == (4, 4, 4)
    assert np.linalg.matrix_rank(B) == B.shape[1]


@pytest.fixture(scope="module")
def distorted():
    """289 points in the triplet (0.1 px), the nadir line with the chip-wise error the block does not know."""
    sim = simulate_prism(seed=4, n_points=300, image_sigma_px=0.1, detector_error_px=LINE_ERROR_PX)
    block = with_focal(prism_block(sim, seed=4), TRUE_FOCAL_MM)
    return sim, block, line_images(block)


def test_wavelet_line_aps_recover_a_chip_wise_error(distorted):
    """M6 alone leaves >= 0.5 px of systematic residual in the nadir image; with wavelet1d:db4 (grid 12) on the
    nadir line sigma0 returns to the noise and the estimated displacement equals the simulated one within
    0.1 px RMS (measured: 0.03 along, 0.08 across) over the columns observed, up to the constant and linear
    parts that the attitude takes."""
    sim, block, images = distorted
    gcps = choose_gcps(block, 5)
    plain = run_case(block, "M6", gcps, (0, 1, 2), sim.dem, "F+N+B")
    result = plain.result
    nadir = result.block.observations.image_index == 1
    # residuals in pixels along the photo axes: x across track (columns), y along track (up = -row)
    assert np.sqrt(np.mean(result.residuals_px[nadir] ** 2, axis=0))[1] >= 0.5
    camera = images[1].camera
    with_aps = run_case(block, "M6", gcps, (0, 1, 2), sim.dem, "F+N+B",
                        AdjustOptions(ap=APOptions("wavelet1d:db4", grid=(12, 12), cameras=("N",))))
    result = with_aps.result
    assert result.converged and 0.85 < np.sqrt(result.variance_factor) < 1.25
    nadir_camera = result.problem.camera_ids.index("N")
    ap = result.problem.cameras[nadir_camera].ap
    obs = block.observations
    seen = obs.pixel[obs.image_index == 1, 0]
    cols = np.linspace(seen.min(), seen.max(), 2000)
    true_line = LineImage.nominal("N", detector_error(camera, **LINE_ERROR_PX["N"]), images[1].trajectory, 0.0, 1)
    truth = (true_line.detector_mm(cols) - images[1].detector_mm(cols)) / camera.pixel_size_mm
    error = ap.displacement_px(cols, result.state.cameras[nadir_camera][4:]) - truth
    s = (cols - camera.center_col) / camera.columns
    F = np.column_stack([np.ones_like(s), s])
    error -= F @ np.linalg.lstsq(F, error, rcond=None)[0]
    rms = np.sqrt(np.mean(error ** 2, axis=0))
    assert np.all(rms <= 0.1), rms
    truth -= F @ np.linalg.lstsq(F, truth, rcond=None)[0]
    assert np.all(np.sqrt(np.mean(truth ** 2, axis=0)) > 0.4)        # the field recovered is not small


def test_cli_line_aps(tmp_path, capsys):
    """--ap wavelet1d:db4 --grid 12 --ap-cameras N through the files: detector_line.csv and parameters in px;
    several cameras without --ap-cameras is refused (exit 2)."""
    from conftest import run_cli

    assert run_cli("simulate", "prism", "--out", str(tmp_path / "sim"), "--points", "150", "--line-error",
                   "--noise-px", "0.1", "--seed", "4") == 0
    truth = json.loads((tmp_path / "sim" / "truth" / "camera_truth.json").read_text())
    assert truth["cameras"]["N"]["detector_error_px"]["bow_px"] == [1.0, 0.5]
    block = str(tmp_path / "sim" / "triplet")
    assert run_cli("adjust", block, "--out", str(tmp_path / "res"), "--gcps", "5", "--ap", "wavelet1d:db4",
                   "--grid", "12", "--ap-cameras", "N", "--no-report") == 0
    line = (tmp_path / "res" / "detector_line.csv").read_text().splitlines()
    assert line[0] == "camera_id,col,d_along_px,d_across_px" and len(line) == 1 + 906
    summary = json.loads((tmp_path / "res" / "summary.json").read_text())
    assert summary["sigma0_px"] < 0.13 and summary["rmse_chk_across_m"] < 1.0
    assert "N,along_c1k+0,AP," in (tmp_path / "res" / "parameters.csv").read_text()
    capsys.readouterr()
    assert run_cli("adjust", block, "--out", str(tmp_path / "bad"), "--ap", "wavelet1d:db4") == 2
    assert "--ap-cameras" in capsys.readouterr().err
