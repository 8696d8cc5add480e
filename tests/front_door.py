"""The front door of issue 22 as data: small valid inputs of every reader, and the cases of bad input and
mistaken commands, each run through ``selfcal.cli.main.main`` in this process.

Used by tests/test_fuzz_inputs.py (which asserts every case) and benchmarks/front_door_table.py (which prints
the table of the issue). A case is a function ``(ws, work) -> (argv, inputs, out)``: it may copy and break
inputs inside its own folder ``work``; ``inputs`` are the files and folders that must come out byte-identical,
``out`` the output path (or None).
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import os
import shutil
import struct
import traceback
from dataclasses import dataclass, field

import numpy as np

SHARED_DATA = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))


# ------------------------------------------------------------------------------------------ running

def run_main(argv: list[str]) -> tuple[object, str]:
    """(exit code, stderr) of ``selfcal ARGV`` in this process; an escaping exception is 'traceback'."""
    code, _, err = run_main_streams(argv)
    return code, err


def run_main_streams(argv: list[str]) -> tuple[object, str, str]:
    """(exit code, stdout, stderr) of ``selfcal ARGV`` in this process; an escaping exception is 'traceback'."""
    from selfcal.cli.main import main
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:            # --help, or an argparse exit main did not turn into a message
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:                # noqa: BLE001 - a traceback is what the cases must never show
            traceback.print_exc(file=err)
            code = "traceback"
    return code, out.getvalue(), err.getvalue()


def digest(path: str) -> dict:
    """Every file and folder below ``path`` (or the file itself) with the SHA-256 of its bytes."""
    out = {}
    if os.path.isfile(path):
        with open(path, "rb") as handle:
            return {"": hashlib.sha256(handle.read()).hexdigest()}
    for folder, dirs, files in os.walk(path):
        rel = os.path.relpath(folder, path)
        out[rel + "/"] = "dir"
        for name in files:
            with open(os.path.join(folder, name), "rb") as handle:
                out[os.path.join(rel, name)] = hashlib.sha256(handle.read()).hexdigest()
    return out


def strays(root: str) -> list[str]:
    """Temporary names selfcal's atomic writing uses, anywhere below ``root``."""
    from selfcal.io.atomic import TEMPORARY_PREFIXES
    found = []
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            if name.startswith(TEMPORARY_PREFIXES) or ".old-" in name or ".partial-" in name:
                found.append(os.path.join(folder, name))
    return found


@dataclass
class Outcome:
    name: str
    expected: tuple
    exit: object
    message: str
    traceback: bool
    error_lines: int
    input_untouched: bool
    strays: list
    output_left: str
    names: str | None
    stderr: str = field(repr=False, default="")

    @property
    def ok(self) -> bool:
        named = self.names is None or self.names in self.message
        one_line = (self.exit in (0, None) or self.error_lines == 1
                    or (self.exit == 130 and "interrupted" in self.message and self.error_lines == 0))
        return (self.exit in self.expected and not self.traceback and self.input_untouched and not self.strays
                and named and one_line)


# ------------------------------------------------------------------------------------------ inputs

class Workspace:
    """Small valid inputs of every reader, made once under ``root``."""

    def __init__(self, root: str):
        self.root = str(root)
        self.fixtures = os.path.join(self.root, "fixtures")
        os.makedirs(self.fixtures, exist_ok=True)
        self._made: dict[str, str] = {}

    def _once(self, name: str, make) -> str:
        if name not in self._made:
            path = os.path.join(self.fixtures, name)
            if not os.path.exists(path):
                make(path)
            self._made[name] = path
        return self._made[name]

    def simulation(self):
        from selfcal.simulate import simulate_uav
        return simulate_uav(seed=3, distortion="none", points_per_mm2=0.05, n_strips=2, images_per_strip=5)

    @property
    def block(self) -> str:
        """A 10-image frame block (27 GCP, 12 CHK, 570 observations)."""
        from selfcal.io import write_block
        return self._once("block", lambda p: write_block(self.simulation().blocks["type3"], p))

    @property
    def results(self) -> str:
        """The results folder of :attr:`block` (no report)."""
        def make(path):
            code, err = run_main(["adjust", self.block, "--out", path, "--no-report", "--quiet"])
            assert code == 0, err
        return self._once("results", make)

    @property
    def bal(self) -> str:
        return self._once("dubrovnik-3-7-pre.txt", lambda p: shutil.copy(
            os.path.join(SHARED_DATA, "bal", "dubrovnik-3-7-pre.txt"), p))

    @property
    def gcp_list(self) -> str:
        return self._once("gcp_list.txt", lambda p: shutil.copy(os.path.join(SHARED_DATA, "copr", "gcp_list.txt"), p))

    @property
    def colmap_text(self) -> str:
        return self._once("colmap_txt", lambda p: write_colmap(p, binary=False))

    @property
    def colmap_binary(self) -> str:
        return self._once("colmap_bin", lambda p: write_colmap(p, binary=True))

    @property
    def isis(self) -> str:
        """The LRO NAC pair: control network and the two cube labels with their ISDs."""
        return self._once("lro_nac_pair", lambda p: shutil.copytree(
            os.path.join(SHARED_DATA, "isis", "lro_nac_pair"), p, copy_function=_copy_writable))

    @property
    def patb(self) -> str:
        """PAT-B files (block.im, block.con, block.ori) of :attr:`block`'s simulation."""
        return self._once("patb", lambda p: write_patb(p, self.simulation()))

    @property
    def opensfm(self) -> str:
        """An OpenSfM reconstruction.json and tracks.csv of :attr:`block`'s simulation."""
        return self._once("opensfm", lambda p: write_opensfm(p, self.simulation()))

    def copy(self, source: str, work: str, name: str | None = None) -> str:
        """A writable copy of ``source`` (file or folder) inside ``work``."""
        target = os.path.join(work, name or os.path.basename(os.path.normpath(source)))
        if os.path.isdir(source):
            shutil.copytree(source, target, copy_function=_copy_writable)
        else:
            _copy_writable(source, target)
        return target


def _copy_writable(source: str, target: str) -> str:
    shutil.copyfile(source, target)
    os.chmod(target, 0o644)
    return target


def colmap_model():
    """A small COLMAP model: 4 PINHOLE images looking down at 40 points (world = camera axes, Z forward)."""
    rng = np.random.default_rng(22)
    points = np.column_stack([rng.uniform(0.5, 2.5, 40), rng.uniform(-1.5, 1.5, 40), rng.uniform(8, 12, 40)])
    centres = [np.array([0.6 * k, 0.0, 0.0]) for k in range(4)]
    f, cx, cy = 900.0, 500.0, 400.0
    obs = []
    for i, c in enumerate(centres):
        X = points - c
        uv = np.column_stack([f * X[:, 0] / X[:, 2] + cx, f * X[:, 1] / X[:, 2] + cy])
        obs.append(uv)
    return points, centres, (f, cx, cy), obs


