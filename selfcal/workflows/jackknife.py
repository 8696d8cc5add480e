"""The jackknife of the calibration over groups of images (issue 44 item 5; ``selfcal adjust --jackknife G``).

The tested adjustment's block as it ended (its rejections made, its AP set as the screening left it, the AP basis
and where it is evaluated kept) is split into G groups of consecutive images (images.csv order: a flight's strips,
a close-range block's sequence; G at most the number of images). Each group is left out in turn and the rest
adjusted again from the converged estimate with the caller's options (no robust loss, no snooping, no screening:
:meth:`selfcal.adjust.AdjustmentResult.readjust`). The cameras' estimated parameters of the G replicates go to
:func:`selfcal.stats.calibration_precision.jackknife_spread`. A group whose removal leaves the block undetermined
(an image that alone ties two parts, the control of a small block) is skipped and named; fewer than three
replicates leave the check undone, with the reason.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions
from ..errors import AdjustmentError
from ..stats.calibration_precision import (JACKKNIFE_ALPHA, NAMED_INFLATION, CameraPrecision,
                                           camera_precision, critical_ratio, jackknife_spread,
                                           precision_statement)
from .tested import TestedAdjustment

__all__ = ["Jackknife", "image_groups", "jackknife", "precision_summary", "calibration_precision",
           "half_block_findings", "MIN_REPLICATES"]

#: a jackknife needs at least this many replicates
MIN_REPLICATES = 3


@dataclass
class Jackknife:
    groups: int
    done: bool
    reason: str = ""
    #: camera id -> parameter name -> its estimate in each replicate (the unit of CameraPrecision's values)
    replicates: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)       # the groups whose replicate failed, and why
    seconds: float = 0.0

    @property
    def n_replicates(self) -> int:
        return next((len(v) for cam in self.replicates.values() for v in cam.values()), 0)


def image_groups(n_images: int, groups: int) -> list[np.ndarray]:
    """G groups of consecutive image indices, sizes within one of each other (G at most ``n_images``)."""
    return [g for g in np.array_split(np.arange(n_images), min(int(groups), n_images)) if g.size]


def _values(result, camera_id: str, names: list[str]) -> dict[str, float]:
    """A replicate's estimates of the camera's parameters ``names`` in CameraPrecision's units (NaN where not
    estimated)."""
    for cam in camera_precision(result):
        if cam.camera_id == camera_id:
            by_name = cam.by_name()
            return {name: by_name[name].value if name in by_name else np.nan for name in names}
    return {name: np.nan for name in names}


def jackknife(tested: TestedAdjustment, options: AdjustOptions, groups: int,
              precision: list[CameraPrecision] | None = None,
              say: Callable[[str], None] | None = None) -> Jackknife:
    """The replicates of every camera's estimated parameters, each group of images left out in turn (module
    docstring). ``say`` receives a line as the re-adjustments begin and one at most every second after."""
    t0 = time.perf_counter()
    said = t0
    result = tested.result
    block = result.block
    precision = camera_precision(result) if precision is None else precision
    parts = image_groups(len(block.images), groups)
    out = Jackknife(len(parts), False)
    if len(parts) < MIN_REPLICATES:
        out.reason = f"{len(block.images)} image(s): a jackknife needs {MIN_REPLICATES} groups or more"
        return out
    names = {cam.camera_id: [p.name for p in cam.parameters] for cam in precision}
    rows: dict[str, dict[str, list[float]]] = {cid: {n: [] for n in ns} for cid, ns in names.items()}
    obs = block.observations
    if say is not None:
        say(f"jackknife of the calibration: the block re-adjusted without each of {len(parts)} groups of images")
    for k, part in enumerate(parts):
        if say is not None and k and time.perf_counter() - said >= 1.0:
            said = time.perf_counter()
            say(f"jackknife of the calibration: {k}/{len(parts)} done")
        label = ", ".join(str(block.images.image_id[i]) for i in part[:3]) + (", ..." if part.size > 3 else "")
        try:
            replicate = result.readjust(options, without_rows=obs.row[np.isin(obs.image_index, part)])
        except AdjustmentError as exc:
            out.skipped.append(f"images {label}: {str(exc).splitlines()[0]}")
            continue
        if not replicate.converged:
            out.skipped.append(f"images {label}: {replicate.reason}")
            continue
        for cid, ns in names.items():
            for name, value in _values(replicate, cid, ns).items():
                rows[cid][name].append(value)
    out.replicates = {cid: {n: np.asarray(v, float) for n, v in by.items()} for cid, by in rows.items()}
    out.seconds = time.perf_counter() - t0
    if out.n_replicates < MIN_REPLICATES:
        out.reason = (f"{out.n_replicates} of {len(parts)} replicates converged; {MIN_REPLICATES} are needed"
                      + (f" ({out.skipped[0]})" if out.skipped else ""))
        return out
    out.done = True
    return out


def precision_summary(precision: list[CameraPrecision], jack: Jackknife | None, findings: list[str] | None = None
                      ) -> dict:
    """summary.json ``calibration_precision``: the verdict, its sentence, the jackknife's settings and every
    camera's parameters (:mod:`selfcal.stats.calibration_precision`); fills ``precision``'s jackknife fields.
    ``findings``: other checks' model errors (the half-block check's), which make the verdict "not trusted"."""
    done = jack is not None and jack.done
    if done:
        assert jack is not None
        for cam in precision:
            jackknife_spread(cam, jack.replicates.get(cam.camera_id, {}))
    trusted, statement = precision_statement(precision, done, findings or ())
    return {
        "trusted": trusted,
        "statement": statement,
        "jackknife": None if jack is None else {
            "groups": jack.groups, "done": jack.done, "reason": jack.reason, "n_replicates": jack.n_replicates,
            "skipped": jack.skipped, "alpha": JACKKNIFE_ALPHA,
            "critical_ratio": critical_ratio(jack.n_replicates) if jack.n_replicates >= MIN_REPLICATES else None,
            "seconds": jack.seconds},
        "cameras": {cam.camera_id: [p.as_dict() for p in cam.parameters] for cam in precision},
    }


def half_block_findings(check) -> list[str]:
    """The half-block check's (:mod:`.half_block`) flagged cameras as sentences for the verdict."""
    if check is None:
        return []
    return [f"the half-block check finds camera {c.camera_id}'s APs differ between the halves of the block "
            f"(T = {c.difference.statistic:.1f}, chi2({c.difference.dof}), p = {c.difference.p_value:.2g})"
            for c in check.cameras if c.difference.flag]


def calibration_precision(tested: TestedAdjustment, options: AdjustOptions, groups: int,
                          say: Callable[[str], None] | None = None) -> tuple[dict | None, str]:
    """summary.json ``calibration_precision`` of a tested adjustment (None where no camera parameter is
    estimated), and the note it makes: the statement where the verdict is "not trusted", or "not verified" with a
    weakly determined core parameter named, else empty. ``groups``: the jackknife's groups (0: none); the
    half-block check's flags (``tested.half_block``, where it was made) count as model errors."""
    precision = camera_precision(tested.result)
    if not precision:
        return None, ""
    jack = jackknife(tested, options, groups, precision, say) if groups else None
    summary = precision_summary(precision, jack, half_block_findings(getattr(tested, "half_block", None)))
    weak = any(p.core and (p.ap_inflation or 0.0) >= NAMED_INFLATION for cam in precision for p in cam.parameters)
    said = summary["trusted"] is False or (summary["trusted"] is None and weak)
    return summary, (summary["statement"] if said else "")
