"""What every verb prints (DESIGN.md §5): stdout holds the outcome only (one line, or with --json one JSON document
with the key figures and the paths written), stderr the progress, warnings and errors; --quiet leaves the progress
out, --verbose adds the logger's lines."""
import json
import os
import re

import pytest

from front_door import run_main_streams


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    """A 10-image simulated block and its adjustment (brown, no snooping)."""
    from selfcal.io import write_block
    from selfcal.simulate import simulate_uav
    sim = simulate_uav(seed=3, distortion="brown", points_per_mm2=0.05, n_strips=2, images_per_strip=5)
    root = tmp_path_factory.mktemp("outcome")
    write_block(sim.blocks["type3"], root / "block")
    code, out, err = run_main_streams(["adjust", root / "block", "--out", root / "res", "--ap", "brown",
                                       "--snoop", "0", "--no-report", "--json"])
    assert code == 0, err
    doc = json.loads(out)
    code, _, err = run_main_streams(["export", "opencv", root / "res", "--out", root / "given.yaml", "--quiet"])
    assert code == 0, err                          # the calibration "import calibration" reads, whatever runs first
    return root, doc


def _document(out: str) -> dict:
    """stdout as the one JSON document it must be: json.loads fails on anything printed beside it."""
    doc = json.loads(out)
    assert set(doc) == {"selfcal", "command", "exit_code", "outcome", "error", "figures", "written"}
    return doc


def test_adjust_json_holds_the_summary_figures_and_the_results_folder(adjusted):
    root, doc = adjusted
    summary = json.loads((root / "res" / "summary.json").read_text())
    assert doc["command"] == "adjust" and doc["exit_code"] == 0 and doc["error"] is None
    assert doc["figures"]["converged"] is True
    assert doc["figures"]["sigma0_px"] == pytest.approx(summary["sigma0_px"], rel=1e-9)
    assert doc["figures"]["rmsd_chk_xy_m"] == pytest.approx(summary["rmsd_chk_xy_m"], rel=1e-9)
    assert doc["figures"]["n_chk_used"] == summary["n_chk_used"] > 0
    assert doc["written"] == [os.path.abspath(root / "res")]
    assert doc["outcome"].startswith("sigma0 ") and "results in" in doc["outcome"]


def _verbs(root):
    """One run of each verb the block can feed, with the file or folder it writes."""
    return {
        "report": (["report", root / "res"], root / "res" / "report.html"),
        "export opencv": (["export", "opencv", root / "res", "--out", root / "cam.yaml"], root / "cam.yaml"),
        "export colmap": (["export", "colmap", root / "res", "--out", root / "cameras.txt"], root / "cameras.txt"),
        "export metashape": (["export", "metashape", root / "res", "--out", root / "cam.xml"], root / "cam.xml"),
        "export opensfm": (["export", "opensfm", root / "res", "--out", root / "cameras.json"],
                           root / "cameras.json"),
        "export kalibr": (["export", "kalibr", root / "res", "--out", root / "camchain.yaml"],
                          root / "camchain.yaml"),
        "export undistort-map": (["export", "undistort-map", root / "res", "--out", root / "maps.npz"],
                                 root / "maps.npz"),
        "import calibration": (["import", "calibration", root / "given.yaml", "--block", root / "block",
                                "--out", root / "recalibrated"], root / "recalibrated"),
    }


VERBS = [       # export undistort-map: test_undistort_map_says_how_far_it_is (a subprocess, its stderr timed)
    "report", "export opencv", "export colmap", "export metashape", "export opensfm", "export kalibr",
    "import calibration"]


@pytest.mark.parametrize("verb", VERBS)
def test_every_verb_prints_one_line_or_one_json_document(adjusted, verb):
    root, _ = adjusted
    argv, written = _verbs(root)[verb]
    code, out, err = run_main_streams(argv + ["--json"])
    assert code == 0, err
    doc = _document(out)
    assert doc["command"] == verb and doc["exit_code"] == 0 and doc["error"] is None
    assert doc["written"] and os.path.abspath(written) in doc["written"] and os.path.exists(written)
    assert doc["outcome"] and "\n" not in doc["outcome"]
    code, plain, err = run_main_streams(argv + ["--quiet"])         # the same run without --json: the line alone
    assert code == 0, err
    untimed = re.compile(r"\d+(\.\d+)? s\b")                       # a run's duration differs between runs
    assert untimed.sub("", plain) == untimed.sub("", doc["outcome"]) + "\n"