def write_colmap(folder: str, binary: bool) -> None:
    points, centres, (f, cx, cy), obs = colmap_model()
    os.makedirs(folder)
    if not binary:
        with open(os.path.join(folder, "cameras.txt"), "w") as h:
            h.write(f"# Camera list\n1 PINHOLE 1000 800 {f} {f} {cx} {cy}\n")
        with open(os.path.join(folder, "images.txt"), "w") as h:
            h.write("# Image list\n")
            for i, c in enumerate(centres):
                h.write(f"{i + 1} 1 0 0 0 {-c[0]} {-c[1]} {-c[2]} 1 img{i + 1}.jpg\n")
                h.write(" ".join(f"{u:.4f} {v:.4f} {j + 1}" for j, (u, v) in enumerate(obs[i])) + "\n")
        with open(os.path.join(folder, "points3D.txt"), "w") as h:
            h.write("# 3D point list\n")
            for j, p in enumerate(points):
                track = " ".join(f"{i + 1} {j}" for i in range(len(centres)))
                h.write(f"{j + 1} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} 128 128 128 0.5 {track}\n")
        return
    with open(os.path.join(folder, "cameras.bin"), "wb") as h:
        h.write(struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, 1, 1000, 800) + struct.pack("<4d", f, f, cx, cy))
    with open(os.path.join(folder, "images.bin"), "wb") as h:
        h.write(struct.pack("<Q", len(centres)))
        for i, c in enumerate(centres):
            h.write(struct.pack("<i4d3di", i + 1, 1, 0, 0, 0, -c[0], -c[1], -c[2], 1))
            h.write(f"img{i + 1}.jpg".encode() + b"\0")
            h.write(struct.pack("<Q", len(obs[i])))
            for j, (u, v) in enumerate(obs[i]):
                h.write(struct.pack("<ddq", u, v, j + 1))
    with open(os.path.join(folder, "points3D.bin"), "wb") as h:
        h.write(struct.pack("<Q", len(points)))
        for j, p in enumerate(points):
            h.write(struct.pack("<Q3d3Bd", j + 1, *p, 128, 128, 128, 0.5))
            h.write(struct.pack("<Q", len(centres)))
            for i in range(len(centres)):
                h.write(struct.pack("<ii", i + 1, j))


def write_patb(folder: str, sim) -> None:
    """The simulation's type3 block as PAT-B (.im in mm from the image centre, y up; .con; .ori with A = M^T)."""
    from selfcal.geometry.rotation import matrix_from_opk
    block = sim.blocks["type3"]
    cam = block.cameras["ilce7m3"]
    p, w, h = cam.pixel_size_mm, cam.width_px, cam.height_px
    os.makedirs(folder)
    ob = block.observations
    with open(os.path.join(folder, "block.im"), "w") as f:
        for i, image in enumerate(block.images.image_id):
            f.write(f"{image} {cam.focal_mm}\n")
            for k in np.flatnonzero(ob.image_index == i):
                col, row = ob.pixel[k]
                f.write(f"{block.points.point_id[ob.point_index[k]]} {(col - w / 2) * p:.6f} {(h / 2 - row) * p:.6f}\n")
            f.write("-99\n")
    marks = np.flatnonzero(block.points.role != "tie")
    with open(os.path.join(folder, "block.con"), "w") as f:
        for k in marks:
            f.write(f"{block.points.point_id[k]} " + " ".join(f"{v:.3f}" for v in block.points.xyz_m[k]) + "\n")
        f.write("-99\n")
    with open(os.path.join(folder, "block.ori"), "w") as f:
        for image, eop in zip(sim.truth.image_id, sim.truth.eop):
            a = matrix_from_opk(eop[3:]).T.ravel()
            f.write(f"{image} {eop[0]:.4f} {eop[1]:.4f} {eop[2]:.4f}\n" + " ".join(f"{v:.12f}" for v in a[:5]) + "\n"
                    + " ".join(f"{v:.12f}" for v in a[5:]) + "\n")


def write_opensfm(folder: str, sim) -> None:
    """The simulation's block as OpenSfM's reconstruction.json and tracks.csv (a perspective camera)."""
    import json
    from selfcal.geometry.rotation import matrix_from_opk
    from scipy.spatial.transform import Rotation
    block = sim.blocks["type3"]
    cam = block.cameras["ilce7m3"]
    w, h, s = cam.width_px, cam.height_px, max(cam.width_px, cam.height_px)
    os.makedirs(folder)
    shots = {}
    for image, eop in zip(sim.truth.image_id, sim.truth.eop):
        r = np.diag([1.0, -1.0, -1.0]) @ matrix_from_opk(eop[3:])
        shots[str(image)] = {"rotation": [float(v) for v in Rotation.from_matrix(r).as_rotvec()],
                             "translation": [float(v) for v in -r @ eop[:3]], "camera": "cam"}
    points = {str(i): {"coordinates": [float(v) for v in x]} for i, x in zip(sim.truth.point_id, sim.truth.xyz)}
    camera = {"projection_type": "perspective", "width": w, "height": h, "focal": cam.focal_mm / cam.pixel_size_mm / s,
              "k1": 0.0, "k2": 0.0}
    with open(os.path.join(folder, "reconstruction.json"), "w") as f:
        json.dump([{"cameras": {"cam": camera}, "shots": shots, "points": points}], f, indent=1)
    ob = block.observations
    with open(os.path.join(folder, "tracks.csv"), "w") as f:
        f.write("OPENSFM_TRACKS_VERSION_v2\n")
        for k in range(len(ob)):
            x, y = (ob.pixel[k] - [w / 2, h / 2]) / s
            f.write(f"{block.images.image_id[ob.image_index[k]]}\t{block.points.point_id[ob.point_index[k]]}\t{k}\t"
                    f"{x:.9f}\t{y:.9f}\t0.004\t1\t2\t3\t-1\t-1\n")


# ------------------------------------------------------------------------------------------ editing

def edit_field(path: str, line: int, column: str, value: str) -> None:
    """Set ``column`` (header name) of 1-based ``line`` of a CSV file."""
    with open(path) as h:
        lines = h.read().split("\n")
    k = lines[0].split(",").index(column)
    fields = lines[line - 1].split(",")
    fields[k] = value
    lines[line - 1] = ",".join(fields)
    with open(path, "w") as h:
        h.write("\n".join(lines))


def replace_bytes(path: str, old: bytes, new: bytes, count: int = 1) -> None:
    with open(path, "rb") as h:
        data = h.read()
    assert old in data, (path, old)
    with open(path, "wb") as h:
        h.write(data.replace(old, new, count))


def prepend(path: str, prefix: bytes) -> None:
    with open(path, "rb") as h:
        data = h.read()
    with open(path, "wb") as h:
        h.write(prefix + data)


def truncate(path: str, fraction: float) -> None:
    with open(path, "rb") as h:
        data = h.read()
    with open(path, "wb") as h:
        h.write(data[:int(len(data) * fraction)])


# ------------------------------------------------------------------------------------------ cases

@dataclass(frozen=True)
class Case:
    name: str
    setup: object          # (ws, work) -> (argv, inputs, out)
    expected: tuple        # exit codes accepted
    names: str | None      # text the error message must hold (a file, a point, an option)


CASES: list[Case] = []


def case(name: str, exit=2, names: str | None = None):
    def register(setup):
        CASES.append(Case(name, setup, exit if isinstance(exit, tuple) else (exit,), names))
        return setup
    return register


def run_case(ws: Workspace, c: Case) -> Outcome:
    work = os.path.join(ws.root, "cases", c.name.replace(" ", "_").replace("/", "_")[:80])
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    argv, inputs, out = c.setup(ws, work)
    before = {p: digest(p) for p in inputs}
    existed = out is not None and os.path.lexists(out)
    with getattr(argv, "patch", None) or contextlib.nullcontext():
        code, err = run_main(list(argv))
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if ": error:" in line]
    message = errors[-1] if errors else (lines[-1] if lines else "")
    untouched = all(os.path.lexists(p) and digest(p) == d for p, d in before.items())
    if out is None or not os.path.lexists(out):
        left = "none" + (" (was there: removed!)" if existed else "")
    else:
        left = ("replaced" if existed else "written") if code == 0 else ("kept as it was" if existed else "written")
    return Outcome(c.name, c.expected, code, message, "Traceback" in err, len(errors), untouched,
                   strays(ws.root), left, c.names, err)


