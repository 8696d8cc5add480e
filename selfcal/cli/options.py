"""Options shared by several verbs, so that a flag means the same everywhere."""
from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING, Any, Callable

from ..adjust import LOSSES, RobustOptions
from ..workflows.progress import LOG, iteration_line, round_line
from .outcome import progress

if TYPE_CHECKING:
    from ..stats import ScreeningOptions

__all__ = ["grid", "ap_option", "grid_option", "progress_printer", "test_options", "round_printer",
           "trajectory_options", "drift_order", "screening_options", "robust_options", "number", "count", "ap_spec",
           "ap_list", "force_option"]


def _range_text(low, high, low_open, high_open) -> str:
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    if low is not None:
        return f"{'>' if low_open else '>='} {low:g}"
    return f"{'<' if high_open else '<='} {high:g}"


def number(low: float | None = None, high: float | None = None, low_open: bool = False,
           high_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number within [low, high] (open ends as asked); NaN and infinity are refused."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, found '{text}'")
        if ((low is not None and (value < low or (low_open and value == low)))
                or (high is not None and (value > high or (high_open and value == high)))):
            raise argparse.ArgumentTypeError(f"must be {_range_text(low, high, low_open, high_open)}, found {text}")
        return value
    return parse


def count(low: int = 0, high: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer within [low, high]."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be an integer {_range_text(low, high, False, False)}, "
                                             f"found {text}")
        return value
    return parse


def ap_spec(text: str) -> str:
    """An argparse type: an AP model that exists with its option (``legendre:3``, ``wavelet:db4``), or ``auto``
    / ``auto:MODEL,...`` (checked when the candidates are built)."""
    from ..ap import check_ap_spec
    if text == "auto" or text.startswith("auto:"):
        return text
    try:
        return check_ap_spec(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def ap_list(text: str) -> str:
    """An argparse type: AP models separated by commas, each checked as :func:`ap_spec`."""
    models = [m.strip() for m in text.split(",") if m.strip()]
    if not models:
        raise argparse.ArgumentTypeError("name at least one AP model")
    for model in models:
        ap_spec(model)
    return ",".join(models)


def force_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--force", action="store_true",
                        help="replace --out even when it is an existing folder that selfcal did not write "
                             "(a folder selfcal wrote holds a .selfcal-output file and is replaced without it)")


def grid(text: str) -> tuple[int, int]:
    """Parse ``GxXGy`` (e.g. ``9x6``), or one number N: N x N over a frame, N cells along a pushbroom line."""
    try:
        parts = [int(v) for v in text.lower().split("x")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2):
        raise argparse.ArgumentTypeError(f"grid must look like 9x6, found '{text}'")
    gx, gy = parts if len(parts) == 2 else (parts[0], parts[0])
    if max(gx, gy) > 1000:
        raise argparse.ArgumentTypeError(f"grid sizes of at most 1000 cells, found '{text}'")
    if gx < 1 or gy < 1:
        raise argparse.ArgumentTypeError(f"grid sizes must be positive, found '{text}'")
    return gx, gy


def ap_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ap", default=None, metavar="MODEL", type=ap_spec,
                        help="additional-parameter model: none, brown, ebner, gruen, legendre[:deg], "
                             "fourier[:order], wavelet:db4 | sym4 | meyer | bl4; auto[:MODEL@GxXGy,...] chooses by the "
                             "cross-validated prediction error of held-out tie points (the simplest model within one "
                             "standard error of the best; auto alone: the ten families, the wavelets on grids 3x2 ... "
                             "15x10, short-listed by BIC); pushbroom blocks: wavelet1d:db4 | sym4 | meyer | bl4 along "
                             "the detector line. Default: for frame cameras whose calibration is not held, "
                             "auto:none,brown (Brown's only where it predicts the held-out observations better than "
                             "no APs by more than a standard error); otherwise none")


def ap_at_option(parser: argparse.ArgumentParser) -> None:
    from ..adjust.options import AP_POSITIONS
    parser.add_argument("--ap-at", choices=AP_POSITIONS, default=AP_POSITIONS[0],
                        help="where a frame camera's AP correction of an observation is evaluated: at its adjusted "
                             "image coordinates (default: converged with the measured ones first) or at the measured "
                             "ones throughout (seed 000's Eq. (1) read literally: an errors-in-variables estimate, "
                             "biased where the APs trade with c, x0, y0)")


def grid_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--grid", type=grid, default=(9, 6), metavar="GxXGy",
                        help="grid of the wavelet APs over the frame (default: 9x6); for wavelet1d on a pushbroom "
                             "block, one number: cells along the detector line")


def progress_printer(image_sigma_px: float, prefix: str = "") -> Callable[[Any], None]:
    """A callback printing one line per iteration to stderr (and logging it: selfcal.workflows.progress)."""
    def show(record) -> None:
        line = iteration_line(record, image_sigma_px, prefix)
        LOG.info(line)
        progress(line)
    return show


