"""Output safety for every writer (issue 46): the Python API's ``Outcome.write`` passes the ``--out`` check, a
failed run never replaces earlier results, a full disk leaves the previous state exactly and names the path,
and images that do not decode completely or whose names are not UTF-8 are refused by name (exit 2)."""
from __future__ import annotations

import contextlib
import csv
import errno
import os
import shutil
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from front_door import Workspace, digest, run_main, strays
from selfcal.errors import UsageError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: what makes the front door's block fail: orientations far off, least squares, two iterations
FAILING = ["--robust", "none", "--snoop", "0", "--max-iterations", "2", "--no-report", "--quiet"]


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    return Workspace(tmp_path_factory.mktemp("output_safety"))


@pytest.fixture(scope="module")
def far_block(ws, tmp_path_factory):
    """The front door's block with every image turned by 8 degrees and moved by 20 m: two iterations of least
    squares do not converge."""
    path = str(tmp_path_factory.mktemp("far") / "block")
    shutil.copytree(ws.block, path)
    with open(os.path.join(path, "images.csv"), newline="", encoding="utf-8") as handle:
        rows = list(csv.reader(handle))
    kappa, x0 = rows[0].index("kappa_deg"), rows[0].index("X0")
    for row in rows[1:]:
        row[kappa], row[x0] = str(float(row[kappa]) + 8), str(float(row[x0]) + 20)
    with open(os.path.join(path, "images.csv"), "w", newline="", encoding="utf-8") as handle:
        csv.writer(handle, lineterminator="\n").writerows(rows)
    return path


# ------------------------------------------------------------------------------------------ the Python API

def test_api_write_never_goes_over_an_input_or_a_foreign_folder(ws, tmp_path):
    import selfcal
    block = shutil.copytree(ws.block, tmp_path / "block")
    before = digest(str(block))
    outcome = selfcal.bundle_adjust(str(block))
    for target in (block, block / "res", tmp_path):
        with pytest.raises(UsageError, match=str(target).replace("\\", "\\\\")):
            outcome.write(target)
    # a Block read from the folder knows where it came from
    with pytest.raises(UsageError, match="is the input"):
        selfcal.bundle_adjust(selfcal.read_block(str(block))).write(block)
    assert digest(str(block)) == before
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "mine.txt").write_text("my own file\n")
    with pytest.raises(UsageError, match=r"notes exists and was not written by selfcal .*force=True"):
        outcome.write(notes, report=False)
    assert (notes / "mine.txt").read_text() == "my own file\n" and not strays(str(tmp_path))
    assert outcome.write(notes, report=False, force=True) == str(notes)
    assert not (notes / "mine.txt").exists() and (notes / ".selfcal-output").exists()


def test_api_failed_outcome_keeps_earlier_results(ws, far_block, tmp_path):
    import selfcal
    res = shutil.copytree(ws.results, tmp_path / "res")
    before = digest(str(res))
    outcome = selfcal.bundle_adjust(far_block, robust="none", snoop=0, max_iterations=2)
    assert outcome.failed and "did not converge" in outcome.failed
    assert outcome.write(res, report=False) == f"{res}-failed"
    assert digest(str(res)) == before and (tmp_path / "res-failed" / "summary.json").exists()
    assert not strays(str(tmp_path))


# ------------------------------------------------------------------------------------------ a failed run

def test_failed_adjustment_keeps_earlier_results(ws, far_block, tmp_path):
    res = shutil.copytree(ws.results, tmp_path / "res")
    before, block_before = digest(str(res)), digest(far_block)
    code, err = run_main(["adjust", far_block, "--out", str(res), *FAILING])
    assert code == 1, err
    assert (f"selfcal adjust: error: the adjustment did not converge: no convergence within 2 iterations; {res} "
            f"keeps the earlier results; this run's files are in {res}-failed") in err
    assert digest(str(res)) == before and digest(far_block) == block_before
    assert (tmp_path / "res-failed" / ".selfcal-output").exists()
    # the sibling holds someone's files: the failed run's files go nowhere, and the message says why
    shutil.rmtree(tmp_path / "res-failed")
    (tmp_path / "res-failed").mkdir()
    (tmp_path / "res-failed" / "mine.txt").write_text("x")
    code, err = run_main(["adjust", far_block, "--out", str(res), *FAILING])
    assert code == 1 and f"this run's files were not written ({res}-failed exists and selfcal did not write it)" \
        in err, err
    assert digest(str(res)) == before and os.listdir(tmp_path / "res-failed") == ["mine.txt"]
    # nothing earlier: the failed run's files are where they were asked for
    code, err = run_main(["adjust", far_block, "--out", str(tmp_path / "new"), *FAILING])
    assert code == 1 and f"this run's files are in {tmp_path / 'new'}" in err
    assert not strays(str(tmp_path))