def _adjust(out_of, exit=2, names=None, extra=()):
    """A case of ``selfcal adjust BLOCK --out OUT``."""
    def setup(ws, work):
        out = out_of(ws, work)
        return ["adjust", ws.block, "--out", out, "--no-report", "--quiet", *extra], [ws.block], out
    return setup


def _with_block(change, exit=2, extra=()):
    """``selfcal adjust`` on a copy of the block that ``change(block_folder)`` broke."""
    def setup(ws, work):
        block = ws.copy(ws.block, work)
        change(block)
        out = os.path.join(work, "res")
        return ["adjust", block, "--out", out, "--no-report", "--quiet", *extra], [block] if os.path.exists(block) else [], out
    return setup


def _option(command: str, *options, needs=None):
    """``selfcal COMMAND ... OPTIONS`` with valid inputs: only the option is wrong."""
    def setup(ws, work):
        out = os.path.join(work, "out")
        if command == "adjust":
            argv = ["adjust", ws.block, "--out", out, "--quiet"]
            inputs = [ws.block]
        elif command == "compare":
            argv, inputs = ["compare", ws.block, "--out", out, "--scheduler", "serial"], [ws.block]
        elif command == "simulate":
            argv, inputs = ["simulate", "uav", "--out", out], []
        elif command == "simulate prism":
            argv, inputs = ["simulate", "prism", "--out", out], []
        elif command == "import":
            argv, inputs = ["import", "bal", ws.bal, "--out", out], [ws.bal]
        elif command == "import colmap":
            argv, inputs = ["import", "colmap", ws.colmap_text, "--out", out], [ws.colmap_text]
        elif command == "import isis":
            argv = ["import", "isis", os.path.join(ws.isis, "observationPair.net"), "--images", ws.isis, "--out", out]
            inputs = [ws.isis]
        elif command == "export":
            argv, inputs = ["export", "opencv", ws.results, "--out", os.path.join(work, "cam.yaml")], [ws.results]
        elif command == "demo":
            argv, inputs = ["demo", "--out", out], []
        else:
            argv, inputs = [command], []
        return argv + list(options), inputs, out
    return setup


# --- 1. output safety ---------------------------------------------------------------------------------
case("adjust --out BLOCK", names="is the input")(_adjust(lambda ws, w: ws.block))
case("adjust --out PARENT_OF_BLOCK", names="holds the input")(_adjust(lambda ws, w: ws.fixtures))
case("adjust --out ''", names="--out is empty")(_adjust(lambda ws, w: ""))
case("adjust --out BLOCK/results", names="lies inside the input")(_adjust(lambda ws, w: os.path.join(ws.block, "res")))
case("adjust --out BLOCK/.. (parent, spelt otherwise)", names="holds the input")(
    _adjust(lambda ws, w: os.path.join(ws.block, "..")))
case("adjust --out / (the root)", names="holds the input")(_adjust(lambda ws, w: "/"))


def _symlink_to_block(ws, work):
    link = os.path.join(work, "link")
    os.symlink(ws.block, link)
    return link


case("adjust --out SYMLINK_TO_BLOCK", names="is the input")(_adjust(_symlink_to_block))


def _existing_file(ws, work):
    path = os.path.join(work, "notes.txt")
    with open(path, "w") as h:
        h.write("my notes\n")
    return path


def _user_folder(ws, work):
    path = os.path.join(work, "thesis")
    os.makedirs(path)
    with open(os.path.join(path, "chapter1.tex"), "w") as h:
        h.write("\\chapter{One}\n")
    return path


case("adjust --out EXISTING_FILE", names="is a file")(_adjust(_existing_file))
case("adjust --out FILE/child (parent is a file)", names="is a file")(
    _adjust(lambda ws, w: os.path.join(_existing_file(ws, w), "res")))
case("adjust --out USER_FOLDER (not selfcal's)", names="not written by selfcal")(_adjust(_user_folder))
case("adjust --out USER_FOLDER --force", exit=0)(_adjust(_user_folder, extra=("--force",)))
case("adjust --out /proc/x (cannot be written)", names="cannot write")(_adjust(lambda ws, w: "/proc/selfcal-front-door"))
case("adjust --out /sys/x (cannot be written)", names="cannot write")(_adjust(lambda ws, w: "/sys/selfcal-front-door"))


def _previous_results(ws, work):
    out = os.path.join(work, "res")
    shutil.copytree(ws.results, out)
    return out


case("adjust --out EARLIER_RESULTS (selfcal's: replaced)", exit=0)(_adjust(_previous_results))
case("adjust --out EMPTY_FOLDER", exit=0)(_adjust(lambda ws, w: (os.makedirs(os.path.join(w, "e")), os.path.join(w, "e"))[1]))


@case("adjust --out = the block's --dem file", names="is the input")
def _(ws, work):
    dem = _existing_file(ws, work)
    return ["adjust", ws.block, "--out", dem, "--dem", dem, "--quiet"], [ws.block, dem], dem


@case("compare --out BLOCK", names="is the input")
def _(ws, work):
    return ["compare", ws.block, "--out", ws.block, "--scheduler", "serial"], [ws.block], ws.block


@case("compare --out PARENT_OF_BLOCK", names="holds the input")
def _(ws, work):
    return ["compare", ws.block, "--out", ws.fixtures, "--scheduler", "serial"], [ws.block], ws.fixtures


@case("compare --out ''", names="--out is empty")
def _(ws, work):
    return ["compare", ws.block, "--out", "", "--scheduler", "serial"], [ws.block], None


@case("demo --out ''", names="--out is empty")
def _(ws, work):
    return ["demo", "--out", ""], [], None


@case("demo --out EXISTING_FILE", names="is a file")
def _(ws, work):
    path = _existing_file(ws, work)
    return ["demo", "--out", path], [path], path


@case("demo --out USER_FOLDER", names="not written by selfcal")
def _(ws, work):
    path = _user_folder(ws, work)
    return ["demo", "--out", path], [path], path


@case("simulate --out ''", names="--out is empty")
def _(ws, work):
    return ["simulate", "uav", "--out", ""], [], None


@case("simulate --out EXISTING_FILE", names="is a file")
def _(ws, work):
    path = _existing_file(ws, work)
    return ["simulate", "uav", "--out", path], [path], path


@case("simulate --out USER_FOLDER", names="not written by selfcal")
def _(ws, work):
    path = _user_folder(ws, work)
    return ["simulate", "uav", "--out", path], [path], path


@case("import colmap MODEL --out MODEL", names="is the input")
def _(ws, work):
    return ["import", "colmap", ws.colmap_text, "--out", ws.colmap_text], [ws.colmap_text], ws.colmap_text


@case("import colmap MODEL --out MODEL/block", names="lies inside the input")
def _(ws, work):
    out = os.path.join(ws.colmap_text, "block")
    return ["import", "colmap", ws.colmap_text, "--out", out], [ws.colmap_text], out


