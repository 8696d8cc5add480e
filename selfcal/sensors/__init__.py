"""Sensor models behind one contract (:mod:`.base`), found by name.

A camera's ``model`` in block.toml names its sensor; the engine, the block reader and the
initial values find it here and never branch on the name. Foreign descriptions that become a
pushbroom camera are read by :mod:`selfcal.io` (usgscsm ISD; Pleiades and SPOT 5 DIMAP, DigitalGlobe XML) and
built by the modules :mod:`.usgscsm` and :mod:`.vendor` (:mod:`.dimap`, :mod:`.spot`, :mod:`.dg`).
"""
from . import bal, frame, opencv, pushbroom, rolling, rpc, usgscsm, usgscsm_frame, vendor
from .base import BoundSensor, Parameter, Sensor

#: sensor name (``model =`` of a camera in block.toml) -> the sensor
SENSORS: dict[str, Sensor] = {
    "frame": frame.SENSOR,
    "frame-rolling": rolling.SENSOR,
    "bal": bal.SENSOR,
    "opencv": opencv.SENSOR,
    "pushbroom": pushbroom.SENSOR,
    "rpc": rpc.SENSOR,
    "usgscsm": usgscsm_frame.SENSOR,
    "usgscsm-line": usgscsm.SENSOR,
    "dimap": vendor.DIMAP_SENSOR,
    "dg": vendor.DG_SENSOR,
}


def sensor_of(camera) -> Sensor:
    """The sensor of a block camera: its ``model``, or the sensor its images need where one model covers
    several (a usgscsm camera of frame or line-scan ISDs, a frame camera with a rolling shutter: ``camera.sensor``)."""
    try:
        return SENSORS[getattr(camera, "sensor", camera.model)]
    except KeyError:
        raise ValueError(f"camera model {camera.model!r} has no sensor (known: {', '.join(SENSORS)})") from None


__all__ = ["SENSORS", "Sensor", "BoundSensor", "Parameter", "sensor_of", "frame", "bal", "opencv", "pushbroom", "rpc"]
