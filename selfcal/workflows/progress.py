"""The progress lines of an adjustment, as text: the CLI prints them, and every one also goes to
``logging.getLogger("selfcal")`` at INFO, so a program that calls selfcal sees them in its own log."""
from __future__ import annotations

import logging

__all__ = ["LOG", "iteration_line", "round_line", "logging_progress", "logging_rounds"]

LOG = logging.getLogger("selfcal")


def iteration_line(record, image_sigma_px: float, prefix: str = "") -> str:
    """One iteration of the solver (a :class:`selfcal.adjust.solver` iteration record)."""
    status = "" if record.accepted else "  (step rejected, more damping)"
    return (f"{prefix}iteration {record.iteration:2d}: sigma0 {record.sigma0 * image_sigma_px:.4f} px, "
            f"largest correction {record.max_step_sigma:.3g} sigma{status}")


def round_line(record) -> str:
    """One round of data snooping and screening (a round that removed nothing: its adjustment, stopped at the
    rounds' tolerance, is taken on to the full one and tested again)."""
    control = getattr(record, "control_w", None)
    if control is not None:
        return (f"tests round {record.round}: a control point fails the test of the control group (|w| "
                f"{control:.1f}); checked instead of used as control, dropped {record.dropped_aps} APs; re-adjusting")
    if not record.rejected and not record.dropped_aps:
        return (f"tests round {record.round}: nothing to remove (largest |w| {record.largest_w:.1f}); converging "
                f"the adjustment to the full tolerance and testing it again")
    return (f"tests round {record.round}: rejected {record.rejected} observations (largest |w| "
            f"{record.largest_w:.1f}), dropped {record.dropped_aps} APs; re-adjusting")


def logging_progress(image_sigma_px: float):
    """A solver callback logging :func:`iteration_line` at INFO."""
    return lambda record: LOG.info(iteration_line(record, image_sigma_px))


def logging_rounds():
    """A tests callback logging :func:`round_line` at INFO."""
    return lambda record: LOG.info(round_line(record))
