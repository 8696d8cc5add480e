"""The README and every example's README run as written (issue 45 item 5).

Every ```sh block of README.md and of examples/*/README.md runs here (each README.md block on its own), in a
fresh folder that looks like a clone beside ``../shared`` (the repository's files linked, the examples copied, so
nothing is written into the checkout), unless the line before it says otherwise:

* ``<!-- readme-test: long: REASON -->``: runs only with ``SELFCAL_README_LONG=1`` (``make examples``);
* ``<!-- readme-test: yours: REASON -->``: commands on the reader's own files; not run, but every ``selfcal``
  command in it must parse with the command's own argument parser (a renamed option fails here).

The numbers the READMEs quote are the runs': an example's README tables are copies of the Markdown tables its
script prints, and every row of a table whose header the run prints must be in the run's output verbatim; the
quick start's figures are asserted against the results folders it writes.
"""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), ".."))
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared"))
DOCUMENTS = ["README.md"] + sorted(os.path.join("examples", name, "README.md")
                                   for name in os.listdir(os.path.join(ROOT, "examples"))
                                   if os.path.isfile(os.path.join(ROOT, "examples", name, "README.md")))
MARK = re.compile(r"^<!-- readme-test: (long|yours): (.+) -->$")
LONG = os.environ.get("SELFCAL_README_LONG") == "1"


@dataclass
class ShellBlock:
    document: str       # path relative to the repository
    line: int           # of the opening fence, 1-based
    text: str
    kind: str           # "runs", "long" or "yours"
    reason: str

    @property
    def name(self) -> str:
        return f"{self.document}:{self.line}"


def shell_blocks(document: str) -> list[ShellBlock]:
    """The ```sh blocks of ``document``, each with the marker of the line before its fence."""
    with open(os.path.join(ROOT, document), encoding="utf-8") as handle:
        lines = handle.read().splitlines()
    blocks, k = [], 0
    while k < len(lines):
        if lines[k].strip() == "```sh":
            end = next(j for j in range(k + 1, len(lines)) if lines[j].strip() == "```")
            before = next((lines[j].strip() for j in range(k - 1, -1, -1) if lines[j].strip()), "")
            mark = MARK.match(before)
            blocks.append(ShellBlock(document, k + 1, "\n".join(lines[k + 1:end]),
                                     mark.group(1) if mark else "runs", mark.group(2) if mark else ""))
            k = end
        k += 1
    return blocks


BLOCKS = [block for document in DOCUMENTS for block in shell_blocks(document)]


def _runs_of(document: str) -> list[ShellBlock]:
    return [b for b in BLOCKS if b.document == document and (b.kind == "runs" or b.kind == "long" and LONG)]


def selfcal_commands(text: str) -> list[list[str]]:
    """Every ``selfcal ...`` command of a shell block as its argument list (comments and continuations removed)."""
    joined = re.sub(r"\\\n", " ", text)
    commands = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if words and words[0] == "selfcal":
            commands.append(words[1:])
    return commands


def test_every_shell_block_runs_or_says_why():
    assert len(BLOCKS) >= 12, [b.name for b in BLOCKS]
    for block in BLOCKS:
        assert block.kind == "runs" or len(block.reason) > 10, f"{block.name}: a marker needs its reason"
    # the quick start and every example run in `make test`; only the long runs wait for `make examples`
    running = {b.document for b in BLOCKS if b.kind == "runs"}
    assert {"README.md", "examples/apollo15/README.md", "examples/lro_nac/README.md",
            "examples/ventoux/README.md"} <= running, running
    assert [b.kind for b in BLOCKS if b.document == "examples/copr/README.md"] == ["long"]


@pytest.mark.parametrize("block", BLOCKS, ids=[b.name for b in BLOCKS])
def test_every_selfcal_command_parses(block):
    """The argument parser of each command accepts it as written (its verb, its options, their values)."""
    from selfcal.cli.main import build_parser
    for argv in selfcal_commands(block.text):
        try:
            build_parser(argv).parse_args(argv)
        except SystemExit as exc:           # argparse's exit: an unknown verb or option, a bad value
            if exc.code != 0:
                pytest.fail(f"{block.name}: selfcal {' '.join(argv)}: the parser refuses it")


def test_every_example_script_honours_data_selfcal_and_python():
    for name in sorted(os.listdir(os.path.join(ROOT, "examples"))):
        script = os.path.join(ROOT, "examples", name, "run.sh")
        if not os.path.isfile(script):
            continue
        with open(script, encoding="utf-8") as handle:
            text = handle.read()
        for variable in ("DATA", "SELFCAL", "PYTHON"):
            assert re.search(r"\$\{" + variable + r":-", text), f"{script}: {variable} is not honoured"
        assert "rm -rf \"$out\"" not in text and "rm -rf \"$OUT\"" not in text, f"{script} removes its OUT"


# ------------------------------------------------------------------------------------------------ the runs

