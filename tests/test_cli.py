"""The command line end to end: simulate, adjust, results contract, exit codes, atomic output."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import run_cli

SUMMARY_KEYS = ["ap_model", "converged", "iterations", "sigma0_px", "variance_factor", "rmsd_chk_xy_m",
                "rmsd_chk_z_m", "rmsd_chk_xy_gsd", "rmsd_chk_z_gsd", "rms_sigma_tie_xy_m", "rms_sigma_tie_z_m",
                "n_gcp_used", "n_chk_used", "n_obs_rejected", "n_ap_initial", "n_ap_significant",
                "max_abs_corr", "seconds", "ce90_chk_m", "le90_chk_m", "datum", "datum_detail"]
RESULT_FILES = ["summary.json", "camera.json", "images.csv", "points.csv", "residuals.csv", "distortion_grid.csv",
                "screening.json", "correlation.csv"]


def _read(path):
    with open(path) as handle:
        return handle.read()


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "uav"
    assert run_cli("simulate", "uav", "--out", str(out), "--seed", "4", "--distortion", "none") == 0
    return out


def test_simulate_writes_four_scenarios_and_truth(simulated):
    assert sorted(os.listdir(simulated)) == [".selfcal-output", "truth", "type1", "type2", "type3", "type4"]
    for scenario, gcp, chk in (("type1", 15, 24), ("type3", 27, 12)):
        roles = [line.split(",")[1] for line in _read(simulated / scenario / "points.csv").split("\n")[1:] if line]
        assert roles.count("gcp") == gcp and roles.count("chk") == chk
    assert "[gnss]" in _read(simulated / "type2" / "block.toml")
    assert "[gnss]" not in _read(simulated / "type1" / "block.toml")
    assert set(os.listdir(simulated / "truth")) >= {"camera.json", "images.csv", "points.csv", "distortion_grid.csv"}


@pytest.mark.slow
def test_adjust_writes_the_results_contract(simulated, tmp_path, capsys):
    out = tmp_path / "res"
    assert run_cli("adjust", str(simulated / "type3"), "--out", str(out), "--snoop", "0") == 0
    err = capsys.readouterr().err
    assert "iteration  1" in err                      # progress is shown
    assert set(os.listdir(out)) >= set(RESULT_FILES)
    summary = json.loads(_read(out / "summary.json"))
    for key in SUMMARY_KEYS:
        assert key in summary
    assert summary["converged"] and summary["n_gcp_used"] == 27 and summary["n_chk_used"] == 12
    assert summary["datum"] == "control" and summary["datum_detail"].startswith("27 control points")
    assert summary["sigma0_px"] == pytest.approx(0.5, rel=0.02)
    assert summary["rmsd_chk_xy_gsd"] < 1 and summary["rmsd_chk_z_gsd"] < 1
    grid = _read(out / "distortion_grid.csv").split("\n")
    assert grid[0] == "col,row,dcol,drow" and len([g for g in grid[1:] if g]) == 61 * 41
    camera = json.loads(_read(out / "camera.json"))["cameras"]["ilce7m3"]
    truth = json.loads(_read(simulated / "truth" / "camera.json"))
    assert abs(camera["focal_mm"]["value"] - truth["focal_mm"]) < 4 * camera["focal_mm"]["sigma"]
    residuals = _read(out / "residuals.csv").split("\n")
    assert residuals[0].startswith("image_id,point_id,vx_px,vy_px,w_test,rejected,")
    v = np.array([[float(x) for x in r.split(",")[2:4]] for r in residuals[1:] if r])
    # residuals are smaller than the noise by sqrt(redundancy share): E[v^T P v] = sigma^2 (n - u)
    expected = summary["sigma0_px"] * np.sqrt(summary["redundancy"] / summary["n_observations"])
    assert np.sqrt(np.mean(v ** 2)) == pytest.approx(expected, rel=0.02)
    points = _read(out / "points.csv").split("\n")
    assert points[0].startswith("point_id,role,X,Y,Z,sigma_X_m")


def test_failed_run_leaves_previous_results_untouched(simulated, tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    (out / "summary.json").write_text("previous")
    bad = tmp_path / "bad"
    bad.mkdir()
    for name in os.listdir(simulated / "type3"):
        (bad / name).write_text(_read(simulated / "type3" / name))
    with open(bad / "observations.csv", "a") as handle:
        handle.write("S1_01,T999999,1.0,2.0\n")
    assert run_cli("adjust", str(bad), "--out", str(out), "--quiet") == 2
    assert os.listdir(out) == ["summary.json"] and (out / "summary.json").read_text() == "previous"
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".res")]


def test_datum_defect_exits_1_and_names_the_unknowns(simulated, tmp_path, capsys):
    # attitudes observed, no ground control and no positions: translation and scale are free
    block = tmp_path / "nodatum"
    block.mkdir()
    for name in os.listdir(simulated / "type4"):
        (block / name).write_text(_read(simulated / "type4" / name))
    toml = _read(block / "block.toml")
    toml = toml[:toml.index("[gnss]")] + toml[toml.index("[imu]"):]
    (block / "block.toml").write_text(toml)
    points = _read(block / "points.csv").replace(",gcp,", ",chk,")
    (block / "points.csv").write_text(points)
    out = tmp_path / "res"
    assert run_cli("adjust", str(block), "--out", str(out), "--quiet") == 1
    err = capsys.readouterr().err
    assert "singular" in err and "X0" in err
    assert not out.exists()


def test_console_script_runs(selfcal_exe, tmp_path):
    done = subprocess.run([selfcal_exe, "adjust", str(tmp_path / "nowhere"), "--out", str(tmp_path / "r")],
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert "block folder not found" in done.stderr
    done = subprocess.run([selfcal_exe, "--help"], capture_output=True, text=True)
    assert done.returncode == 0 and "adjust" in done.stdout


#: what building the parser of a command line may import (issue 45: help answers at once): the verbs that only
#: read options nothing numeric; the engine's verbs NumPy (their defaults); a format that projects through the
#: frame camera (Numba kernels) SciPy and Numba too; none of them matplotlib, OpenCV, Dask, GDAL or PROJ
_HELP_IMPORTS = {"": set(), "report": set(), "export": set(), "adjust": {"numpy"}, "compare": {"numpy"},
                 "demo": {"numpy"}, "import": {"numpy"}, "import gnss": {"numpy"},
                 "simulate": {"numpy", "scipy", "numba"}, "import colmap": {"numpy", "scipy", "numba"},
                 "export opencv": {"numpy", "scipy", "numba"}, "undistort": {"numpy", "scipy", "numba"}}
_HEAVY = ("numpy", "scipy", "numba", "matplotlib", "cv2", "dask", "rasterio", "pyproj", "pywt", "PIL")


@pytest.mark.parametrize("words", list(_HELP_IMPORTS))
def test_help_loads_only_what_the_options_need(words):
    code = ("import sys\nfrom selfcal.cli import main\nmain.build_parser(sys.argv[1:])\n"
            f"print(','.join(m for m in {_HEAVY!r} if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code, *words.split()], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    loaded = set(filter(None, done.stdout.strip().split(",")))
    assert loaded <= _HELP_IMPORTS[words], f"selfcal {words} --help imports {sorted(loaded - _HELP_IMPORTS[words])}"


@pytest.mark.slow
def test_adjust_with_screening_and_variance_components(simulated, tmp_path):
    out = tmp_path / "res"
    assert run_cli("adjust", str(simulated / "type4"), "--out", str(out), "--snoop", "0", "--screen",
                   "--variance-components", "--quiet") == 0
    summary = json.loads(_read(out / "summary.json"))
    vc = summary["variance_components"]
    assert vc["converged"] and {g["group"] for g in vc["groups"]} == {"image", "GCP", "GNSS", "IMU"}
    image = next(g for g in vc["groups"] if g["group"] == "image")
    assert image["sigma_apriori"] == [0.5] and image["sigma_aposteriori"][0] == pytest.approx(0.5, rel=0.02)
    assert summary["variance_factor"] == pytest.approx(1.0, abs=0.02)
    screening = json.loads(_read(out / "screening.json"))
    assert screening["options"]["joint_alpha"] == 0.05
    owners = {d["camera_id"] for d in screening["dropped"]}
    assert owners <= {"GNSS", "IMU"} and "IMU" in owners          # no APs here; the absent IMU drifts go
    assert screening["joint_tests"] and not screening["joint_tests"][-1]["jointly_significant"]
    groups = {g["group"] for g in screening["joint_tests"][-1]["groups"]}
    assert "IMU" in groups and any(g.startswith("IMU S") for g in groups)       # per sensor and per strip
    report = _read(out / "report.html")
    assert 'id="joint-tests"' in report and report.count("passes") >= len(groups)
    first = next(d for d in screening["dropped"] if d["camera_id"] == "IMU")
    assert f"dropped in round {first['round']} (t = {first['t']:.2f})" in report


@pytest.mark.slow
def test_adjust_auto_chooses_the_model_and_logs_the_candidates(simulated, tmp_path, capsys):
    """No distortion simulated: BIC keeps the model without APs; every candidate is in model_choice.csv."""
    out = tmp_path / "res"
    assert run_cli("adjust", str(simulated / "type3"), "--out", str(out), "--ap", "auto:none,brown,ebner") == 0
    assert "chosen AP model: none" in capsys.readouterr().err
    lines = _read(out / "model_choice.csv").splitlines()
    header = lines[0].split(",")
    rows = [dict(zip(header, line.split(","))) for line in lines[1:]]
    assert [r["model"] for r in rows] == ["none", "brown", "ebner"]
    assert [r["chosen"] for r in rows] == ["1", "0", "0"]
    assert all(float(r["delta_bic"]) > 0 for r in rows[1:])
    assert json.loads(_read(out / "summary.json"))["ap_model"] == "none"
    assert run_cli("adjust", str(simulated / "type3"), "--out", str(tmp_path / "x"), "--ap", "auto:brown,bogus") == 2
    assert "unknown AP model 'bogus'" in capsys.readouterr().err