@case("import colmap MODEL --out PARENT_OF_MODEL", names="holds the input")
def _(ws, work):
    return ["import", "colmap", ws.colmap_text, "--out", ws.fixtures], [ws.colmap_text], ws.fixtures


@case("import colmap MODEL --gcp F --out F", names="is the input")
def _(ws, work):
    return (["import", "colmap", ws.colmap_text, "--gcp", ws.gcp_list, "--out", ws.gcp_list],
            [ws.colmap_text, ws.gcp_list], ws.gcp_list)


@case("import bal FILE --out FILE", names="is the input")
def _(ws, work):
    return ["import", "bal", ws.bal, "--out", ws.bal], [ws.bal], ws.bal


@case("import bal FILE --out ''", names="--out is empty")
def _(ws, work):
    return ["import", "bal", ws.bal, "--out", ""], [ws.bal], None


@case("import bal FILE --out FOLDER_OF_FILE", names="holds the input")
def _(ws, work):
    return ["import", "bal", ws.bal, "--out", ws.fixtures], [ws.bal], ws.fixtures


@case("import isis NET --images DIR --out DIR", names="holds the input")
def _(ws, work):
    net = os.path.join(ws.isis, "observationPair.net")
    return ["import", "isis", net, "--images", ws.isis, "--out", ws.isis], [ws.isis], ws.isis


@case("import bal FILE --out NEW (works)", exit=0)
def _(ws, work):
    out = os.path.join(work, "ladybug")
    return ["import", "bal", ws.bal, "--out", out], [ws.bal], out


@case("import colmap TEXT --out NEW (works)", exit=0)
def _(ws, work):
    out = os.path.join(work, "block")
    return ["import", "colmap", ws.colmap_text, "--out", out], [ws.colmap_text], out


@case("import colmap BINARY --out NEW (works)", exit=0)
def _(ws, work):
    out = os.path.join(work, "block")
    return ["import", "colmap", ws.colmap_binary, "--out", out], [ws.colmap_binary], out


def _utm_block_and_geo(ws, work, bad_line: str | None = None) -> tuple[str, str]:
    """A UTM copy of the workspace block and an ODM geo.txt (WGS84 UTM 32N) of its images' positions; with
    ``bad_line`` that line is added at line 3."""
    from dataclasses import replace
    from selfcal.io import read_block, write_block
    block = read_block(ws.block)
    shift = np.array([500_000.0, 5_200_000.0, 0.0])
    block = replace(block, crs="EPSG:32632", images=replace(block.images, position_m=block.images.position_m + shift),
                    points=replace(block.points, xyz_m=block.points.xyz_m + shift))
    folder = os.path.join(work, "utm")
    write_block(block, folder)
    lines = ["WGS84 UTM 32N"] + [f"{i}.JPG {x:.3f} {y:.3f} {z:.3f}" for i, (x, y, z) in
                                 zip(block.images.image_id, block.images.position_m)]
    if bad_line is not None:
        lines.insert(2, bad_line)
    geo = os.path.join(work, "geo.txt")
    with open(geo, "w") as handle:
        handle.write("\n".join(lines) + "\n")
    return folder, geo


@case("import gnss GEO --block B --out NEW (works)", exit=0)
def _(ws, work):
    block, geo = _utm_block_and_geo(ws, work)
    out = os.path.join(work, "gnss")
    return ["import", "gnss", geo, "--block", block, "--out", out], [block, geo], out


@case("import gnss GEO --block B --out B", names="is the input")
def _(ws, work):
    block, geo = _utm_block_and_geo(ws, work)
    return ["import", "gnss", geo, "--block", block, "--out", block], [block, geo], block


@case("import gnss GEO(bad line 3) --block B", names="line 3")
def _(ws, work):
    block, geo = _utm_block_and_geo(ws, work, bad_line="S1_02.JPG 500100.0 5200100.0 high")
    out = os.path.join(work, "gnss")
    return ["import", "gnss", geo, "--block", block, "--out", out], [block, geo], out


@case("import gnss GEO --block LOCAL_BLOCK", names='crs is "local"')
def _(ws, work):
    _, geo = _utm_block_and_geo(ws, work)
    out = os.path.join(work, "gnss")
    return ["import", "gnss", geo, "--block", ws.block, "--out", out], [ws.block, geo], out


@case("import gnss GEO --block B --sigma-m 0.02,0", names="--sigma-m")
def _(ws, work):
    block, geo = _utm_block_and_geo(ws, work)
    out = os.path.join(work, "gnss")
    return ["import", "gnss", geo, "--block", block, "--sigma-m", "0.02,0", "--out", out], [block, geo], out


@case("export --out RESULTS", names="is the input")
def _(ws, work):
    return ["export", "opencv", ws.results, "--out", ws.results], [ws.results], ws.results


@case("export --out RESULTS/summary.json", names="lies inside the input")
def _(ws, work):
    out = os.path.join(ws.results, "summary.json")
    return ["export", "opencv", ws.results, "--out", out], [ws.results], out


@case("export --out RESULTS/camera.yaml", names="lies inside the input")
def _(ws, work):
    out = os.path.join(ws.results, "camera.yaml")
    return ["export", "opencv", ws.results, "--out", out], [ws.results], out


@case("export --out ''", names="--out is empty")
def _(ws, work):
    return ["export", "opencv", ws.results, "--out", ""], [ws.results], None


@case("export --out EXISTING_FOLDER", names="is a folder")
def _(ws, work):
    out = _user_folder(ws, work)
    return ["export", "opencv", ws.results, "--out", out], [ws.results, out], out


@case("export --out FILE/x.yaml (parent is a file)", names="is a file")
def _(ws, work):
    out = os.path.join(_existing_file(ws, work), "x.yaml")
    return ["export", "opencv", ws.results, "--out", out], [ws.results], out


@case("export --out MISSING_FOLDER/cam.yaml (created)", exit=0)
def _(ws, work):
    out = os.path.join(work, "new", "folder", "cam.yaml")
    return ["export", "opencv", ws.results, "--out", out], [ws.results], out


@case("export colmap --out /proc/x (cannot be written)", names="cannot write")
def _(ws, work):
    return ["export", "colmap", ws.results, "--out", "/proc/selfcal/cameras.txt"], [ws.results], None


def _first_image(block: str) -> str:
    with open(os.path.join(block, "images.csv")) as handle:
        return handle.read().splitlines()[1].split(",")[0]


@case("export rpc of a frame image (no RPC)", names="cannot be handed over")
def _(ws, work):
    out = os.path.join(work, "img.RPB")
    return (["export", "rpc", ws.results, "--block", ws.block, "--image", _first_image(ws.block), "--out", out],
            [ws.results, ws.block], out)


@case("export rpc --image NOT_IN_RESULTS", names="--image nope: not an image of")
def _(ws, work):
    out = os.path.join(work, "img.RPB")
    return ["export", "rpc", ws.results, "--block", ws.block, "--image", "nope", "--out", out], [ws.results, ws.block], out


@case("export rpc --out x.jpg (the format is the name's)", names=".RPB or _RPC.TXT")
def _(ws, work):
    out = os.path.join(work, "img.jpg")
    return (["export", "rpc", ws.results, "--block", ws.block, "--image", _first_image(ws.block), "--out", out],
            [ws.results, ws.block], out)


@case("export rpc --out BLOCK/x.RPB", names="lies inside the input")
def _(ws, work):
    out = os.path.join(ws.block, "x.RPB")
    return (["export", "rpc", ws.results, "--block", ws.block, "--image", _first_image(ws.block), "--out", out],
            [ws.results, ws.block], out)