def test_failed_comparison_keeps_earlier_results(ws, tmp_path, monkeypatch):
    """``compare`` (and ``demo``, which writes the same matrix) with a failed cell: exit 1, the earlier comparison
    byte-identical, this run's files beside it."""
    import selfcal.batch as batch          # compare imports run_matrix from it when it runs
    out = tmp_path / "cmp"
    code, err = run_main(["compare", ws.block, "--ap", "none", "--out", str(out), "--no-report"])
    assert code == 0, err
    before = digest(str(out))
    real = batch.run_matrix

    def one_fails(*args, **kwargs):
        cells = real(*args, **kwargs)
        return [replace(cells[0], error="injected failure"), *cells[1:]]
    monkeypatch.setattr(batch, "run_matrix", one_fails)
    code, err = run_main(["compare", ws.block, "--ap", "none", "--out", str(out), "--no-report"])
    assert code == 1, err
    assert (f"selfcal compare: error: 1 of 1 adjustments failed (block none); {out} keeps the earlier results; "
            f"this run's files are in {out}-failed") in err, err
    assert digest(str(out)) == before and (tmp_path / "cmp-failed" / "comparison.md").exists()
    assert not strays(str(tmp_path))


# ------------------------------------------------------------------------------------------ a full disk

def _full_disk_on_report(monkeypatch):
    """report.html cannot be written (ENOSPC) after the figures were: an injected OSError in the writer."""
    import selfcal.io.results as results_io
    real = results_io.atomic_write

    @contextlib.contextmanager
    def atomic_write(path, *args, **kwargs):
        with real(path, *args, **kwargs) as handle:
            if os.path.basename(path) == "report.html":      # as handle.write would: no file name
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            yield handle
    monkeypatch.setattr(results_io, "atomic_write", atomic_write)


def test_full_disk_in_report_leaves_the_results_as_they_were(ws, tmp_path, monkeypatch):
    res = shutil.copytree(ws.results, tmp_path / "res")
    before = digest(str(res))
    _full_disk_on_report(monkeypatch)
    code, err = run_main(["report", str(res)])
    assert code == 1, err
    # the progress lines of the report's steps, then the one error
    last = err.strip().splitlines()[-1]
    assert last == f"selfcal report: error: cannot write {res}/report.html: No space left on device"
    assert err.count("error") == 1 and "Traceback" not in err, err
    assert digest(str(res)) == before and not strays(str(tmp_path))


def test_full_disk_in_adjust_leaves_the_earlier_results(ws, tmp_path, monkeypatch):
    res = shutil.copytree(ws.results, tmp_path / "res")
    before = digest(str(res))
    _full_disk_on_report(monkeypatch)
    code, err = run_main(["adjust", ws.block, "--out", str(res), "--quiet"])
    assert code == 1 and f"selfcal adjust: error: cannot write {res}/report.html: No space left on device" in err
    assert digest(str(res)) == before and not strays(str(tmp_path))


def _can_mount_tmpfs() -> bool:
    if not sys.platform.startswith("linux") or shutil.which("unshare") is None:
        return False
    done = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                          capture_output=True)
    return done.returncode == 0


@pytest.mark.skipif(not _can_mount_tmpfs(), reason="needs a private mount namespace (unshare -m, root) for a tmpfs")
def test_a_real_full_disk_leaves_the_results_as_they_were(ws, selfcal_exe, tmp_path):
    """``selfcal report`` on a 1 MiB tmpfs that has room for a copy of the results but not for the figures."""
    mount = tmp_path / "disk"
    mount.mkdir()
    script = f"""
set -e
mount -t tmpfs -o size=1m tmpfs {mount}
cp -a {ws.results} {mount}/res
free=$(df -B1 --output=avail {mount} | tail -1); used=$(du -sB1 {mount}/res | cut -f1)
head -c $((free - used - 60000)) /dev/zero > {mount}/filler
cd {mount}/res && find . -type f | sort | xargs sha256sum > {tmp_path}/before.sha
set +e
{selfcal_exe} report {mount}/res 2> {tmp_path}/err; echo $? > {tmp_path}/code
cd {mount}/res && find . -type f | sort | xargs sha256sum > {tmp_path}/after.sha
ls -A {mount} > {tmp_path}/left
"""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH")) if p))
    subprocess.run(["unshare", "-m", "sh", "-c", script], check=True, env=env)
    err = (tmp_path / "err").read_text()
    assert (tmp_path / "code").read_text().strip() == "1", err
    last = err.strip().splitlines()[-1]                      # after the progress lines of the report's steps
    assert last.startswith(f"selfcal report: error: cannot write {mount}/res/") and \
        last.endswith(": No space left on device") and "partial" not in err, err
    assert err.count("error") == 1 and "Traceback" not in err, err
    assert (tmp_path / "before.sha").read_text() == (tmp_path / "after.sha").read_text()
    assert (tmp_path / "left").read_text().split() == ["filler", "res"]


