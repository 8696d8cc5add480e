"""A-priori readout times of rolling-shutter cameras, by the camera model the images' EXIF names, and the cameras of a
block made rolling-shutter cameras (``selfcal import gnss|colmap|pix4d --rolling-shutter``).

The readout times are those OpenDroneMap measured and lists in ``opendm/rollingshutter.py`` (its ``RS_DATABASE``,
make and model lower-cased, "each line represents ~1 ms" of a photo of an LED blinking at about 2 kHz taken with the
fastest shutter speed: https://github.com/OpenDroneMap/RSCalibration). Where ODM gives two values by the capture's
size (megapixels), the table keeps both with ODM's threshold. A camera model not in the table gets
:data:`UNKNOWN_READOUT_MS` (ODM's own default, "just a guess") with the wide sigma :data:`UNKNOWN_SIGMA_MS`, so that
the block determines it; a tabulated one the sigma :func:`readout_prior` states (ODM's values are rounded to the
millisecond and one camera reads faster or slower in another capture mode).
"""
from __future__ import annotations

import re
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..block import Block, FrameCamera
from ..geometry.gnss import STRIP_GAP_FACTOR, STRIP_TURN_DEG, detect_strips

if TYPE_CHECKING:
    from ..io.exif import ImageGnss

__all__ = ["READOUT_MS", "UNKNOWN_READOUT_MS", "UNKNOWN_SIGMA_MS", "ReadoutPrior", "readout_prior",
           "with_rolling_shutter", "camera_model_key", "pix4d_camera_model", "with_exposure_times", "NEEDS_TIMES"]

#: camera make and model (lower case, as EXIF Make + " " + Model) -> readout (ms), or steps by the capture's size:
#: ((below this many megapixels, readout ms), ..., (inf, readout ms)); source: OpenDroneMap, opendm/rollingshutter.py
#: (RS_DATABASE), with its comments' camera names
_ANY = float("inf")
READOUT_MS: dict[str, float | tuple[tuple[float, float], ...]] = {
    "autel robotics xt701": 25,             # Autel Evo II 8k
    "autel robotics xt705": 30,             # Autel EVO II Pro
    "autel robotics xl724": 29,             # Autel Nano+
    "dji phantom vision fc200": 74,         # Phantom 2
    "dji fc300s": 33,                       # Phantom 3 Advanced
    "dji fc300c": 33,                       # Phantom 3 Standard
    "dji fc300x": 33,                       # Phantom 3 Professional
    "dji fc330": 33,                        # Phantom 4
    "dji fc6310": 33,                       # Phantom 4 Professional
    "dji fc7203": ((10, 19), (_ANY, 25)),   # Mavic Mini v1 (16:9, 9 MP: 19 ms; 4:3, 12 MP: 25 ms)
    "dji fc2103": 32,                       # Mavic Air 1
    "dji fc3170": 27,                       # Mavic Air 2
    "dji fc3411": 32,                       # Air 2S
    "dji fc220": 64,                        # Mavic Pro (Platinum)
    "hasselblad l1d-20c": ((17, 47), (_ANY, 56)),   # Mavic 2 Pro (16:10, 16.8 MP: 47 ms; 3:2 and 4:3: 56 ms)
    "hasselblad l2d-20c": 16.6,             # Mavic 3 (not the enterprise version)
    "dji fc3582": ((48, 26), (_ANY, 60)),   # Mini 3 Pro (12 MP: 26 ms; 48 MP: 60 ms)
    "dji fc8482": ((12, 16), (20, 21), (45, 43), (_ANY, 58)),   # Mini 4 Pro (by resolution and aspect ratio)
    "dji fc350": 30,                        # Inspire 1
    "dji mavic2-enterprise-advanced": 31,   # Mavic 2 Enterprise Advanced
    "dji zenmuse z30": 8,                   # Zenmuse Z30
    "yuneec e90": 44,                       # Yuneec E90
    "gopro hero4 black": 30,
    "gopro hero8 black": 17,
    "teracube teracube one": 32,            # TeraCube One TR1907Q phone
    "fujifilm x-a5": 186,
    "fujifilm x-t2": 35,
    "parrot anafi": 39,
}
#: a camera model the table does not know: ODM's default readout and a sigma that lets the block decide
UNKNOWN_READOUT_MS, UNKNOWN_SIGMA_MS = 30.0, 30.0
#: the a-priori sigma of a tabulated readout: this share of it, at least MIN_TABLE_SIGMA_MS
TABLE_SIGMA_SHARE, MIN_TABLE_SIGMA_MS = 0.15, 5.0


