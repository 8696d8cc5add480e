"""Options shared by several verbs, so that a flag means the same everywhere."""
from __future__ import annotations

import argparse
import sys

__all__ = ["grid", "ap_option", "grid_option", "progress_printer"]


def grid(text: str) -> tuple[int, int]:
    """Parse ``GxXGy`` (e.g. ``9x6``)."""
    try:
        gx, gy = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"grid must look like 9x6, found '{text}'") from None
    if gx < 1 or gy < 1:
        raise argparse.ArgumentTypeError(f"grid sizes must be positive, found '{text}'")
    return gx, gy


def ap_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ap", default="none", metavar="MODEL",
                        help="additional-parameter model: none, brown, ebner, gruen, legendre[:deg], "
                             "fourier[:order], wavelet:db4 | sym4 | meyer | bl4 (default: none)")


def grid_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--grid", type=grid, default=(9, 6), metavar="GxXGy",
                        help="grid of the wavelet APs over the frame (default: 9x6)")


def progress_printer(prefix: str = ""):
    """A callback printing one line per iteration to stderr."""
    def show(record) -> None:
        status = "" if record.accepted else "  (step rejected, more damping)"
        print(f"{prefix}iteration {record.iteration:2d}: sigma0 {record.sigma0:.4f}, "
              f"largest correction {record.max_step_sigma:.3g} sigma{status}", file=sys.stderr, flush=True)
    return show