@case("export metashape --out RESULTS/cal.xml", names="lies inside the input")
def _(ws, work):
    out = os.path.join(ws.results, "cal.xml")
    return ["export", "metashape", ws.results, "--out", out], [ws.results], out


@case("export opencv --out cam.txt (no FileStorage format)", names="cam.txt")
def _(ws, work):
    out = os.path.join(work, "cam.txt")
    return ["export", "opencv", ws.results, "--out", out], [ws.results], out


@case("export kalibr --model pinhole (no such model)", names="--model")
def _(ws, work):
    out = os.path.join(work, "camchain.yaml")
    return ["export", "kalibr", ws.results, "--model", "pinhole", "--out", out], [ws.results], out


@case("export opensfm --out NEW (works)", exit=0)
def _(ws, work):
    out = os.path.join(work, "cameras.json")
    return ["export", "opensfm", ws.results, "--out", out, "--tolerance-px", "1"], [ws.results], out


def _metashape_xml(ws, work) -> str:
    """A Metashape calibration of the block's camera (exported from its results)."""
    path = os.path.join(work, "cal.xml")
    code, err = run_main(["export", "metashape", ws.results, "--out", path, "--tolerance-px", "1"])
    assert code == 0, err
    return path


@case("import calibration XML --block BLOCK --out BLOCK", names="is the input")
def _(ws, work):
    xml = _metashape_xml(ws, work)
    return ["import", "calibration", xml, "--block", ws.block, "--out", ws.block], [ws.block, xml], ws.block


@case("import calibration NOT_A_CALIBRATION --block BLOCK", names="not a calibration file")
def _(ws, work):
    path = os.path.join(work, "notes.txt")
    with open(path, "w") as handle:
        handle.write("f = 3000\n")
    out = os.path.join(work, "b2")
    return ["import", "calibration", path, "--block", ws.block, "--out", out], [ws.block, path], out


@case("import calibration XML --block BLOCK --camera NOPE", names="--camera")
def _(ws, work):
    xml = _metashape_xml(ws, work)
    out = os.path.join(work, "b2")
    return ["import", "calibration", xml, "--block", ws.block, "--camera", "NOPE", "--out", out], [ws.block, xml], out


@case("import calibration XML --block BLOCK --fixed --out NEW (works)", exit=0)
def _(ws, work):
    xml = _metashape_xml(ws, work)
    out = os.path.join(work, "b2")
    return ["import", "calibration", xml, "--block", ws.block, "--fixed", "--out", out], [ws.block, xml], out


def _images_folder(work, *names, size=(10, 10)):
    """A folder of small grey PNGs with the given file names."""
    import cv2
    folder = os.path.join(work, "photos")
    os.makedirs(folder)
    for name in names:
        cv2.imwrite(os.path.join(folder, name), np.zeros(size, np.uint8))
    return folder


@case("export colmap-workspace --images MISSING", names="no such folder")
def _(ws, work):
    out = os.path.join(work, "ws")
    return (["export", "colmap-workspace", ws.results, "--images", os.path.join(work, "photos"), "--out", out],
            [ws.results], out)


@case("export colmap-workspace --images DIR without the block's images", names="none of the block's")
def _(ws, work):
    images, out = _images_folder(work, "IMG_0001.JPG"), os.path.join(work, "ws")
    return ["export", "colmap-workspace", ws.results, "--images", images, "--out", out], [ws.results, images], out


@case("export colmap-workspace --out RESULTS/ws", names="lies inside the input")
def _(ws, work):
    images, out = _images_folder(work, "S1_01.png"), os.path.join(ws.results, "ws")
    return ["export", "colmap-workspace", ws.results, "--images", images, "--out", out], [ws.results, images], out


@case("export colmap-workspace, an image of the wrong size", names="is 10 x 10 px")
def _(ws, work):
    images, out = _images_folder(work, "S1_01.png", "S1_02.png"), os.path.join(work, "ws")
    return ["export", "colmap-workspace", ws.results, "--images", images, "--out", out], [ws.results, images], out


@case("undistort --out RESULTS", names="is the input")
def _(ws, work):
    return ["undistort", ws.results, ws.bal, "--out", ws.results], [ws.results, ws.bal], ws.results


@case("undistort --out IMAGE", names="is the input")
def _(ws, work):
    return ["undistort", ws.results, ws.bal, "--out", ws.bal], [ws.results, ws.bal], ws.bal


@case("undistort --out ''", names="--out is empty")
def _(ws, work):
    return ["undistort", ws.results, ws.bal, "--out", ""], [ws.results], None


@case("undistort NOT_AN_IMAGE --out NEW", names="dubrovnik")
def _(ws, work):
    out = os.path.join(work, "u")
    return ["undistort", ws.results, ws.bal, "--out", out], [ws.results, ws.bal], out


@case("report MISSING_FOLDER", names="no such results folder")
def _(ws, work):
    return ["report", os.path.join(work, "nothing")], [], None


@case("report BLOCK (not a results folder)", names="summary.json")
def _(ws, work):
    return ["report", ws.block], [ws.block], None


@case("report ''", names="RESULTS is empty")
def _(ws, work):
    return ["report", ""], [], None


# --- 2. options -------------------------------------------------------------------------------------------
for _command, _options, _names in [
        ("adjust", ("--ap", "unknown_family"), "unknown AP model"),
        ("adjust", ("--ap", "wavelet:db99"), "db99"),
        ("adjust", ("--ap", "legendre:-2"), "legendre degree"),
        ("adjust", ("--ap", "fourier:9"), "fourier order"),
        ("adjust", ("--ap", "brown:3"), "takes no option"),
        ("adjust", ("--ap", "wavelet"), "needs a wavelet"),
        ("adjust", ("--ap", "wavelet:db4+x"), "formulation"),
        ("adjust", ("--ap", ""), "unknown AP model"),
        ("adjust", ("--ap", "auto:brown,nope"), "nope"),
        ("adjust", ("--snoop", "-1"), "--snoop"),
        ("adjust", ("--snoop", "nan"), "--snoop"),
        ("adjust", ("--snoop", "inf"), "--snoop"),
        ("adjust", ("--snoop", "three"), "--snoop"),
        ("adjust", ("--grid", "0x6"), "--grid"),
        ("adjust", ("--grid", "9y6"), "--grid"),
        ("adjust", ("--grid", "100000x1"), "--grid"),
        ("adjust", ("--max-iterations", "0"), "--max-iterations"),
        ("adjust", ("--ap-sigma-px", "-1"), "--ap-sigma-px"),
        ("adjust", ("--ap-sigma-px", "nan"), "--ap-sigma-px"),
        ("adjust", ("--significance", "-2"), "--significance"),
        ("adjust", ("--max-correlation", "1.5"), "--max-correlation"),
        ("adjust", ("--joint-alpha", "1"), "--joint-alpha"),
        ("adjust", ("--max-iop-move", "-0.1"), "--max-iop-move"),
        ("adjust", ("--gnss-drift", "7"), "--gnss-drift"),
        ("adjust", ("--gnss-drift", "x"), "--gnss-drift"),
        ("adjust", ("--gcps", "0"), "--gcps"),
        ("adjust", ("--sensor-model", "M6"), "does not apply"),
        ("adjust", ("--trajectory-significance", "nan"), "--trajectory-significance"),
        ("adjust", ("--trajectory-significance", "1.0"), "has no [gnss]"),
        ("adjust", ("--no-such-option",), "unrecognized"),
        ("compare", ("--ap", "brown,nope"), "nope"),
        ("compare", ("--workers", "0"), "--workers"),
        ("simulate", ("--noise-px", "0"), "--noise-px"),
        ("simulate", ("--noise-px", "nan"), "--noise-px"),
        ("simulate", ("--blunder-rate", "0.9"), "--blunder-rate"),
        ("simulate", ("--seed", "-1"), "--seed"),
        ("simulate prism", ("--points", "3"), "--points"),
        ("import colmap", ("--pixel-size-mm", "-1"), "--pixel-size-mm"),
        ("import", ("--image-sigma-px", "nan"), "--image-sigma-px"),
        ("import isis", ("--attitude-degree", "9"), "--attitude-degree"),
        ("export", ("--tolerance-px", "0"), "--tolerance-px"),
        ("demo", ("--blunder-rate", "nan"), "--blunder-rate"),
        ("frobnicate", (), "invalid choice")]:
    case(f"{_command} {' '.join(_options)}".strip(), names=_names)(_option(_command, *_options))


