"""Render the report of a results folder again (report.html, figures/), without adjusting."""
from __future__ import annotations

import argparse
import glob
import os
import time

from .outcome import finish, progress, steps


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", metavar="RESULTS", help="results folder written by selfcal adjust")


def run(args: argparse.Namespace) -> int:
    progress(f"reading {args.results} ...")     # at once: the report's import takes a second of its own
    from .. import interrupts
    with interrupts.deferred():                  # imported whole: a signal waits for it (report.render.load_matplotlib)
        from ..io.atomic import atomic_update
        from ..io.output import update_folder
        from ..io.results import read_results, write_files
        from ..report import render_report
    t0 = time.perf_counter()
    results = read_results(update_folder(args.results))
    progress(f"read {args.results} in {time.perf_counter() - t0:.1f} s")
    files = render_report(results, say=steps("rendering the report"))
    progress(f"writing {len(files)} files into {args.results} ...")
    # a copy of the folder gets the new report and replaces it: the figures and report.html appear together,
    # or (a full disk, an interrupt) the folder stays exactly as it was
    with atomic_update(args.results) as tmp:
        # figures of an earlier rendering that this one did not draw (e.g. fewer cameras) would mislead
        for path in glob.glob(os.path.join(tmp, "figures", "*")):
            if os.path.relpath(path, tmp).replace(os.sep, "/") not in files:
                os.unlink(path)
        write_files(tmp, files)
    n_figures = sum(name.endswith(".png") for name in files)
    report = os.path.join(args.results, "report.html")
    return finish(args, f"{report}: {n_figures} figures, rendered in {time.perf_counter() - t0:.1f} s",
                  {"n_figures": n_figures}, [os.path.abspath(report)])
