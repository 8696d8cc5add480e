"""The front door (issue 22): no command destroys a user's files, every bad input gets a one-line message.

Every case of tests/front_door.py runs through ``selfcal.cli.main.main``: the exit code is the one expected
(2 bad input, 1 undeterminable geometry, 130 Ctrl-C, 0 where the input is fine), the error is one line that
names the file (or point, or option), no traceback, every input byte-identical afterwards and no temporary
name left anywhere. Then Hypothesis mutates valid files of every reader (truncation, byte flips, inserted
tokens, numbers replaced by NaN / inf / huge values / text, column swaps, dropped lines) with a fixed seed:
a reader either reads the file or raises a BlockError naming it, on one line, and changes nothing.
"""
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from selfcal.errors import BlockError

import front_door
from front_door import CASES, SHARED_DATA, Workspace, digest, run_case, run_main, strays

EXAMPLES = 200


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    return Workspace(tmp_path_factory.mktemp("front_door"))


def test_there_are_at_least_90_cases():
    assert len(CASES) >= 90
    assert len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_case(ws, case):
    outcome = run_case(ws, case)
    assert not outcome.traceback, outcome.stderr
    assert outcome.exit in case.expected, outcome.stderr
    assert outcome.input_untouched, f"an input changed: {outcome.stderr}"
    assert not outcome.strays, outcome.strays
    if outcome.exit == 130:
        assert "interrupted" in outcome.message and "was there: removed" not in outcome.output_left
    elif outcome.exit != 0:
        assert outcome.error_lines == 1, outcome.stderr
        assert case.names is None or case.names in outcome.message, outcome.message
        assert "was there: removed" not in outcome.output_left


def test_out_block_parent_or_empty_leave_the_block_byte_identical(ws, tmp_path, monkeypatch):
    block = ws.copy(ws.block, str(tmp_path))
    before = digest(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    for out in (block, str(tmp_path), "", ".", os.path.join(block, "..")):
        code, err = run_main(["adjust", block, "--out", out, "--quiet"])
        assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, (out, err)
        assert digest(str(tmp_path)) == before


def test_ctrl_c_leaves_nothing_behind(tmp_path):
    """A real SIGINT in the middle of an adjustment: exit 130, no results folder, no temporary name."""
    from selfcal.io import write_block
    from conftest import simulation
    block = tmp_path / "block"
    write_block(simulation(seed=2, distortion="none", points_per_mm2=0.5).blocks["type3"], block)
    before = digest(str(block))
    out = tmp_path / "res"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.dirname(os.path.dirname(front_door.__file__)),
                                                       os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "selfcal.cli.main", "adjust", str(block), "--out", str(out),
                             "--ap", "brown", "--no-report"], stderr=subprocess.PIPE, text=True, env=env,
                            # a pytest-xdist worker ignores SIGINT and a child inherits that: give it Python's default
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    for line in proc.stderr:                 # interrupt once the iterations run
        lines.append(line)
        if "iteration" in line:
            proc.send_signal(signal.SIGINT)
            break
    rest = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=60) == 130, "".join(lines) + rest
    assert "Traceback" not in rest and "interrupted" in rest
    assert not out.exists() and not strays(str(tmp_path)) and digest(str(block)) == before


