"""The attitude jitter of line images chosen by the data (``--jitter auto`` and ``--jitter wavelet1d:NAME``; issue 42).

The jitter basis (:mod:`selfcal.sensors.pushbroom.jitter`) has a level and its coefficients an a-priori sigma per
attitude axis. Both are chosen here, before the tested adjustment runs with them:

* **The power of the jitter, per axis, by variance components.** The coefficients are observed to be 0 with sigma
  s_a (the axis's jitter power); after each adjustment the group of those prior observations has the variance
  factor Omega_a / r_a (Förstner 1979), Omega_a = sum (x_k / s_a)^2 over its coefficients and r_a = sum (1 - Q_kk /
  s_a^2) its redundancy (Q the cofactors of the unknowns), relative to the image observations' factor; s_a is scaled
  by its root until every factor is within :data:`VCE_TOLERANCE` of 1. The data thus set the weight that ASP's
  jitter_solve asks its user for (its smoothness weights), and a combination of the images' jitter that the tie points
  cannot see (the ground under all three images moving alike; the heights between fore and aft views) stays near 0
  with the sigma of that prior, not wherever the noise pushes it.
* **Practical significance.** An axis whose estimated power moves an image point by less than
  :data:`MIN_EFFECT_PX` (s_a times the RMS over the observations of how far a unit turn about the axis moves them)
  has no jitter: its coefficients are
  held, as a parameter is held that moves no ray by 0.1 px (issue 44); with no axis left, the images keep their
  polynomial alone (bias and drift: the results of ``--jitter none``).
* **The level, by the fit.** With ``auto`` or ``wavelet1d:NAME`` the levels from :data:`FIRST_LEVEL` up are tried in
  turn; the search stops at the first level whose image observations' weighted residual sum falls by less than
  :data:`LEVEL_GAIN` against the level below, or where a level would have fewer than :data:`OBSERVATIONS_PER_TERM`
  observations of an image per function. The level below it is chosen.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..adjust import AdjustOptions, adjust
from ..sensors.pushbroom.jitter import JITTER_LEVELS, parse_jitter, time_basis

__all__ = ["JitterChoice", "choose_jitter", "estimate_jitter_power", "FIRST_LEVEL", "LEVEL_GAIN", "MIN_EFFECT_PX",
           "VCE_TOLERANCE", "START_SIGMA_RAD", "OBSERVATIONS_PER_TERM"]

#: the first level the search tries (8 cells over an image)
FIRST_LEVEL = 3
#: a level is worth its functions when the image observations' weighted residual sum falls by this share
LEVEL_GAIN = 0.02
#: an axis whose jitter moves an image point by less than this (RMS, px) has none
MIN_EFFECT_PX = 0.1
#: the variance factors of the jitter priors are 1 within this
VCE_TOLERANCE = 0.02
VCE_ITERATIONS = 12
#: over-relaxation of the sigmas' update: sigma * factor^(relaxation / 2) (1: Förstner's plain update, whose steps
#: shrink slowly where an axis trades with another, a yaw with the roll of a tilted view)
VCE_RELAXATION = 2.0
#: the a-priori sigma the estimation starts from (rad)
START_SIGMA_RAD = 1.0e-5
#: a level needs this many observations of an image per function of one axis
OBSERVATIONS_PER_TERM = 6


@dataclass(frozen=True)
class JitterChoice:
    """What the data chose: the spec (``wavelet1d:NAME:LEVEL``, or ``none``), the sigma per axis (rad; None without
    jitter), the levels tried with their image observations' weighted residual sums, and the final adjustment."""

    spec: str
    sigma_rad: tuple[float, ...] | None
    axes: tuple[str, ...]
    tried: tuple[tuple[int, float], ...]
    result: object

    def options(self, options: AdjustOptions) -> AdjustOptions:
        """``options`` with this choice."""
        sensor = replace(options.sensor, jitter=self.spec, jitter_sigma_rad=self.sigma_rad,
                         jitter_axes=self.axes or None)
        return replace(options, sensor=sensor)

    def as_dict(self) -> dict:
        return {"jitter": self.spec, "sigma_urad": None if self.sigma_rad is None else
                [round(s * 1e6, 6) for s in self.sigma_rad], "axes": list(self.axes),
                "levels_tried": [{"level": level, "image_residual_sum": round(omega, 3)} for level, omega in self.tried]}


def _jitter_slot(result):
    from ..errors import UsageError
    for slot in result.problem.sensors:
        if getattr(slot.bound, "jitter", None) is not None:
            return slot
    raise UsageError("--jitter: the block has no line images (pushbroom, usgscsm-line, dimap, dg) to correct")


def _image_omega(result) -> float:
    """The weighted residual sum of the image observations."""
    problem = result.problem
    w = result.residuals[problem.obs_order] / problem.obs_sigma
    return float(np.sum(w * w))


def _pixels_per_rad(result) -> np.ndarray:
    """(3,): the RMS over the jitter's image observations of how far a unit increment of each attitude axis moves
    them, pixels per radian (a yaw moves the line's ends only)."""
    slot = _jitter_slot(result)
    bound, problem, state = slot.bound, result.problem, result.state
    o = slot.observations
    img = problem.obs_image[o]
    _, j_e, _, _ = bound.predict(bound.context(state), o, img, problem.image_camera[img],
                                 state.points[problem.obs_point[o]], True)
    j_axes = j_e[:, :, list(bound.attitude_constant_columns)] / np.abs(bound.scale[o])[:, :, None]
    return np.sqrt(np.mean(np.sum(j_axes ** 2, axis=1), axis=0))


