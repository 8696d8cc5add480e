"""Additional-parameter (AP) families, found by name.

The registry below is the single place a family is made known: the CLI's
``--ap`` choices, serialisation and the contract tests all read it.
"""
from __future__ import annotations

import numpy as np

from .base import APModel, ImageFrame, parse_ap_spec
from .brown import BrownAP
from .ebner import EbnerAP
from .fourier import FourierAP
from .gruen import GruenAP
from .legendre import LegendreAP
from .none import NoAP
from .wavelet import WaveletAP

__all__ = ["AP_FAMILIES", "APModel", "ImageFrame", "create_ap", "ap_from_dict", "parse_ap_spec"]

#: family name -> model class
AP_FAMILIES: dict[str, type[APModel]] = {
    "none": NoAP,
    "brown": BrownAP,
    "ebner": EbnerAP,
    "gruen": GruenAP,
    "legendre": LegendreAP,
    "fourier": FourierAP,
    "wavelet": WaveletAP,
}


def _family(spec: str) -> tuple[type[APModel], str | None]:
    family, option = parse_ap_spec(spec)
    try:
        return AP_FAMILIES[family], option
    except KeyError:
        known = ", ".join(AP_FAMILIES)
        raise ValueError(f"unknown AP model '{spec}' (known families: {known})") from None


def create_ap(spec: str, frame: ImageFrame, observed_xy_mm: np.ndarray | None = None, **settings) -> APModel:
    """Build an AP model from its name, e.g. ``create_ap("wavelet:db4", frame, xy, grid=(9, 6))``."""
    cls, option = _family(spec)
    return cls.from_spec(option, frame, observed_xy_mm, **settings)


def ap_from_dict(data: dict, frame: ImageFrame) -> APModel:
    """Rebuild an AP model from :meth:`APModel.to_dict` output."""
    cls, _ = _family(data["spec"])
    return cls.from_dict(data, frame)