def test_ctrl_c_inside_a_compiled_kernel_is_an_interrupt(monkeypatch, capsys):
    """Ctrl-C while a Numba kernel calls back into Python (unpickling a constant) reaches the command as a
    SystemError caused by the KeyboardInterrupt (seen once in test_ctrl_c_leaves_nothing_behind): it is an
    interrupt, exit 130 without a traceback; a SystemError of any other cause is not hidden."""
    from selfcal.cli import main as cli

    def interrupted(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("<function _numba_unpickle> returned a result with an exception set") from exc

    def broken(args):
        raise SystemError("a genuine fault")

    monkeypatch.setattr(cli._module("adjust"), "run", interrupted)
    assert cli.main(["adjust", "somewhere", "--out", "elsewhere"]) == 130
    assert "interrupted (SIGINT); nothing was written" in capsys.readouterr().err
    monkeypatch.setattr(cli._module("adjust"), "run", broken)
    with pytest.raises(SystemError, match="genuine fault"):
        cli.main(["adjust", "somewhere", "--out", "elsewhere"])


# ------------------------------------------------------------------------------------------ Hypothesis

_NUMBER = re.compile(rb"-?\d+\.?\d*(?:[eE][-+]?\d+)?")
_VALUES = [b"nan", b"NaN", b"inf", b"-inf", b"1e308", b"1e400", b"-1e30", b"abc", b"", b"1,5", b"1e-320",
           b"99999999999999999999999", b"0", b"-0", b"\xff", b"\"", b"\x00", b"null", b"\"abc\"", b"[]", b"{}", b"true"]
_MUTATIONS = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0.0, 1.0)),
    st.tuples(st.just("flip"), st.floats(0.0, 1.0), st.integers(0, 255)),
    st.tuples(st.just("insert"), st.floats(0.0, 1.0), st.sampled_from(_VALUES)),
    st.tuples(st.just("number"), st.integers(0, 10**6), st.sampled_from(_VALUES)),
    st.tuples(st.just("swap_columns"), st.integers(0, 12), st.integers(0, 12)),
    st.tuples(st.just("drop_line"), st.integers(0, 10**6)),
)


def mutate(data: bytes, mutation) -> bytes:
    kind = mutation[0]
    if kind == "truncate":
        return data[:int(len(data) * mutation[1])]
    if kind == "flip":
        k = min(int(len(data) * mutation[1]), max(len(data) - 1, 0))
        return data[:k] + bytes([mutation[2]]) + data[k + 1:]
    if kind == "insert":
        k = int(len(data) * mutation[1])
        return data[:k] + mutation[2] + data[k:]
    if kind == "number":
        numbers = list(_NUMBER.finditer(data))
        if not numbers:
            return data
        m = numbers[mutation[1] % len(numbers)]
        return data[:m.start()] + mutation[2] + data[m.end():]
    if kind == "swap_columns":
        i, j = mutation[1], mutation[2]
        lines = data.split(b"\n")
        for n, line in enumerate(lines):
            sep = b"," if b"," in line else b" "
            fields = line.split(sep)
            if max(i, j) < len(fields):
                fields[i], fields[j] = fields[j], fields[i]
                lines[n] = sep.join(fields)
        return b"\n".join(lines)
    lines = data.split(b"\n")
    if lines:
        del lines[mutation[1] % len(lines)]
    return b"\n".join(lines)


def _block_reader(path):
    from selfcal.io import read_block
    return read_block(os.path.dirname(path))


def _colmap_reader(path):
    from selfcal.io.colmap import read_colmap
    return read_colmap(os.path.dirname(path))


def _reader(module, name):
    def read(path):
        import importlib
        return getattr(importlib.import_module(module), name)(path)
    return read


def _shared(*parts):
    return lambda ws: os.path.join(SHARED_DATA, *parts)


def _camera_json_reader(path):
    from selfcal.cli.calibrations import calibrations
    return calibrations(os.path.dirname(path))


def _isis_folder_reader(path):
    from selfcal.io.isis import read_image_folder
    left_out: list = []
    return read_image_folder(os.path.dirname(path), left_out=left_out)


