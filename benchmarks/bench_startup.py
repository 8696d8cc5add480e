"""Start-up of the command line: ``selfcal --help``, ``--version`` and every verb's ``--help``.

Each command runs as a new process (the console script, as a user types it), ``--repeat`` times, interleaved with
the peer measured in the same run: the interpreter's own start with the same site packages (``python -c pass``),
which no command can beat. Prints the median and the slowest run of each, and the ratio to the interpreter's start.
The issue's bars (45, item 1): ``selfcal --help`` median at most 0.5 s, ``selfcal adjust --help`` at most 1 s.

Run: ``python benchmarks/bench_startup.py [--repeat 7]``.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time

#: the commands measured: every verb's --help, and the formats of import and export that load the most
COMMANDS = [
    ["--help"], ["--version"],
    ["adjust", "--help"], ["simulate", "--help"], ["compare", "--help"], ["report", "--help"],
    ["import", "--help"], ["import", "colmap", "--help"], ["import", "isis", "--help"],
    ["export", "--help"], ["export", "opencv", "--help"], ["export", "colmap-workspace", "--help"],
    ["undistort", "--help"], ["demo", "--help"],
]
BARS_S = {("--help",): 0.5, ("adjust", "--help"): 1.0}


def _selfcal() -> list[str]:
    script = os.path.join(os.path.dirname(sys.executable), "selfcal")
    return [script] if os.path.exists(script) else [shutil.which("selfcal") or "selfcal"]


def _seconds(command: list[str]) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)}: exit {done.returncode}: {done.stderr.strip()[-300:]}")
    return elapsed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    selfcal = _selfcal()
    peer = [sys.executable, "-c", "pass"]
    times: dict[tuple[str, ...], list[float]] = {tuple(c): [] for c in COMMANDS}
    interpreter: list[float] = []
    _seconds(selfcal + ["--help"])                     # the page cache warm, as for a user's second command
    for _ in range(args.repeat):                       # interleaved: the machine's load falls on every command alike
        interpreter.append(_seconds(peer))
        for command in COMMANDS:
            times[tuple(command)].append(_seconds(selfcal + command))
    base = statistics.median(interpreter)
    print(f"{'command':<42} {'median s':>9} {'max s':>7} {'/ python':>9}  bar")
    print(f"{'python -c pass (the peer)':<42} {base:9.3f} {max(interpreter):7.3f} {1.0:9.1f}")
    failed = []
    for command, runs in times.items():
        median = statistics.median(runs)
        bar = BARS_S.get(command)
        verdict = "" if bar is None else f"<= {bar:g} s {'ok' if median <= bar else 'MISSED'}"
        if bar is not None and median > bar:
            failed.append(" ".join(command))
        print(f"{'selfcal ' + ' '.join(command):<42} {median:9.3f} {max(runs):7.3f} {median / base:9.1f}  {verdict}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