# --- 2. encodings and readers: the block folder -----------------------------------------------------------
def _bom_everywhere(block):
    for name in ("block.toml", "images.csv", "points.csv", "observations.csv"):
        prepend(os.path.join(block, name), b"\xef\xbb\xbf")


case("block: UTF-8 byte-order mark in every file (Excel)", exit=0)(_with_block(_bom_everywhere))
case("block: Latin-1 byte in points.csv", names="points.csv, line 3")(
    _with_block(lambda b: _latin1_on_line(os.path.join(b, "points.csv"), 3)))


def _latin1_on_line(path, line):
    with open(path, "rb") as h:
        lines = h.read().split(b"\n")
    lines[line - 1] = b"\xe9" + lines[line - 1]
    with open(path, "wb") as h:
        h.write(b"\n".join(lines))

case("block: Latin-1 byte in block.toml", names="block.toml, line 1")(
    _with_block(lambda b: replace_bytes(os.path.join(b, "block.toml"), b"name = \"", b"name = \"\xe9")))


def _utf16(block):
    path = os.path.join(block, "images.csv")
    with open(path, encoding="utf-8") as h:
        text = h.read()
    with open(path, "wb") as h:
        h.write(text.encode("utf-16"))


case("block: images.csv saved as UTF-16", names="images.csv")(_with_block(_utf16))
case("block: NUL byte in observations.csv", names="observations.csv, line 5")(
    _with_block(lambda b: edit_field(os.path.join(b, "observations.csv"), 5, "col_px", "12\x003")))
case("block: NaN in points.csv", names="points.csv, line 4, column 'Z'")(
    _with_block(lambda b: edit_field(os.path.join(b, "points.csv"), 4, "Z", "nan")))
case("block: inf in observations.csv", names="observations.csv, line 7, column 'row_px'")(
    _with_block(lambda b: edit_field(os.path.join(b, "observations.csv"), 7, "row_px", "inf")))
case("block: 1e400 in images.csv", names="images.csv, line 3, column 'Z0'")(
    _with_block(lambda b: edit_field(os.path.join(b, "images.csv"), 3, "Z0", "1e400")))
case("block: text in a number", names="observations.csv, line 9, column 'col_px'")(
    _with_block(lambda b: edit_field(os.path.join(b, "observations.csv"), 9, "col_px", "12.5x")))
case("block: observations.csv truncated mid-line", names="observations.csv")(
    _with_block(lambda b: truncate(os.path.join(b, "observations.csv"), 0.5)))
case("block: points.csv empty", names="points.csv")(
    _with_block(lambda b: open(os.path.join(b, "points.csv"), "w").close()))
case("block: block.toml not TOML", names="block.toml")(
    _with_block(lambda b: replace_bytes(os.path.join(b, "block.toml"), b"[observations]", b"[observations")))
case("block: unknown column", names="unknown column")(
    _with_block(lambda b: replace_bytes(os.path.join(b, "points.csv"), b"point_id,", b"pointid,")))
case("block: columns shuffled in the header", names="points.csv")(
    _with_block(lambda b: replace_bytes(os.path.join(b, "points.csv"), b"X,Y,Z", b"Z,role2,X")))
case("block: folder missing", names="block folder not found")(_with_block(lambda b: shutil.rmtree(b)))
case("block: observations.csv is a folder", names="observations.csv")(
    _with_block(lambda b: (os.unlink(os.path.join(b, "observations.csv")), os.mkdir(os.path.join(b, "observations.csv")))))


def _first_gcp_line(block) -> int:
    with open(os.path.join(block, "points.csv")) as h:
        return next(k for k, line in enumerate(h.read().split("\n"), start=1) if ",gcp," in line)


case("block: control point at X = 1e30", exit=1, names="points.csv line")(
    _with_block(lambda b: edit_field(os.path.join(b, "points.csv"), _first_gcp_line(b), "X", "1e30")))


def _one_outside(block):
    edit_field(os.path.join(block, "observations.csv"), 6, "row_px", "4004.8")


case("block: one observation 4.8 px outside the frame (dropped, warned)", exit=0)(_with_block(_one_outside))


def _image_in_mm(block):
    path = os.path.join(block, "observations.csv")
    with open(path) as h:
        lines = h.read().split("\n")
    image = lines[1].split(",")[0]
    for k, line in enumerate(lines[1:], start=1):
        f = line.split(",")
        if f[0] == image:
            f[2], f[3] = str(float(f[2]) * 1000), str(float(f[3]) * 1000)
            lines[k] = ",".join(f)
    with open(path, "w") as h:
        h.write("\n".join(lines))


case("block: an image's observations x1000 (unit mistake)", names="are the units pixels?")(_with_block(_image_in_mm))


# --- 3. geometry that cannot be determined ----------------------------------------------------------------
def _control_on_a_line(off_line_m: float):
    def change(block):
        from selfcal.sensors.frame import pixel_from_photo, project
        sim = Workspace.simulation(None)
        truth, camera = sim.truth, sim.truth.camera
        path = os.path.join(block, "points.csv")
        with open(path) as h:
            lines = h.read().split("\n")
        gcp = np.array([[float(v) for v in line.split(",")[2:5]] for line in lines[1:] if ",gcp," in line])
        d = np.linalg.norm(gcp[:, None] - gcp[None], axis=2)
        a, b = np.unravel_index(np.argmax(d), d.shape)
        normal = np.cross(gcp[b] - gcp[a], [0.0, 0.0, 1.0])
        normal /= np.linalg.norm(normal)
        lines = [line.replace(",gcp,", ",tie,") for line in lines]
        rng = np.random.default_rng(1)
        observations = []
        for k, s in enumerate((0.15, 0.5, 0.85)):
            X = gcp[a] + s * (gcp[b] - gcp[a]) + (off_line_m * normal if k == 1 else 0.0)
            lines.insert(1, f"line{k + 1},gcp,{X[0]:.6f},{X[1]:.6f},{X[2]:.6f},0.02,0.03")
            for image, eop in zip(truth.image_id, truth.eop):
                xy = project(X[None], eop[None], np.array([camera.focal_mm, camera.x0_mm, camera.y0_mm]))
                px = pixel_from_photo(xy, camera.width_px, camera.height_px, camera.pixel_size_mm)[0]
                px = px + rng.normal(0.0, 0.5, 2)
                if 0 <= px[0] <= camera.width_px and 0 <= px[1] <= camera.height_px:
                    observations.append(f"{image},line{k + 1},{px[0]:.5f},{px[1]:.5f}")
        with open(path, "w") as h:
            h.write("\n".join(lines))
        with open(os.path.join(block, "observations.csv"), "a") as h:
            h.write("\n".join(observations) + "\n")
    return change