#: reader -> (function of the mutated file's path, the valid folder or file, the files in it to mutate)
READERS = {
    "block folder": (_block_reader, lambda ws: ws.block, ("block.toml", "images.csv", "points.csv", "observations.csv")),
    "colmap text": (_colmap_reader, lambda ws: ws.colmap_text, ("cameras.txt", "images.txt", "points3D.txt")),
    "colmap binary": (_colmap_reader, lambda ws: ws.colmap_binary, ("cameras.bin", "images.bin", "points3D.bin")),
    "bal": (_reader("selfcal.io.bal", "read_bal"), lambda ws: ws.bal, None),
    "odm gcp_list": (_reader("selfcal.io.odm", "read_gcp_list"), lambda ws: ws.gcp_list, None),
    "isis control network": (_reader("selfcal.io.isis", "read_control_network"),
                             _shared("isis", "lro_nac_pair", "observationPair.net"), None),
    "isis cube label": (_reader("selfcal.io.isis", "read_cube_label"),
                        _shared("isis", "apollo15_metric", "apolloImage1.pvl"), None),
    "usgscsm frame isd": (_reader("selfcal.io.sensor_files", "read_usgscsm"),
                          _shared("isis", "apollo15_metric", "apolloImage1.isd"), None),
    "usgscsm line isd": (_reader("selfcal.io.sensor_files", "read_usgscsm"),
                         _shared("pushbroom", "asp_dg_spot", "ctx.json"), None),
    "rpc rpb": (_reader("selfcal.io.rpc", "read_rpc"), _shared("pushbroom", "asp_dg_spot", "sample.RPB"), None),
    "rpc dimap xml": (_reader("selfcal.io.rpc", "read_rpc"),
                      _shared("pushbroom", "pleiades", "rpc", "RPC_PHR1B_P_201709281038045_SEN_PRG_FC_178608-001.XML"),
                      None),
    "rpc ossim geom": (_reader("selfcal.io.rpc", "read_rpc"),
                       _shared("pushbroom", "pleiades", "rpc", "PHR1B_P_201709281038045_SEN_PRG_FC_178608-001.geom"),
                       None),
    "dimap physical model": (_reader("selfcal.io.dimap", "read_dimap_sensor"),
                             _shared("pushbroom", "pleiades", "rpc", "PHRDIMAP_P1BP--2018122638935449CP.XML"), None),
    "digitalglobe xml": (_reader("selfcal.io.dg", "read_dg"), _shared("pushbroom", "asp_dg_spot", "dg_example1.xml"),
                         None),
    "spot5 dimap": (_reader("selfcal.io.spot", "read_spot5"), _shared("pushbroom", "asp_dg_spot", "spot_example1.xml"),
                    None),
    "pat-b .im": (_reader("selfcal.io.patb", "read_photo_blocks"), lambda ws: os.path.join(ws.patb, "block.im"), None),
    "pat-b .con": (_reader("selfcal.io.patb", "read_con"), lambda ws: os.path.join(ws.patb, "block.con"), None),
    "pat-b .ori": (_reader("selfcal.io.patb", "read_ori"), lambda ws: os.path.join(ws.patb, "block.ori"), None),
    "opensfm reconstruction": (_reader("selfcal.io.opensfm", "read_reconstruction"),
                               lambda ws: os.path.join(ws.opensfm, "reconstruction.json"), None),
    "opensfm tracks": (_reader("selfcal.io.opensfm", "read_tracks"),
                       lambda ws: os.path.join(ws.opensfm, "tracks.csv"), None),
    "metashape calibration": (_reader("selfcal.io.calibration_files", "read_calibration_file"),
                              lambda ws: _metashape_calibration(ws), None),
    **{f"opencv {ext}": (_reader("selfcal.io.calibration_files", "read_calibration_file"),
                         lambda ws, ext=ext: _exported(ws, "opencv", f"cal.{ext}"), None)
       for ext in ("yaml", "xml", "json")},
    "opensfm cameras.json": (_reader("selfcal.io.calibration_files", "read_calibration_file"),
                             lambda ws: _exported(ws, "opensfm", "cameras.json"), None),
    "kalibr camchain": (_reader("selfcal.io.calibration_files", "read_calibration_file"),
                        lambda ws: _exported(ws, "kalibr", "camchain.yaml"), None),
    "camera.json": (_camera_json_reader, lambda ws: ws.results, ("camera.json",)),
    "isis label folder": (_isis_folder_reader, _shared("isis", "lro_nac_pair"), ("observationImageL.pvl",)),
}