def camera_model_key(make: str, model: str) -> str:
    """The table's key of an EXIF Make and Model: ``"dji fc6310"``; without the make, the key whose model it is
    (``"FC6310"``: ``"dji fc6310"``; a model name the table does not hold as the key's model: the name)."""
    if not make.strip():
        model = model.strip().lower()
        return next((key for key in READOUT_MS if key.split(" ", 1)[-1] == model), model)
    return f"{make.strip()} {model.strip()}".lower().strip()


#: Pix4D's name of a camera: ``MODEL_FOCAL_WIDTHxHEIGHT`` (``FC6310_8.8_5472x3648``, as its camera database and
#: quality report write it, sometimes followed by `` (RGB)``), or an older ``MODEL_FOCAL_...`` (``H_8.07_6.0525``)
_PIX4D_NAME = re.compile(r"^(?P<model>.+?)_(?P<focal>\d+(?:\.\d+)?)(?:_(?P<width>\d+)x(?P<height>\d+))?(?:[_ ].*)?$")


def pix4d_camera_model(name: str) -> tuple[str, int | None, int | None]:
    """The camera model and the image size (None where the name has none) in Pix4D's name of a camera (the BINGO
    file's headers ``image camera``): ``"FC6310_8.8_5472x3648"`` -> ``("FC6310", 5472, 3648)``; a name of another
    form is the model as it is."""
    match = _PIX4D_NAME.match(name.strip())
    if match is None:
        return name.strip(), None, None
    width, height = match.group("width"), match.group("height")
    return match.group("model"), (int(width) if width else None), (int(height) if height else None)


@dataclass(frozen=True)
class ReadoutPrior:
    """An a-priori readout (ms) with its sigma, and where it comes from (for the import's messages)."""

    readout_ms: float
    sigma_ms: float
    source: str


def readout_prior(make: str | None, model: str | None, width_px: int | None = None,
                  height_px: int | None = None) -> ReadoutPrior:
    """The a-priori readout of a camera by its EXIF Make and Model and capture size (ODM's table), else the wide
    prior of an unknown camera."""
    key = camera_model_key(make or "", model or "")
    entry = READOUT_MS.get(key)
    if entry is None:
        named = f"'{' '.join(n for n in (make, model) if n)}'" if make or model else \
            "a camera whose images name no model"
        return ReadoutPrior(UNKNOWN_READOUT_MS, UNKNOWN_SIGMA_MS, f"{named} is not in OpenDroneMap's readout table: "
                            f"{UNKNOWN_READOUT_MS:g} +- {UNKNOWN_SIGMA_MS:g} ms, for the block to determine")
    if isinstance(entry, tuple):
        values = [ms for _, ms in entry]
        if width_px is None or height_px is None:
            value = max(values)
            how = f" (capture size unknown: the largest of its {', '.join(f'{v:g}' for v in values)} ms)"
        else:
            megapixels = width_px * height_px / 1e6
            value = next(ms for below, ms in entry if megapixels < below)
            how = f" at {megapixels:.1f} MP"
    else:
        value, how = float(entry), ""
    sigma = max(MIN_TABLE_SIGMA_MS, TABLE_SIGMA_SHARE * float(value))
    return ReadoutPrior(float(value), sigma, f"'{key}'{how}: {value:g} +- {sigma:g} ms (OpenDroneMap's "
                                             f"opendm/rollingshutter.py)")