def test_errors_give_the_document_with_the_exit_code(adjusted, tmp_path):
    root, _ = adjusted
    code, out, err = run_main_streams(["export", "opencv", tmp_path / "nowhere", "--out", tmp_path / "c.yaml",
                                       "--json"])
    assert code == 2
    doc = _document(out)
    assert doc["exit_code"] == 2 and doc["outcome"] is None and "nowhere" in doc["error"]
    assert doc["command"] == "export opencv" and doc["written"] == []
    assert "selfcal export: error:" in err and "nowhere" in err
    code, out, err = run_main_streams(["adjust", root / "block", "--out", tmp_path / "r", "--bogus", "--json"])
    assert code == 2 and _document(out)["exit_code"] == 2 and "--bogus" in _document(out)["error"]
    code, out, err = run_main_streams(["export", "opencv", tmp_path / "nowhere", "--out", tmp_path / "c.yaml"])
    assert code == 2 and out == ""                                  # an error leaves stdout empty without --json


def test_quiet_and_verbose_change_stderr_only(adjusted, tmp_path):
    root, _ = adjusted
    argv = ["adjust", root / "block", "--ap", "none", "--snoop", "0", "--no-report"]
    code, out_q, err_q = run_main_streams(argv + ["--out", tmp_path / "q", "--quiet"])
    assert code == 0 and "iteration" not in err_q
    code, out_v, err_v = run_main_streams(argv + ["--out", tmp_path / "v", "--verbose"])
    assert code == 0 and "iteration" in err_v and len(err_v) > len(err_q)
    assert out_q.count("\n") == out_v.count("\n") == 1
    assert out_q.replace(str(tmp_path / "q"), "") == out_v.replace(str(tmp_path / "v"), "")
    code, _, err = run_main_streams(argv + ["--out", tmp_path / "x", "--quiet", "--verbose"])
    assert code == 2 and "not allowed with" in err