# ------------------------------------------------------------------------------------------ images

SCALE = 10


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A results folder of a 600 x 400 px camera and its ten images as JPEG."""
    import cv2
    from selfcal.io import write_block
    from selfcal.simulate import simulate_uav
    root = tmp_path_factory.mktemp("images")
    sim = simulate_uav(seed=3, distortion="brown", points_per_mm2=0.05, n_strips=2, images_per_strip=5)
    block = sim.blocks["type3"]
    cams = {k: replace(c, width_px=c.width_px // SCALE, height_px=c.height_px // SCALE,
                       pixel_size_mm=c.pixel_size_mm * SCALE) for k, c in block.cameras.items()}
    obs = block.observations
    block = replace(block, cameras=cams, image_sigma_px=block.image_sigma_px / SCALE,
                    observations=replace(obs, pixel=obs.pixel / SCALE, sigma_px=obs.sigma_px / SCALE))
    write_block(block, root / "block")
    code, err = run_main(["adjust", str(root / "block"), "--out", str(root / "res"), "--ap", "brown",
                          "--no-report", "--quiet"])
    assert code == 0, err
    images = root / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    for image_id in block.images.image_id:
        noise = (rng.random((400, 600, 3)) * 255).astype(np.uint8)
        cv2.imwrite(str(images / f"{image_id}.jpg"), cv2.GaussianBlur(noise, (31, 31), 8))
    return root


def _cut(path, fraction: float) -> None:
    with open(path, "rb") as handle:
        data = handle.read()
    with open(path, "wb") as handle:
        handle.write(data[:int(len(data) * fraction)])


def test_a_truncated_jpeg_is_an_error_naming_it(small, tmp_path):
    images = shutil.copytree(small / "images", tmp_path / "images")
    cut = images / "S1_03.jpg"
    _cut(cut, 0.4)
    before = digest(str(images))
    code, err = run_main(["undistort", str(small / "res"), *sorted(map(str, images.iterdir())),
                          "--out", str(tmp_path / "und")])
    assert code == 2 and f"selfcal undistort: error: {cut}: " in err, err
    assert "cut short or damaged" in err
    code, err = run_main(["export", "colmap-workspace", str(small / "res"), "--images", str(images),
                          "--out", str(tmp_path / "ws")])
    assert code == 2 and f"selfcal export: error: {cut}: " in err and "cut short or damaged" in err, err
    assert not (tmp_path / "und").exists() and not (tmp_path / "ws").exists() and not strays(str(tmp_path))
    assert digest(str(images)) == before


def test_the_complete_decode_check_catches_what_opencv_lets_through(tmp_path):
    """cv2.imread of a JPEG cut at 40 % warns and fills the missing rows grey; the check refuses every cut."""
    import cv2
    from selfcal.errors import BlockError
    from selfcal.io.images import read_image
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur((rng.random((400, 600, 3)) * 255).astype(np.uint8), (31, 31), 8)
    for ext in (".jpg", ".png"):
        path = str(tmp_path / f"whole{ext}")
        cv2.imwrite(path, image)
        assert read_image(path).shape == (400, 600, 3)
        for fraction in (0.1, 0.4, 0.9, 0.999):
            cut = str(tmp_path / f"cut{ext}")
            shutil.copy(path, cut)
            _cut(cut, fraction)
            with pytest.raises(BlockError, match="cut"):
                read_image(cut)


def test_a_file_name_that_is_not_utf8_is_refused_by_name(small, tmp_path):
    images = shutil.copytree(small / "images", tmp_path / "images")
    strange = os.path.join(os.fsencode(str(images)), b"S1_01-caf\xe9.jpg")
    os.rename(os.path.join(os.fsencode(str(images)), b"S1_01.jpg"), strange)
    code, err = run_main(["undistort", str(small / "res"), os.fsdecode(strange), "--out", str(tmp_path / "und")])
    assert code == 2, err
    assert f"selfcal undistort: error: {images}/S1_01-caf\\xe9.jpg: the file name is not UTF-8 (byte 0xe9)" in err
    assert not (tmp_path / "und").exists() and not strays(str(tmp_path))