case("geometry: three control points exactly on a line", exit=1, names="lie on one line")(
    _with_block(_control_on_a_line(0.0)))
case("geometry: control 1 m off a line in a 385 m block", exit=1, names="line1")(
    _with_block(_control_on_a_line(1.0)))
case("geometry: control 30 m off the line (determined)", exit=0)(_with_block(_control_on_a_line(30.0)))


def _far_tie_point(block):
    from selfcal.sensors.frame import pixel_from_photo, project
    sim = Workspace.simulation(None)
    truth, camera = sim.truth, sim.truth.camera
    ground = truth.xyz[np.argmin(np.linalg.norm(truth.xyz[:, :2] - truth.eop[0, :2], axis=1))]
    ray = ground - truth.eop[0, :3]
    X = truth.eop[0, :3] + ray * (30000.0 / np.linalg.norm(ray))
    rows = []
    for image, eop in zip(truth.image_id, truth.eop):
        xy = project(X[None], eop[None], np.array([camera.focal_mm, camera.x0_mm, camera.y0_mm]))
        px = pixel_from_photo(xy, camera.width_px, camera.height_px, camera.pixel_size_mm)[0]
        if 0 <= px[0] <= camera.width_px and 0 <= px[1] <= camera.height_px and len(rows) < 2:
            rows.append(f"{image},far1,{px[0]:.5f},{px[1]:.5f}")
    with open(os.path.join(block, "points.csv"), "a") as h:
        h.write("far1,tie,,,,,\n")
    with open(os.path.join(block, "observations.csv"), "a") as h:
        h.write("\n".join(rows) + "\n")


case("geometry: a tie point 30 km away (sigma 2.8 km)", exit=1, names="far1")(_with_block(_far_tie_point))


# --- 2. the other readers, through the commands that read them --------------------------------------------
def _import(kind: str, source_of, change, names=None, exit=2, gcp=None):
    def setup(ws, work):
        source = ws.copy(source_of(ws), work)
        change(source)
        out = os.path.join(work, "imported")
        argv = ["import", kind, source, "--out", out]
        inputs = [source]
        if gcp is not None:
            g = ws.copy(ws.gcp_list, work)
            gcp(g)
            argv += ["--gcp", g]
            inputs.append(g)
        return argv, inputs, out
    return setup


def _colmap_file(name, change_bytes):
    return lambda folder: change_bytes(os.path.join(folder, name))


for _label, _kind, _src, _change, _names in [
        ("colmap text: NaN in points3D.txt", "colmap", "colmap_text",
         _colmap_file("points3D.txt", lambda p: replace_bytes(p, b"\n5 ", b"\n5 nan 0 ")), "points3D.txt"),
        ("colmap text: inf in images.txt", "colmap", "colmap_text",
         _colmap_file("images.txt", lambda p: replace_bytes(p, b"\n2 1 0 0 0", b"\n2 1 inf 0 0")), "images.txt"),
        ("colmap text: text in cameras.txt", "colmap", "colmap_text",
         _colmap_file("cameras.txt", lambda p: replace_bytes(p, b"PINHOLE 1000", b"PINHOLE 1OOO")), "cameras.txt"),
        ("colmap text: images.txt truncated", "colmap", "colmap_text",
         _colmap_file("images.txt", lambda p: truncate(p, 0.6)), "images.txt"),
        ("colmap text: Latin-1 byte in images.txt", "colmap", "colmap_text",
         _colmap_file("images.txt", lambda p: replace_bytes(p, b"img1.jpg", b"img\xe9.jpg")), "images.txt"),
        ("colmap text: BOM in cameras.txt", "colmap", "colmap_text",
         _colmap_file("cameras.txt", lambda p: prepend(p, b"\xef\xbb\xbf")), None),
        ("colmap binary: images.bin truncated", "colmap", "colmap_binary",
         _colmap_file("images.bin", lambda p: truncate(p, 0.5)), "images.bin"),
        ("colmap binary: points3D.bin truncated", "colmap", "colmap_binary",
         _colmap_file("points3D.bin", lambda p: truncate(p, 0.7)), "points3D.bin"),
        ("colmap binary: NaN in points3D.bin", "colmap", "colmap_binary",
         _colmap_file("points3D.bin", lambda p: _patch(p, 16, struct.pack("<d", float("nan")))), "points3D.bin"),
        ("colmap binary: cameras.bin empty", "colmap", "colmap_binary",
         _colmap_file("cameras.bin", lambda p: open(p, "wb").close()), "cameras.bin"),
        ("bal: NaN in an observation", "bal", "bal", lambda p: _bal_token(p, 2, b"nan"), "line 3"),
        ("bal: text in the parameters", "bal", "bal", lambda p: _bal_token(p, -5, b"abc"), "dubrovnik-3-7-pre.txt"),
        ("bal: truncated", "bal", "bal", lambda p: truncate(p, 0.5), "dubrovnik-3-7-pre.txt"),
        ("bal: header counts too large", "bal", "bal", lambda p: replace_bytes(p, b"3 7 ", b"3 70 "), "dubrovnik"),
        ("bal: Latin-1 byte", "bal", "bal", lambda p: prepend(p, b"\xe9"), "dubrovnik-3-7-pre.txt, line 1"),
        ("bal: 1e400 in a point", "bal", "bal", lambda p: _bal_token(p, -1, b"1e400"), "dubrovnik-3-7-pre.txt")]:
    case(_label, names=_names, exit=0 if _names is None else 2)(
        _import(_kind, (lambda attr: lambda ws: getattr(ws, attr))(_src), _change))


for _label, _change, _names in [
        ("odm gcp_list: NaN", lambda p: _odm_token(p, 2, 2, b"nan"), "gcp_list.txt, line 3"),
        ("odm gcp_list: text in a number", lambda p: _odm_token(p, 3, 4, b"12x"), "gcp_list.txt, line 4"),
        ("odm gcp_list: truncated line", lambda p: _odm_cut(p, 3), "gcp_list.txt, line 3"),
        ("odm gcp_list: Latin-1 byte", lambda p: _odm_token(p, 2, 6, b"IMG_\xe9.JPG"), "gcp_list.txt, line 3")]:
    case(_label, names=_names)(_import("colmap", lambda ws: ws.colmap_text, lambda s: None, gcp=_change))


def _isis(change, names):
    def setup(ws, work):
        folder = ws.copy(ws.isis, work)
        change(folder)
        out = os.path.join(work, "imported")
        net = os.path.join(folder, "observationPair.net")
        return ["import", "isis", net, "--images", folder, "--out", out], [folder], out
    return setup


case("isis: control network truncated", names="observationPair.net")(
    _isis(lambda f: truncate(os.path.join(f, "observationPair.net"), 0.4), "observationPair.net"))
case("isis: NaN in a point's coordinate", names="observationPair.net")(
    _isis(lambda f: _first_number_after(os.path.join(f, "observationPair.net"), b"AprioriX         =", b"NaN"),
          "observationPair.net"))