def with_rolling_shutter(block: Block, camera_of_images: Mapping[str, tuple] | None = None,
                         readout_ms: float | None = None, sigma_readout_ms: float | None = None
                         ) -> tuple[Block, list[str]]:
    """``block`` with its frame cameras made rolling-shutter cameras, and one note per camera saying its prior.

    ``camera_of_images``: image id -> (make, model, width_px, height_px) from its EXIF; a camera takes the model its
    images name most often. ``readout_ms`` (and ``sigma_readout_ms``, default :data:`MIN_TABLE_SIGMA_MS`): a prior
    for every camera instead of the table's."""
    cameras = dict(block.cameras)
    notes = []
    for camera_id, camera in block.cameras.items():
        if not isinstance(camera, FrameCamera):
            continue
        if readout_ms is not None:
            sigma = MIN_TABLE_SIGMA_MS if sigma_readout_ms is None else sigma_readout_ms
            prior = ReadoutPrior(float(readout_ms), float(sigma), f"{readout_ms:g} +- {sigma:g} ms (given)")
        else:
            mine = np.flatnonzero(block.images.camera_id == camera_id)
            given = camera_of_images or {}
            named = Counter(given[str(i)] for i in block.images.image_id[mine] if str(i) in given)
            make, model, width, height = named.most_common(1)[0][0] if named else (None, None, None, None)
            prior = readout_prior(make, model, width, height)
        cameras[camera_id] = replace(camera, shutter="rolling", readout_ms=prior.readout_ms,
                                     sigma_readout_ms=prior.sigma_ms)
        notes.append(f"camera {camera_id}: rolling shutter, readout {prior.source}")
    return replace(block, cameras=cameras), notes


#: what the rolling-shutter model needs that a tool's orientation files do not hold, and how to give it
NEEDS_TIMES = ("a rolling shutter needs each image's exposure time (the velocity during its readout comes from the "
               "positions and times of its strip)")


def with_exposure_times(block: Block, records: Sequence[ImageGnss], turn_deg: float = STRIP_TURN_DEG,
                        gap_factor: float = STRIP_GAP_FACTOR) -> tuple[Block, list[str]]:
    """``block`` with each image's exposure time from its JPEG's EXIF (``records``, :class:`selfcal.io.exif.ImageGnss`
    matched by file name or stem; seconds since the first exposure, one clock for all:
    :func:`selfcal.convert.gnss.exposure_times`) and its strips found from the times and the block's positions
    (:func:`selfcal.geometry.gnss.detect_strips`: a turn or a pause starts a strip), for the rolling-shutter model.
    Notes say which clock; a ValueError names the images without a JPEG or a time (the CLI's exit 2)."""
    from .gnss import exposure_times, match_images
    names = np.array([r.name for r in records], dtype=object)
    index, _ = match_images(block.images.image_id, names)
    time, note = exposure_times([r for r, k in zip(records, index) if k >= 0])
    notes = [note] if note else []
    n = len(block.images)
    times = np.full(n, np.nan)
    times[index[index >= 0]] = time
    untimed = block.images.image_id[~np.isfinite(times)]
    if untimed.size:
        matched = np.zeros(n, bool)
        matched[index[index >= 0]] = True
        without = [str(i) for i in block.images.image_id[~matched]]
        why = (f"{len(without)} image(s) of the block have no JPEG among the images ({', '.join(without[:3])})"
               if without else note)
        raise ValueError(f"{NEEDS_TIMES}: {why}")
    times -= times.min()
    has = np.isfinite(block.images.position_m).all(axis=1)
    strips = np.array([f"S{s + 1}" for s in detect_strips(times, block.images.position_m, turn_deg, gap_factor)],
                      dtype=object)
    k = len(set(strips[has]))
    notes.append(f"exposure times of {n} images from their EXIF, {k} strip{'s' if k != 1 else ''} from the times "
                 f"and the positions")
    return replace(block, images=replace(block.images, time_s=times, strip_id=strips)), notes