def test_options(parser: argparse.ArgumentParser) -> None:
    """Data snooping and AP screening (selfcal.stats)."""
    parser.add_argument("--snoop", type=number(0.0), default=3.0, metavar="K",
                        help="Baarda data snooping: reject image observations with |w| > K (default 3.0, "
                             "as in seed 000; 0 disables)")
    parser.add_argument("--snoop-mode", choices=["batch", "single"], default="batch",
                        help="batch: per round the worst observation of every point above K (default); "
                             "single: one observation per round")
    parser.add_argument("--screen", action="store_true",
                        help="screen the APs: drop insignificant and highly correlated coefficients")
    parser.add_argument("--significance", type=number(0.0, low_open=True), default=1.96, metavar="T",
                        help="screening: drop an AP with |a|/sigma < T (default 1.96)")
    parser.add_argument("--max-correlation", type=number(0.0, 1.0, low_open=True), default=0.9, metavar="R",
                        help="screening: drop the less significant AP of a pair with |rho| > R (default 0.9)")
    parser.add_argument("--joint-alpha", type=number(0.0, 1.0, high_open=True), default=0.05, metavar="A",
                        help="screening: the APs dropped in a round must pass their joint F-test at level A "
                             "(default 0.05; 0 switches the guard off); with GNSS/IMU per group (APs, GNSS, "
                             "IMU, each sensor's strip)")
    parser.add_argument("--trajectory-significance", type=number(0.0), default=None, metavar="T",
                        help="screening: drop a GNSS/IMU shift/drift term only with t < T before the screening "
                             "and at the drop (default 1.355 = 3 - z(0.95): shown smaller than 3 sigma)")
    parser.add_argument("--min-effect-px", type=number(0.0), default=0.1, metavar="PX",
                        help="screening: an AP coefficient or a rolling shutter's readout stays only if holding "
                             "it (at 0) moves some adjusted image coordinate over the observed area by PX or more "
                             "(default 0.1; 0: no test); --ap auto: a richer model must predict better than a "
                             "simpler one by more than a field of PX")
    parser.add_argument("--min-support", type=count(0), default=20, metavar="N",
                        help="screening: a coefficient of a local basis (a WAP) stays only if N observations or "
                             "more lie in its support (default 20)")
    parser.add_argument("--max-iop-move", type=number(0.0), default=0.1, metavar="S",
                        help="screening: stop before a drop that would move a camera's c, x0 or y0 by more than S of "
                             "its sigma (default 0.1; 0: no guard): where a few control points hold the heights, c "
                             "carries them")
    parser.add_argument("--no-screen-cv", action="store_true",
                        help="screening: do not cross-validate (by default it stops where the screened set would "
                             "predict held-out tie points worse than the unscreened one)")
    parser.add_argument("--robust", choices=["none", *LOSSES], default=RobustOptions.loss, metavar="LOSS",
                        help=f"robust cleaning before the tests: {', '.join(LOSSES)} (default {RobustOptions.loss}: "
                             "gross errors of matcher output rejected first), or none (least squares throughout)")
    parser.add_argument("--robust-reject", type=number(0.0, low_open=True), default=RobustOptions.reject, metavar="U",
                        help=f"robust cleaning: reject image points more than U robust sigmas off (default "
                             f"{RobustOptions.reject:g}); the rest face data snooping")
    parser.add_argument("--variance-components", action="store_true",
                        help="estimate a variance factor per observation group (image, GCP, GNSS, IMU) and "
                             "report the a-posteriori sigmas next to the a-priori ones")


def robust_options(args: argparse.Namespace) -> RobustOptions | None:
    """RobustOptions from the command line, or None for ``--robust none``."""
    return None if args.robust == "none" else RobustOptions(loss=args.robust, reject=args.robust_reject)


def screening_options(args: argparse.Namespace) -> ScreeningOptions:
    """ScreeningOptions from the command line (the thresholds apply wherever screening is on)."""
    from ..stats import ScreeningOptions
    extra = {} if args.trajectory_significance is None else {"trajectory_significance": args.trajectory_significance}
    return ScreeningOptions(args.significance, args.max_correlation,
                            joint_alpha=args.joint_alpha if args.joint_alpha > 0 else None,
                            min_effect_px=args.min_effect_px, min_support=args.min_support,
                            cross_validate=not args.no_screen_cv, max_iop_move_sigma=args.max_iop_move, **extra)


def round_printer() -> Callable[[Any], None]:
    """A callback printing one line per snooping/screening round to stderr (and logging it)."""
    def show(record) -> None:
        line = round_line(record)
        LOG.info(line)
        progress(line)
    return show


def drift_order(text: str) -> int:
    try:
        value = -1 if text.lower() == "none" else int(text)
    except ValueError:
        value = None
    if value not in (-1, 0, 1, 2):
        raise argparse.ArgumentTypeError(f"drift order must be none, 0, 1 or 2, found '{text}'")
    return value


def trajectory_options(parser: argparse.ArgumentParser) -> None:
    """Strip-wise shift/drift of the trajectory observations (Eq. 12 of seed 000)."""
    parser.add_argument("--gnss-drift", type=drift_order, default=1, metavar="N",
                        help="GNSS positions: none, 0 (shift), 1 (shift + drift, default), 2 (+ quadratic)")
    parser.add_argument("--imu-drift", type=drift_order, default=1, metavar="N",
                        help="IMU attitudes: none, 0 (shift), 1 (shift + drift, default), 2 (+ quadratic)")
    parser.add_argument("--lever-arm", action="store_true",
                        help="estimate the GNSS antenna's lever arm (camera frame; start: [gnss] lever_arm_m or 0); "
                             "needs --gnss-drift none")
    parser.add_argument("--boresight", action="store_true",
                        help="estimate the IMU boresight angles (start: [imu] boresight_deg or 0); needs --imu-drift none")