def _clone(top, shared: bool):
    """``top``/selfcal laid out as a clone: the repository's files linked (the .venv included), examples/ copied
    without earlier results; beside it ``shared`` (linked to ../shared) if ``shared``."""
    repo = top / "selfcal"
    repo.mkdir()
    for name in os.listdir(ROOT):
        if name in ("examples", ".git", "pyproject.toml") or name.endswith("-results"):
            continue
        os.symlink(os.path.join(ROOT, name), repo / name)
    # pyproject.toml copied, no newer than the .venv's install stamp: the README's `make install` in the clone finds
    # the linked .venv installed and leaves it alone (a reinstall from here would point the developer's editable
    # install and console scripts at this temporary folder; it did, from a worktree sharing the .venv)
    shutil.copy2(os.path.join(ROOT, "pyproject.toml"), repo / "pyproject.toml")
    stamp = os.path.join(ROOT, ".venv", ".installed-stamp")
    if os.path.exists(stamp):
        mtime = min(os.path.getmtime(stamp), os.path.getmtime(repo / "pyproject.toml"))
        os.utime(repo / "pyproject.toml", (mtime, mtime))
    shutil.copytree(os.path.join(ROOT, "examples"), repo / "examples",
                    ignore=shutil.ignore_patterns("results", "__pycache__"))
    if shared:
        os.symlink(SHARED, top / "shared")
    return repo


@pytest.fixture(scope="module")
def bare_clone(tmp_path_factory):
    """A clone with no ../shared beside it: an example finds its data only through DATA."""
    return _clone(tmp_path_factory.mktemp("examples"), shared=False)


def _run(block: ShellBlock, cwd, env_extra: dict | None = None) -> str:
    """The block in bash -e from ``cwd`` with the .venv first on PATH; its stdout (stderr in the failure)."""
    env = dict(os.environ, PATH=os.path.join(ROOT, ".venv", "bin") + os.pathsep + os.environ.get("PATH", ""),
               **(env_extra or {}))
    env.pop("VIRTUAL_ENV", None)
    script = ("set -euo pipefail\n"
              "xdg-open() { test -s \"$1\"; }       # no desktop here: the file must exist and not be empty\n"
              + block.text + "\n")
    proc = subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, f"{block.name} exited {proc.returncode}:\n{proc.stderr[-4000:]}"
    return proc.stdout


def _tables(document: str) -> list[list[str]]:
    """The Markdown tables of ``document``: lists of their lines (header, rule, rows)."""
    with open(os.path.join(ROOT, document), encoding="utf-8") as handle:
        lines = handle.read().splitlines()
    tables, current = [], []
    for line in lines + [""]:
        if line.startswith("|"):
            current.append(line.rstrip())
        elif current:
            tables.append(current)
            current = []
    return tables


def _rows_printed(document: str, out: str) -> int:
    """Every row of each table of ``document`` whose header ``out`` prints is in ``out``; the rows checked."""
    printed = {line.rstrip() for line in out.splitlines()}
    checked = 0
    for table in _tables(document):
        if table[0] not in printed:
            continue
        missing = [row for row in table[2:] if row not in printed]
        assert not missing, f"{document}: rows the run does not print:\n" + "\n".join(missing)
        checked += len(table) - 2
    return checked


#: README.md's blocks that run in ``make test``, each a test of its own (the two cores share them out)
README_RUNS = _runs_of("README.md")


def test_the_readme_has_blocks_that_run():
    assert len(README_RUNS) >= 3
    assert any("sim/type1" in b.text for b in README_RUNS), "the quick start adjusts the Type 1 block"


@pytest.mark.slow
@pytest.mark.parametrize("block", README_RUNS, ids=[b.name for b in README_RUNS])
def test_readme_block_runs_as_written(block, tmp_path):
    """A README.md block in a clone of its own (no block uses what another wrote); the quick start's figures."""
    import json
    clone = _clone(tmp_path, shared=True)
    _run(block, clone)
    if "sim/type1" not in block.text:
        return
    with open(clone / "res1" / "summary.json", encoding="utf-8") as handle:
        type1 = json.load(handle)
    counts = re.search(r"sparse control: (\d+) GCP / (\d+) CHK", block.text)
    assert counts, "the quick start names the Type 1 block's control"
    assert (type1["n_gcp_used"], type1["n_chk_used"]) == (int(counts.group(1)), int(counts.group(2)))
    assert os.path.getsize(clone / "res1" / "report.html") > 10_000


#: the examples whose README's blocks run here (the long ones with SELFCAL_README_LONG=1)
EXAMPLES = [d.split(os.sep)[1] for d in DOCUMENTS[1:] if _runs_of(d)]


@pytest.mark.slow
@pytest.mark.parametrize("example", EXAMPLES)
def test_example_runs_as_written_and_prints_its_readme_tables(bare_clone, example, tmp_path):
    """The example's blocks with DATA, SELFCAL and PYTHON set (no ../shared beside the clone: DATA must be
    honoured); every row of its README's tables that the run prints comes out of the run."""
    document = os.path.join("examples", example, "README.md")
    blocks = _runs_of(document)
    data = {"apollo15": "isis/apollo15_metric", "lro_nac": "isis/lro_nac_pair",
            "ventoux": "pushbroom/pleiades/phr_ventoux", "copr": "copr"}[example]
    link = tmp_path / "data"                 # DATA honoured: the scripts read the data through this link only
    os.symlink(os.path.join(SHARED, "data", data), link)
    env = {"DATA": str(link), "SELFCAL": os.path.join(ROOT, ".venv", "bin", "selfcal"),
           "PYTHON": os.path.join(ROOT, ".venv", "bin", "python")}
    out = "".join(_run(block, bare_clone, env) for block in blocks)
    assert _rows_printed(document, out) >= 3, f"{document}: no table of the README is printed by its run"