def _timed(argv, timeout_s: float = 120.0):
    """Run the ``selfcal`` command ARGV as a process; (exit code, stdout, stderr's lines, the gaps): each stderr
    line is stamped as the pipe delivers it, and a gap is the silence before a line, from the start of the process
    to the first and from the last to the end; the gaps are in seconds of an idle machine: the wall clock's divided
    by the share of a core the process had (its wall time over its CPU time, at least 1), so that the test holds
    the program to the issue's 2 s and not the machine's other work (the suite's other worker)."""
    import resource
    import subprocess
    import sys
    import time
    exe = os.path.join(os.path.dirname(sys.executable), "selfcal")
    stamps, lines = [], []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    with subprocess.Popen([exe, *map(str, argv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True) as proc:
        assert proc.stderr is not None and proc.stdout is not None
        for line in proc.stderr:
            stamps.append(time.perf_counter())
            lines.append(line.rstrip())
        out = proc.stdout.read()
        proc.wait(timeout_s)
    end = time.perf_counter()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    share = max(1.0, (end - start) / max(cpu_s, 1e-3))
    gaps = [(b - a) / share for a, b in zip([start] + stamps, stamps + [end])]
    return proc.returncode, out, lines, gaps


def _silences(lines, gaps):
    """The longest silences first, each with the line it followed."""
    pairs = sorted(zip(gaps, ["(start)"] + lines), reverse=True)
    return [(line, f"{g:.2f} s") for g, line in pairs[:6]]


def test_undistort_map_says_how_far_it_is(adjusted):
    """The longest step of the exports (the inversion of the distortion on a 6000 x 4000 frame and the maps between
    the nodes: 3-13 s here, minutes for WAPs) prints a line at least every 2 s (3 s allowed for a loaded machine), stamped as stderr delivers it;
    its --json document names the file."""
    root, _ = adjusted
    argv, written = _verbs(root)["export undistort-map"]
    code, out, lines, gaps = _timed(argv + ["--json"])
    assert code == 0, "\n".join(lines)
    doc = _document(out)
    assert doc["command"] == "export undistort-map" and doc["written"] == [os.path.abspath(written)]
    assert max(gaps[1:]) <= 3.0, _silences(lines, gaps)
    assert any(" % of the nodes inverted in " in line or " % of the map rows interpolated in " in line
               for line in lines), lines
    assert any(line.startswith("writing ") for line in lines), lines


# ------------------------------------------------------------------ --quiet and --verbose in every verb

def _formats():
    from selfcal.cli.exporters import EXPORTERS
    from selfcal.cli.importers import IMPORTERS
    from selfcal.cli.main import COMMANDS
    words = [[verb] for verb in COMMANDS if verb not in ("import", "export")]
    return words + [["import", name] for name in IMPORTERS] + [["export", name] for name in EXPORTERS]


@pytest.mark.parametrize("words", _formats(), ids=" ".join)
def test_every_verb_and_format_has_quiet_and_verbose(words):
    code, out, _ = run_main_streams(words + ["--help"])
    assert code == 0 and "--quiet" in out and "--verbose" in out
    assert "no progress on stderr" in out and "more on stderr" in out        # the one meaning, said the same


@pytest.mark.parametrize("verb", VERBS)
def test_quiet_leaves_warnings_only_and_verbose_adds_the_logger(adjusted, verb):
    """--quiet: stderr holds warnings (and errors) only; --verbose: the default's lines and the logger's (the
    verb's time at least); stdout the same line in all three."""
    root, _ = adjusted
    argv, _ = _verbs(root)[verb]
    runs = {flag: run_main_streams(argv + ([flag] if flag else [])) for flag in ("--quiet", "", "--verbose")}
    assert all(code == 0 for code, _, _ in runs.values()), runs
    quiet, plain, loud = (runs[f][2].splitlines() for f in ("--quiet", "", "--verbose"))
    assert all(line.startswith("warning:") for line in quiet), quiet
    assert len(plain) > len(quiet), plain                 # every verb says something of its work by default
    # the same lines but the report's section steps, which are said at most once a second (so by timing)
    # (and the durations they state: 'read res in 0.0 s' in one run is '0.1 s' in the next)
    step = re.compile(r"^rendering the report: (?!quality check)")
    untimed = re.compile(r"\d+(\.\d+)? s\b")
    assert [untimed.sub("", line) for line in loud if not line.startswith("selfcal: ") and not step.match(line)] == \
        [untimed.sub("", line) for line in plain if not step.match(line)]
    assert any(line.startswith(f"selfcal: {verb}: done in ") for line in loud), loud
    assert len({untimed.sub("", out) for _, out, _ in runs.values()}) == 1


# ------------------------------------------------------------------ no step silent for more than ~2 s

COPR = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "copr")
#: the longest silence allowed on stderr, in seconds of an idle machine (``_timed``): the 2 s of issue 45 and a
#: margin for the parts of a run the load stretches more than the whole
SILENCE_S = 2.5


@pytest.fixture(scope="module")
def small_frames(tmp_path_factory):
    """A 10-image block whose camera is scaled to 600 x 400 px (the seed's frame in mm), adjusted with brown, and
    a grey image per photo: the inputs of export colmap-workspace."""
    from dataclasses import replace

    import cv2
    import numpy as np

    from selfcal.io import write_block
    from selfcal.simulate import simulate_uav
    sim = simulate_uav(seed=2, distortion="brown", points_per_mm2=0.3, n_strips=2, images_per_strip=5)
    block = sim.blocks["type1"]
    cams = {k: replace(c, width_px=c.width_px // 10, height_px=c.height_px // 10, pixel_size_mm=c.pixel_size_mm * 10)
            for k, c in block.cameras.items()}
    obs = block.observations
    block = replace(block, cameras=cams, image_sigma_px=block.image_sigma_px / 10,
                    observations=replace(obs, pixel=obs.pixel / 10, sigma_px=obs.sigma_px / 10))
    root = tmp_path_factory.mktemp("frames")
    write_block(block, root / "block")
    code, _, err = run_main_streams(["adjust", root / "block", "--out", root / "res", "--ap", "brown", "--no-report",
                                     "--quiet"])
    assert code == 0, err
    (root / "images").mkdir()
    camera = next(iter(cams.values()))
    for image_id in block.images.image_id:
        cv2.imwrite(str(root / "images" / f"{image_id}.png"),
                    np.full((camera.height_px, camera.width_px), 128, np.uint8))
    return root


def _timed_case(name, root, frames, tmp):
    """(argv, a line the run must print) of each verb's timed run."""
    return {
        "import colmap": (["import", "colmap", os.path.join(COPR, "sparse"), "--gcp",
                           os.path.join(COPR, "gcp_list.txt"), "--out", tmp / "copr"], "writing "),
        "adjust": (["adjust", root / "block", "--out", tmp / "res", "--ap", "brown"],
                   "rendering the report: quality check ..."),          # the first section, said at once
        "report": (["report", root / "res"], "rendering the report: quality check ..."),
        "export colmap-workspace": (["export", "colmap-workspace", frames / "res", "--images", frames / "images",
                                     "--out", tmp / "ws"], "[1/10] "),
        # the batch path of the demo (a local Dask cluster) on the smallest block: it must end without a traceback
        "compare": (["compare", root / "block", "--ap", "none,brown", "--out", tmp / "cmp"],
                    "starting a local Dask cluster of "),
    }[name]


@pytest.mark.parametrize("verb", ["import colmap", "adjust", "report", "export colmap-workspace",
                                  "compare"])
def test_no_step_is_silent_for_more_than_two_seconds(adjusted, small_frames, tmp_path, verb):
    """Each verb run as the command on a small block: every silence on stderr, from the start of the process to
    the first line, between lines and from the last to the end, at most SILENCE_S; exit 0 and no traceback.
    (export undistort-map: test_undistort_map_says_how_far_it_is.)"""
    if verb == "import colmap":
        assert os.path.isdir(COPR), "shared test data missing: ../shared/data/copr"
    root, _ = adjusted
    argv, expected = _timed_case(verb, root, small_frames, tmp_path)
    code, out, lines, gaps = _timed(argv)
    assert code == 0, "\n".join(lines)
    assert not any("Traceback" in line for line in lines), "\n".join(lines)
    assert max(gaps) <= SILENCE_S, _silences(lines, gaps)
    assert any(expected in line for line in lines), lines
    assert out.count("\n") == 1