case("isis: Latin-1 byte in the network", names="observationPair.net")(
    _isis(lambda f: replace_bytes(os.path.join(f, "observationPair.net"), b"Object", b"Obj\xe9ct"),
          "observationPair.net"))
case("isis: ISD truncated", names="observationImageL.isd")(
    _isis(lambda f: truncate(os.path.join(f, "observationImageL.isd"), 0.5), "observationImageL.isd"))
case("isis: NaN in an ISD", names="observationImageL.isd")(
    _isis(lambda f: _first_number_after(os.path.join(f, "observationImageL.isd"), b"\"focal_length_model\"", b"NaN"),
          "observationImageL.isd"))
case("isis: cube label truncated", names="observationImageR.pvl")(
    _isis(lambda f: truncate(os.path.join(f, "observationImageR.pvl"), 0.3), "observationImageR.pvl"))


# --- the UAV tools' files (issue 23): PAT-B, OpenSfM, Pix4D, Metashape markers ----------------------------
PATB_SIZE = ["--image-size", "6000x4000", "--pixel-size-mm", "0.0059"]


def _patb(change, extra=()):
    def setup(ws, work):
        folder = ws.copy(ws.patb, work)
        change(folder)
        out = os.path.join(work, "imported")
        return ["import", "patb", os.path.join(folder, "block.im"), *PATB_SIZE, *extra, "--out", out], [folder], out
    return setup


def _opensfm(change):
    def setup(ws, work):
        folder = ws.copy(ws.opensfm, work)
        change(folder)
        out = os.path.join(work, "imported")
        return ["import", "opensfm", folder, "--out", out], [folder], out
    return setup


case("import patb IM --out NEW (works)", exit=0)(_patb(lambda f: None))
case("import opensfm DIR --out NEW (works)", exit=0)(_opensfm(lambda f: None))
case("patb: .im truncated", names="block.im")(_patb(lambda f: truncate(os.path.join(f, "block.im"), 0.5)))
case("patb: text in .con", names="block.con, line 2")(
    _patb(lambda f: _odm_token(os.path.join(f, "block.con"), 1, 2, b"12x")))
case("patb: .ori of a photo not in .im", names="block.ori, line 1")(
    _patb(lambda f: replace_bytes(os.path.join(f, "block.ori"), b"S1_01 ", b"S7_01 ")))
case("patb: Latin-1 byte in .im", names="block.im, line 1")(_patb(lambda f: prepend(os.path.join(f, "block.im"), b"\xe9")))
case("patb: --check of a point not in .con", names="--check")(_patb(lambda f: None, ("--check", "NOPE")))
case("patb: no --image-size", names="--image-size")(
    lambda ws, work: (["import", "patb", os.path.join(ws.patb, "block.im"), "--pixel-size-mm", "0.0059", "--out",
                       os.path.join(work, "out")], [ws.patb], os.path.join(work, "out")))
case("patb: --out IM_FOLDER", names="holds the input")(
    lambda ws, work: (["import", "patb", os.path.join(ws.patb, "block.im"), *PATB_SIZE, "--out", ws.patb], [ws.patb],
                      ws.patb))
case("opensfm: NaN in reconstruction.json", names="reconstruction.json")(
    _opensfm(lambda f: replace_bytes(os.path.join(f, "reconstruction.json"), b'"focal": ', b'"focal": NaN, "x": ')))
case("opensfm: tracks.csv truncated mid-line", names="tracks.csv")(
    _opensfm(lambda f: truncate(os.path.join(f, "tracks.csv"), 0.5)))
case("opensfm: no tracks.csv", names="tracks.csv")(_opensfm(lambda f: os.remove(os.path.join(f, "tracks.csv"))))
case("pix4d: not a params folder", names="params folder")(
    lambda ws, work: (["import", "pix4d", ws.patb, "--out", os.path.join(work, "out")], [ws.patb],
                      os.path.join(work, "out")))
case("metashape-markers without --block", names="--block")(
    lambda ws, work: (["import", "metashape-markers", os.path.join(ws.patb, "block.im"), "--out",
                       os.path.join(work, "out")], [ws.patb], os.path.join(work, "out")))
case("metashape-markers: not XML", names="block.im")(
    lambda ws, work: (["import", "metashape-markers", os.path.join(ws.patb, "block.im"), "--block", ws.block, "--out",
                       os.path.join(work, "out")], [ws.patb, ws.block], os.path.join(work, "out")))


def _patch(path, offset, data):
    with open(path, "r+b") as h:
        h.seek(offset)
        h.write(data)


def _bal_token(path, index, token):
    """Replace the index-th whitespace-separated token after the header (negative: from the end)."""
    with open(path, "rb") as h:
        data = h.read()
    import re
    spans = [m.span() for m in re.finditer(rb"\S+", data)][3:]
    a, b = spans[index]
    with open(path, "wb") as h:
        h.write(data[:a] + token + data[b:])


def _odm_token(path, line, field_, token):
    with open(path, "rb") as h:
        lines = h.read().split(b"\n")
    fields = lines[line].split()
    fields[field_] = token
    lines[line] = b" ".join(fields)
    with open(path, "wb") as h:
        h.write(b"\n".join(lines))


def _odm_cut(path, line):
    with open(path, "rb") as h:
        lines = h.read().split(b"\n")
    lines[line - 1] = b" ".join(lines[line - 1].split()[:3])
    with open(path, "wb") as h:
        h.write(b"\n".join(lines))


def _first_number_after(path, key, token):
    import re
    with open(path, "rb") as h:
        data = h.read()
    k = data.index(key)
    m = re.compile(rb"-?\d+\.?\d*(?:[eE][-+]?\d+)?").search(data, k + len(key))
    with open(path, "wb") as h:
        h.write(data[:m.start()] + token + data[m.end():])


# --- 1. Ctrl-C -------------------------------------------------------------------------------------------
class _Interrupt:
    """Monkey-patch ``module.name`` to raise KeyboardInterrupt (after calling through ``after`` times)."""

    def __init__(self, module, name, after=0):
        self.module, self.name, self.after = module, name, after

    def __enter__(self):
        self.original = getattr(self.module, self.name)
        calls = []

        def interrupted(*args, **kwargs):
            calls.append(1)
            if len(calls) > self.after:
                raise KeyboardInterrupt
            return self.original(*args, **kwargs)
        setattr(self.module, self.name, interrupted)

    def __exit__(self, *exc):
        setattr(self.module, self.name, self.original)


def _ctrl_c(module_name, attribute, after=0, existing=False):
    def setup(ws, work):
        import importlib
        out = _previous_results(ws, work) if existing else os.path.join(work, "res")
        module = importlib.import_module(module_name)
        argv = ["adjust", ws.block, "--out", out, "--no-report", "--quiet"]
        return _Patched(argv, _Interrupt(module, attribute, after)), [ws.block] + ([out] if existing else []), out
    return setup


class _Patched(list):
    """argv that runs under a patch (run_case enters it around the run)."""

    def __new__(cls, argv, patch):
        return super().__new__(cls, argv)

    def __init__(self, argv, patch):
        super().__init__(argv)
        self.patch = patch


case("Ctrl-C during the adjustment", exit=130)(_ctrl_c("selfcal.workflows.adjust", "adjust_with_tests"))
case("Ctrl-C while the results are written", exit=130)(_ctrl_c("selfcal.io.results", "atomic_write", after=3))
case("Ctrl-C while replacing earlier results", exit=130)(
    _ctrl_c("selfcal.io.results", "atomic_write", after=5, existing=True))
