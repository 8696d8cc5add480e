"""Additional-parameter (AP) families, found by name.

The registry below is the single place a family is made known: the CLI's
``--ap`` choices, serialisation and the contract tests all read it.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .base import APModel, ImageFrame, parse_ap_spec
from .brown import BrownAP
from .ebner import EbnerAP
from .fourier import FourierAP
from .gruen import GruenAP
from .legendre import LegendreAP
from .line import LineWaveletAP
from .none import NoAP
from .wavelet import WaveletAP

__all__ = ["AP_FAMILIES", "APModel", "ImageFrame", "create_ap", "ap_from_dict", "parse_ap_spec", "frame_nodes_mm",
           "fit_displacement", "absorbed_fields", "ap_settings", "takes_grid", "ALL_MODELS", "check_ap_spec"]

#: the ten frame AP models of seed 000's comparison (``selfcal compare``, ``--ap auto``)
ALL_MODELS = ("none", "brown", "ebner", "gruen", "legendre", "fourier",
              "wavelet:db4", "wavelet:sym4", "wavelet:meyer", "wavelet:bl4")

#: a family's class: a frame family's :class:`APModel` subclass, or the family along a detector line (no APModel: it
#: has no image frame)
APFamily = type[APModel] | type[LineWaveletAP]

#: family name -> model class; a family says its domain (frame or detector line) and the settings it takes
AP_FAMILIES: dict[str, APFamily] = {
    "none": NoAP,
    "brown": BrownAP,
    "ebner": EbnerAP,
    "gruen": GruenAP,
    "legendre": LegendreAP,
    "fourier": FourierAP,
    "wavelet": WaveletAP,
    "wavelet1d": LineWaveletAP,
}


def takes_grid(spec: str) -> bool:
    """Whether the family of ``spec`` takes a grid (the wavelet APs, over a frame or along a line)."""
    cls = AP_FAMILIES.get(parse_ap_spec(spec)[0])
    return cls is not None and "grid" in cls.settings


def ap_settings(spec: str, grid: Sequence[int]) -> dict:
    """The settings the family of ``spec`` takes, from the options given (``grid``)."""
    return {"grid": tuple(grid)} if takes_grid(spec) else {}


def _family(spec: str) -> tuple[APFamily, str | None]:
    family, option = parse_ap_spec(spec)
    try:
        return AP_FAMILIES[family], option
    except KeyError:
        known = ", ".join(AP_FAMILIES)
        raise ValueError(f"unknown AP model '{spec}' (known families: {known})") from None


def _frame_family(spec: str) -> tuple[type[APModel], str | None]:
    """:func:`_family` of a family that lives on an image frame; another domain (a detector line): ValueError."""
    cls, option = _family(spec)
    if cls.domain != "frame" or not issubclass(cls, APModel):
        raise ValueError(f"AP model '{spec}' lives on a {cls.domain}, not on a frame (frame families: "
                         f"{', '.join(n for n, c in AP_FAMILIES.items() if c.domain == 'frame')})")
    return cls, option


def check_ap_spec(spec: str) -> str:
    """``spec`` if it names a family with a valid option (``legendre:3``, ``wavelet:db4``); else ValueError saying
    what is wrong. The model is built once on a nominal frame (or detector line), so every check its family makes
    is made here, before any work."""
    cls, option = _family(spec)
    cls.check_option(option)
    return spec.strip()


def create_ap(spec: str, frame: ImageFrame, observed_xy_mm: np.ndarray | None = None, **settings) -> APModel:
    """Build an AP model from its name, e.g. ``create_ap("wavelet:db4", frame, xy, grid=(9, 6))``."""
    cls, option = _frame_family(spec)
    return cls.from_spec(option, frame, observed_xy_mm, **settings)


def ap_from_dict(data: dict, frame: ImageFrame) -> APModel:
    """Rebuild an AP model from :meth:`APModel.to_dict` output (of a frame family)."""
    cls, _ = _frame_family(data["spec"])
    return cls.from_dict(data, frame)


def frame_nodes_mm(frame: ImageFrame, nodes_x: int = 61) -> tuple[np.ndarray, np.ndarray]:
    """Photo coordinates (mm) of a regular grid over the frame, corners included, ``nodes_x`` across and as
    many down as keep the cells square (61 x 41 on a 3:2 frame); row by row from the top of the image, as
    pixel rows run (the grid of distortion_grid.csv, of the OpenCV fit and of initial-value transfers)."""
    nodes_y = max(2, int(round((nodes_x - 1) * frame.height_mm / frame.width_mm)) + 1)
    x, y = np.meshgrid(np.linspace(-0.5, 0.5, nodes_x) * frame.width_mm,
                       np.linspace(0.5, -0.5, nodes_y) * frame.height_mm)
    return x.ravel(), y.ravel()


def absorbed_fields(x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The six image-space fields an adjustment's orientation and interior orientation take up, at photo
    coordinates: shifts in x and y (the principal point), scale (the principal distance), rotation (kappa) and the
    two projective fields of omega and phi; (n, 6) for x and for y, scaled to order one over the points."""
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    s = 1.0 / max(np.max(np.abs(x), initial=0.0), np.max(np.abs(y), initial=0.0), 1e-300)
    one, zero = np.ones_like(x), np.zeros_like(x)
    u, v = s * x, s * y
    return (np.column_stack([one, zero, u, v, u * u, u * v]), np.column_stack([zero, one, v, -u, u * v, v * v]))


def fit_displacement(model: APModel, x_mm: np.ndarray, y_mm: np.ndarray, dx_px: np.ndarray,
                     dy_px: np.ndarray, absorbed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients (px) of ``model`` that fit a displacement field Delta(x, y) in the least-squares sense.

    The basis is linear in its coefficients, so this is one linear solve. With ``absorbed``, the six
    fields the orientation takes up in an adjustment (shifts in x and y: the principal point; scale: the
    principal distance; rotation: kappa; the two projective fields of omega and phi) are fitted
    alongside and left out of the coefficients, so that a family without them does not bend its terms
    towards them. Returns the coefficients and the misfit (n, 2) in pixels at the given points.
    """
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    bx, by = model.basis(x, y)
    design = np.vstack([bx, by])
    if absorbed:
        design = np.hstack([design, np.vstack(absorbed_fields(x, y))])
    target = np.concatenate([dx_px, dy_px])
    if design.shape[1] == 0:
        return np.zeros(0), np.column_stack([dx_px, dy_px])
    solution = np.linalg.lstsq(design, target, rcond=None)[0]
    misfit = (design @ solution - target).reshape(2, -1).T
    return solution[:model.n_params], misfit