#: the readers issue 46 added to the fuzzing, run with EXAMPLES_LONG examples each behind the slow mark
READERS_46 = ("opencv yaml", "opencv xml", "opencv json", "opensfm cameras.json", "metashape calibration",
              "camera.json", "isis cube label", "isis label folder")
EXAMPLES_LONG = 500


def _exported(ws, tool: str, name: str) -> str:
    """A calibration file of the block's camera exported once from its results by ``selfcal export TOOL``."""
    path = os.path.join(ws.root, "calibration", name)
    if not os.path.exists(path):
        from front_door import run_main
        code, err = run_main(["export", tool, ws.results, "--out", path, "--tolerance-px", "1"])
        assert code == 0, err
    return path


def _metashape_calibration(ws) -> str:
    """A Metashape calibration XML of the block's camera, exported once from its results."""
    path = os.path.join(ws.root, "calibration", "cal.xml")
    if not os.path.exists(path):
        from front_door import run_main
        code, err = run_main(["export", "metashape", ws.results, "--out", path, "--tolerance-px", "1"])
        assert code == 0, err
    return path


def _bytes(path: str) -> bytes:
    with open(path, "rb") as handle:
        return handle.read()


#: the readers whose 200 mutated files take more than a second (the vendors' XML files, the larger inputs)
SLOW_READERS = ("dimap physical model", "digitalglobe xml", "spot5 dimap", "isis control network", "isis cube label",
                "opensfm tracks")


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.slow) if name in SLOW_READERS else name
                                  for name in READERS])
def test_mutated_files_are_read_or_refused_with_their_name(ws, name):
    _fuzz(ws, name, EXAMPLES)


@pytest.mark.slow
@pytest.mark.parametrize("name", READERS_46)
def test_the_foreign_readers_of_issue_46_survive_500_mutations(ws, name):
    """OpenCV FileStorage, OpenSfM cameras.json, Metashape calibration XML, camera.json and ISIS labels: each of
    500 mutated files is read or refused with its name (cv2.FileStorage used to abort the process on some)."""
    _fuzz(ws, name, EXAMPLES_LONG)


def _fuzz(ws, name: str, examples_wanted: int) -> None:
    read, source_of, members = READERS[name]
    source = source_of(ws)
    work = tempfile.mkdtemp(prefix="fuzz-", dir=ws.root)
    if members is None:
        folder = work
        shutil.copy(source, os.path.join(folder, os.path.basename(source)))
        originals = {os.path.basename(source): _bytes(source)}
    else:
        folder = os.path.join(work, "copy")
        shutil.copytree(source, folder)
        originals = {m: _bytes(os.path.join(folder, m)) for m in members}
    names = sorted(originals)
    examples = []

    @settings(max_examples=examples_wanted, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(member=st.sampled_from(names), mutation=_MUTATIONS)
    def check(member, mutation):
        examples.append(1)
        for m, data in originals.items():                  # the valid files, then one of them mutated
            with open(os.path.join(folder, m), "wb") as handle:
                handle.write(data)
        path = os.path.join(folder, member)
        broken = mutate(originals[member], mutation)
        with open(path, "wb") as handle:
            handle.write(broken)
        try:
            read(path)
        except BlockError as exc:
            text = str(exc)
            assert "\n" not in text, text
            assert os.path.basename(exc.path) in text and os.path.dirname(os.path.abspath(exc.path)).startswith(
                os.path.abspath(work)), text
        with open(path, "rb") as handle:
            assert handle.read() == broken
        assert sorted(os.listdir(folder)) == sorted(set(os.listdir(folder)) | set()) and not strays(work)

    check()
    assert len(examples) >= examples_wanted   # Hypothesis ran them all (it stops early only on a failure)
    shutil.rmtree(work)
