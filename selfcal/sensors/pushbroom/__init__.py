"""The generic pushbroom (linear CCD) sensor of seed 001: the model (:mod:`.model`) and its place
behind the sensor contract (:mod:`.sensor`)."""
from .model import *  # noqa: F401,F403
from .model import __all__ as _model_all
from .sensor import *  # noqa: F401,F403
from .sensor import __all__ as _sensor_all

__all__ = list(_model_all) + list(_sensor_all)