def estimate_jitter_power(block, options: AdjustOptions, progress: Callable | None = None, start=None,
                          say: Callable[[str], None] | None = None):
    """Adjust ``block`` with ``options``' jitter (a level given) and estimate its sigma per axis (module docstring).
    Returns (the last adjustment, the sigma per axis in rad, the axes kept)."""
    axes_names = None
    sigma = np.asarray(np.broadcast_to(options.sensor.jitter_sigma_rad or START_SIGMA_RAD, 3), float).copy()
    held = np.zeros(3, bool)
    result = start
    for _ in range(VCE_ITERATIONS):
        kept = tuple(a for a, h in zip(axes_names or ("", "", ""), held) if not h) if axes_names else None
        run = replace(options, sensor=replace(options.sensor, jitter_sigma_rad=tuple(sigma), jitter_axes=kept))
        result = adjust(block, run, progress=progress, start=result if result is not None and
                        result.problem.image_width == _width(block, run) else None)
        slot = _jitter_slot(result)
        bound, problem = slot.bound, result.problem
        axes_names = tuple(slot.sensor.attitude_axes)
        m, offset, width = bound.jitter.size, bound.jitter_offset, problem.image_width
        Q = result.Q_theta
        diagonal = np.asarray(Q.diagonal())
        image_factor = float(result.variance_factor)
        factors = np.ones(3)
        for a in range(3):
            if held[a]:
                continue
            cols = np.concatenate([np.arange(i * width + offset + a * m, i * width + offset + (a + 1) * m)
                                   for i in slot.images])
            free = problem.image_free.reshape(-1)[cols]
            cols = cols[free]
            if not cols.size:
                held[a] = True
                continue
            x = result.state.image.reshape(-1)[cols]
            omega = float(np.sum((x / sigma[a]) ** 2))
            redundancy = float(np.sum(1.0 - diagonal[cols] / sigma[a] ** 2))
            factors[a] = omega / max(redundancy, 1e-9) / image_factor
        new_sigma = sigma * np.clip(factors, 0.25, 4.0) ** (0.5 * VCE_RELAXATION)
        effect = new_sigma * _pixels_per_rad(result)
        newly = (effect < MIN_EFFECT_PX) & ~held
        if say and not held.all():
            say("jitter sigma " + ", ".join(f"{n} {s * 1e6:.3f} urad ({e:.2f} px)" for n, s, e, h in
                                            zip(axes_names, new_sigma, effect, held) if not h))
        sigma = np.where(held, sigma, new_sigma)
        if newly.any():
            held |= newly
            continue
        if np.all(np.abs(factors[~held] - 1.0) <= VCE_TOLERANCE):
            break
    kept = tuple(a for a, h in zip(axes_names or (), held) if not h)
    return result, tuple(float(s) for s in sigma), kept


def _width(block, options) -> int:
    from ..sensors import sensor_of
    widths = {len(sensor_of(block.cameras[c]).configured(options.sensor).image_parameters)
              for c in set(block.images.camera_id.tolist())}
    return widths.pop() if len(widths) == 1 else -1


def _levels_carried(wavelet: str, fewest: int, details: bool = False):
    """The levels from :data:`FIRST_LEVEL` up whose functions an image of ``fewest`` observations carries
    (:data:`OBSERVATIONS_PER_TERM` each), built as they are tried: a basis has more functions at every level up, so
    the first one too many ends them (building all eleven took 63 of the 71 s of a triplet's choice: level 10 has
    1,000 functions over 33,000 samples)."""
    for level in JITTER_LEVELS:
        if level < FIRST_LEVEL:
            continue
        if time_basis(wavelet, level, 3, details).size * OBSERVATIONS_PER_TERM > fewest:
            return
        yield level


def choose_jitter(block, options: AdjustOptions, progress: Callable | None = None,
                  say: Callable[[str], None] | None = None) -> JitterChoice:
    """The jitter of ``options.sensor.jitter`` with its level (where not given) and its sigma per axis chosen by the
    data (module docstring); ``none`` where no axis has a practically significant jitter."""
    from .terrain import name_terrain_points
    spec = parse_jitter(options.sensor.jitter)
    assert spec is not None
    # terrain heights (issue 42 item 2) on the tie points the tested workflow will name: they see what the ties do not
    block = name_terrain_points(block, replace(options, sensor=replace(options.sensor, jitter="none")))
    n_obs = np.bincount(block.observations.image_index, minlength=len(block.images))
    fewest = int(n_obs[n_obs > 0].min()) if np.any(n_obs > 0) else 0
    levels = [spec.level] if spec.level is not None else _levels_carried(spec.wavelet, fewest, spec.details)
    tried: list[tuple[int, float]] = []
    best = None
    for level in levels:
        run = replace(options, sensor=replace(options.sensor, jitter=spec.at_level(level).text))
        result, sigma, kept = estimate_jitter_power(block, run, progress, say=say)
        omega = _image_omega(result)
        if say:
            say(f"jitter level {level}: {len(kept)} axes ({', '.join(kept) or 'none'}), image residual sum {omega:.1f}")
        if not kept:
            return JitterChoice("none", None, (), tuple(tried + [(level, omega)]), None)
        if tried and omega > (1.0 - LEVEL_GAIN) * tried[-1][1] and best is not None:
            tried.append((level, omega))
            break
        tried.append((level, omega))
        best = JitterChoice(spec.at_level(level).text, sigma, kept, (), result)
    if best is None:
        return JitterChoice("none", None, (), tuple(tried), None)
    return replace(best, tried=tuple(tried))
