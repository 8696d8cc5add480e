"""Other tools' camera calibration files, as plain data (:class:`ToolCalibration`), written and read.

* Metashape calibration XML (``<calibration>``): f, cx, cy, b1, b2, k1-k4, p1, p2 in Metashape's own
  conventions (cx, cy offsets of the principal point from the image centre in px; its P1, P2 swapped
  relative to OpenCV's p1, p2; the centre of the first pixel at (0.5, 0.5)), and the ``<covariance>`` block
  Metashape writes (``<params>`` names, ``<coeffs>`` the matrix row by row). Also the older PhotoScan / Agisoft
  Lens layout (``fx``, ``fy``, ``cx``, ``cy`` of the principal point itself, ``skew``, ``k1``-``k4``, ``p1``,
  ``p2``), whose values are converted here to the newer names (:data:`OLD_METASHAPE_NAMES`).
* OpenSfM / OpenDroneMap ``cameras.json``: ``{camera key: {projection_type, width, height, ...}}`` with the
  focal length and principal point normalised by the larger image side (OpenSfM's normalised image
  coordinates: origin at the image centre).
* Kalibr ``camchain.yaml``: ``cam0: {camera_model: pinhole, intrinsics: [fu, fv, pu, pv], distortion_model:
  radtan | equidistant, distortion_coeffs, resolution: [w, h], rostopic, cam_overlaps}``, OpenCV's pixel
  convention.
* OpenCV FileStorage (YAML, XML, JSON): :mod:`selfcal.io.opencv`.

No conversion happens here: the values are the tool's, named as the tool names them
(:data:`selfcal.calibration_models.MODELS` gives their meaning).
"""
from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass

import numpy as np

from ..errors import BlockError
from .atomic import atomic_write
from .text import read_text, yaml_error
from .xmlfile import xml_root

__all__ = ["ToolCalibration", "write_metashape_xml", "read_metashape_xml", "write_opensfm_cameras",
           "read_opensfm_cameras", "write_kalibr_camchain", "read_kalibr_camchain", "read_calibration_file",
           "METASHAPE_NAMES", "OLD_METASHAPE_NAMES", "OPENSFM_NAMES", "KALIBR_DISTORTION_NAMES", "KALIBR_ROSTOPIC"]

#: Metashape's parameters in the order of its calibration file
METASHAPE_NAMES = ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2")
#: the older PhotoScan / Agisoft Lens calibration's parameters. Its model (Agisoft Lens user manual 0.4.0, "Camera
#: model", as quoted on Agisoft's forum, topic 6437): x' = x(1 + K1 r^2 + K2 r^4 + K3 r^6) + P2 (r^2 + 2x^2) + 2 P1 x y,
#: y' = y(1 + ...) + P1 (r^2 + 2y^2) + 2 P2 x y, u = cx + x' fx + y' skew, v = cy + y' fy. The newer one (Metashape
#: user manual, Appendix C, Frame cameras): x' = x(...) + P1 (r^2 + 2x^2) + 2 P2 x y, u = w/2 + cx + x'(f + B1) + y' B2,
#: v = h/2 + cy + y' f. So (Agisoft's support on that topic: "F = Fy, B1 = Fx - Fy, B2 = skew") f = fy,
#: b1 = fx - fy, b2 = skew, cx = cx_old - w/2, cy = cy_old - h/2, and the newer P1, P2 are the older P2, P1.
OLD_METASHAPE_NAMES = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "k4", "p1", "p2")
#: each newer parameter as a linear combination of the older ones (the constant -w/2, -h/2 of cx, cy aside)
_FROM_OLD = {"f": {"fy": 1.0}, "cx": {"cx": 1.0}, "cy": {"cy": 1.0}, "b1": {"fx": 1.0, "fy": -1.0},
             "b2": {"skew": 1.0}, "k1": {"k1": 1.0}, "k2": {"k2": 1.0}, "k3": {"k3": 1.0}, "k4": {"k4": 1.0},
             "p1": {"p2": 1.0}, "p2": {"p1": 1.0}}
#: OpenSfM's parameters of each projection type (opensfm/io.py camera_to_json)
OPENSFM_NAMES = {"perspective": ("focal", "k1", "k2"),
                 "brown": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "k3", "p1", "p2"),
                 "fisheye": ("focal", "k1", "k2")}
#: Kalibr's distortion coefficients of each distortion model
KALIBR_DISTORTION_NAMES = {"radtan": ("k1", "k2", "r1", "r2"), "equidistant": ("k1", "k2", "k3", "k4")}
#: the image topic a camchain names when none is given (Kalibr's own examples: /cam0/image_raw)
KALIBR_ROSTOPIC = "/cam0/image_raw"


@dataclass(frozen=True)
class ToolCalibration:
    """One camera of another tool's calibration file: the tool, its model, its parameters by its own names,
    the image size and, where the file has it, the covariance of the parameters (names, matrix)."""

    tool: str
    model: str
    values: dict
    width_px: int
    height_px: int
    covariance_names: tuple[str, ...] = ()
    covariance: np.ndarray | None = None
    camera_id: str = ""
    #: selfcal's warning that the calibration is extrapolated beyond its observations (written as a comment, or a
    #: key the tool does not read), or ""
    warning: str = ""


def _number(text: str) -> str:
    return repr(float(text))


# --- Metashape --------------------------------------------------------------------------------------------

def write_metashape_xml(path: str | os.PathLike, calibration: ToolCalibration) -> None:
    """A Metashape calibration file (Tools > Camera Calibration > Load), with the covariance when given."""
    root = ElementTree.Element("calibration")
    ElementTree.SubElement(root, "projection").text = "frame"
    ElementTree.SubElement(root, "width").text = str(int(calibration.width_px))
    ElementTree.SubElement(root, "height").text = str(int(calibration.height_px))
    for name in METASHAPE_NAMES:
        ElementTree.SubElement(root, name).text = _number(calibration.values.get(name, 0.0))
    if calibration.covariance is not None:
        cov = ElementTree.SubElement(root, "covariance")
        ElementTree.SubElement(cov, "params").text = " ".join(calibration.covariance_names)
        ElementTree.SubElement(cov, "coeffs").text = " ".join(repr(float(v)) for v in
                                                              np.asarray(calibration.covariance).ravel())
    if calibration.warning:
        root.insert(0, ElementTree.Comment(f" selfcal warning: {calibration.warning.replace('--', '- -')} "))
    ElementTree.indent(root)
    with atomic_write(path) as handle:
        handle.write('<?xml version="1.0" encoding="UTF-8"?>\n')
        handle.write(ElementTree.tostring(root, encoding="unicode") + "\n")


def read_metashape_xml(path: str | os.PathLike) -> ToolCalibration:
    """A Metashape calibration file (``<calibration>``), or the one calibrated sensor of a Metashape cameras
    export (``<document>``: ``sensor/calibration`` with ``<resolution width= height=>``, the adjusted one when
    both are there, and the sensor's ``<covariance>``)."""
    path = os.fspath(path)
    root = xml_root(path, "Metashape calibration")
    if root.tag == "document":
        sensors = [s for s in root.iter("sensor") if s.find("calibration") is not None]
        if len(sensors) != 1:
            raise BlockError(path, f"a Metashape document with {len(sensors)} calibrated sensors; export the one "
                                   f"wanted (Tools > Camera Calibration > Export) and import that file")
        sensor = sensors[0]
        calibrations = sensor.findall("calibration")
        calib = next((c for c in calibrations if c.get("class") == "adjusted"), calibrations[0])
        resolution = calib.find("resolution")
        resolution = resolution if resolution is not None else sensor.find("resolution")
        if resolution is None:
            raise BlockError(path, "the sensor's <resolution width=... height=...> is missing")
        size = (resolution.get("width"), resolution.get("height"))
        projection, cov = calib.get("type", "frame"), sensor.find("covariance")
    elif root.tag == "calibration":
        calib = root
        size = (root.findtext("width"), root.findtext("height"))
        projection, cov = (root.findtext("projection") or "frame").strip(), root.find("covariance")
    else:
        raise BlockError(path, f"not a Metashape calibration: the root element is <{root.tag}>, not <calibration>")
    if projection != "frame":
        raise BlockError(path, f"Metashape projection '{projection}': only 'frame' cameras are supported")

    def number(tag, text, default=None):
        if text is None:
            if default is None:
                raise BlockError(path, f"<{tag}> is missing")
            return default
        try:
            value = float(text)
        except ValueError:
            raise BlockError(path, f"<{tag}> is not a number: {text.strip()!r}") from None
        if not np.isfinite(value):
            raise BlockError(path, f"<{tag}> is not finite")
        return value

    width, height = number("width", size[0]), number("height", size[1])
    if width <= 0 or height <= 0 or width != int(width) or height != int(height):
        raise BlockError(path, f"image size {width:g} x {height:g} is not two positive whole numbers")
    old = calib.find("f") is None and calib.find("fx") is not None
    if old:
        if calib.find("fy") is None:
            raise BlockError(path, "<fy> is missing (the older PhotoScan layout has <fx> and <fy>, in pixels)")
        values = _from_old_metashape({name: number(name, calib.findtext(name), 0.0) for name in OLD_METASHAPE_NAMES},
                                     width, height)
        if not values["f"] > 0:
            raise BlockError(path, f"<fy> must be a positive focal length in pixels, found {values['f']!r}")
    else:
        if calib.find("f") is None:
            raise BlockError(path, "<f> is missing (the focal length in pixels; or <fx> and <fy> of PhotoScan's older "
                                   "layout)")
        values = {name: number(name, calib.findtext(name), 0.0) for name in METASHAPE_NAMES}
        if not values["f"] > 0:
            raise BlockError(path, f"<f> must be a positive focal length in pixels, found {values['f']!r}")
    names: tuple[str, ...] = ()
    matrix = None
    if cov is not None:
        known = OLD_METASHAPE_NAMES if old else METASHAPE_NAMES
        names = tuple((cov.findtext("params") or "").split())
        try:
            matrix = np.array([float(v) for v in (cov.findtext("coeffs") or "").split()], float)
        except ValueError:
            raise BlockError(path, "<covariance><coeffs> holds something that is not a number") from None
        if matrix.size != len(names) ** 2:
            raise BlockError(path, f"<covariance>: {matrix.size} coefficients for {len(names)} parameters")
        unknown = [name for name in names if name.lower() not in known]
        if unknown or len(set(names)) != len(names):
            raise BlockError(path, f"<covariance><params> must name distinct parameters of {', '.join(known)}"
                                   f", found {' '.join(names)[:80]!r}")
        if not np.all(np.isfinite(matrix)):
            raise BlockError(path, "<covariance><coeffs> holds a value that is not finite")
        matrix = matrix.reshape(len(names), len(names))
        if old:
            names, matrix = _covariance_from_old_metashape(tuple(n.lower() for n in names), matrix)
    return ToolCalibration("metashape", "frame", values, int(width), int(height), names, matrix)


def _from_old_metashape(old: dict, width: float, height: float) -> dict:
    """The newer Metashape parameters of an older PhotoScan / Lens calibration (:data:`OLD_METASHAPE_NAMES`)."""
    values = {new: sum(k * old[name] for name, k in terms.items()) for new, terms in _FROM_OLD.items()}
    values["cx"] -= width / 2.0
    values["cy"] -= height / 2.0
    return {name: values[name] for name in METASHAPE_NAMES}


def _covariance_from_old_metashape(names: tuple[str, ...], matrix: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
    """The covariance of the newer parameters that the older ones given (``names``) determine: J C J^T."""
    index = {name: k for k, name in enumerate(names)}
    new = tuple(n for n in METASHAPE_NAMES if any(o in index for o in _FROM_OLD[n]))
    jacobian = np.zeros((len(new), len(names)))
    for row, name in enumerate(new):
        for old, k in _FROM_OLD[name].items():
            if old in index:
                jacobian[row, index[old]] = k
    return new, jacobian @ matrix @ jacobian.T


# --- OpenSfM / ODM ----------------------------------------------------------------------------------------

def opensfm_camera_key(calibration: ToolCalibration) -> str:
    """A camera key as OpenSfM forms its own (``v2 make model width height projection focal``)."""
    focal = calibration.values.get("focal", calibration.values.get("focal_x", 0.0))
    ident = "selfcal " + (calibration.camera_id or "camera")
    return f"v2 {ident} {calibration.width_px} {calibration.height_px} {calibration.model} {focal:.4f}".lower()


def write_opensfm_cameras(path: str | os.PathLike, calibration: ToolCalibration, key: str | None = None) -> None:
    entry = {"projection_type": calibration.model, "width": int(calibration.width_px),
             "height": int(calibration.height_px)}
    entry.update({name: float(calibration.values[name]) for name in OPENSFM_NAMES[calibration.model]})
    if calibration.warning:
        entry["selfcal_warning"] = calibration.warning          # (OpenSfM reads its parameters by name)
    with atomic_write(path) as handle:
        json.dump({key or opensfm_camera_key(calibration): entry}, handle, indent=4)
        handle.write("\n")


def read_opensfm_cameras(path: str | os.PathLike, camera: str | None = None) -> ToolCalibration:
    """One camera of an OpenSfM cameras.json (the only one, or ``camera``, its key)."""
    from .text import read_json
    path = os.fspath(path)
    data = read_json(path, "OpenSfM cameras.json")
    if not isinstance(data, dict) or not data or not all(isinstance(v, dict) for v in data.values()):
        raise BlockError(path, "not an OpenSfM cameras.json: expected {camera key: {projection_type, ...}}")
    if camera is None:
        if len(data) > 1:
            raise BlockError(path, f"holds {len(data)} cameras ({', '.join(data)}); choose one")
        camera = next(iter(data))
    if camera not in data:
        raise BlockError(path, f"no camera {camera!r} (it has: {', '.join(data)})")
    entry = data[camera]
    model = entry.get("projection_type")
    if model not in OPENSFM_NAMES:
        raise BlockError(path, f"camera {camera!r}: projection_type {model!r} is not supported (supported: "
                               f"{', '.join(OPENSFM_NAMES)})")
    from .opensfm import check_camera_numbers
    check_camera_numbers(path, entry, f"camera {camera!r}")
    values = {}
    for name in ("width", "height") + OPENSFM_NAMES[model]:
        value = entry.get(name, 0.0 if name[0] in "kpc" else None)
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise BlockError(path, f"camera {camera!r}: '{name}' is missing or not a number, found {value!r}"[:200])
        values[name] = float(value)
    width, height = values.pop("width"), values.pop("height")
    if width <= 0 or height <= 0 or width != int(width) or height != int(height):
        raise BlockError(path, f"camera {camera!r}: image size {width:g} x {height:g} is not two positive whole "
                               f"numbers")
    return ToolCalibration("opensfm", model, values, int(width), int(height), camera_id=camera)


def _whole(value) -> int:
    """A whole number of a YAML/JSON file (int, or a float without fraction); anything else: ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        raise ValueError(f"{value!r} is not a whole number")
    return int(value)


# --- Kalibr -----------------------------------------------------------------------------------------------

def write_kalibr_camchain(path: str | os.PathLike, calibration: ToolCalibration,
                          rostopic: str = KALIBR_ROSTOPIC) -> None:
    """A Kalibr camchain.yaml of one camera (cam0) with every key Kalibr's camchain reader requires
    (kalibr_common/ConfigReader.py, CameraParameters and CameraChainParameters): camera_model, intrinsics
    (floats), distortion_model, distortion_coeffs, resolution [w, h] (ints), rostopic (the image topic the
    IMU-camera calibration reads the bag from) and cam_overlaps (no other camera). No T_cn_cnm1: cam0 is the
    chain's base, Kalibr has none for it."""
    import yaml
    v = calibration.values
    names = KALIBR_DISTORTION_NAMES[calibration.model]
    cam = {"camera_model": "pinhole",
           "intrinsics": [float(v["fu"]), float(v["fv"]), float(v["pu"]), float(v["pv"])],
           "distortion_model": calibration.model,
           "distortion_coeffs": [float(v[name]) for name in names],
           "resolution": [int(calibration.width_px), int(calibration.height_px)],
           "rostopic": str(rostopic),
           "cam_overlaps": []}
    with atomic_write(path) as handle:
        if calibration.warning:
            handle.write(f"# selfcal warning: {calibration.warning}\n")
        yaml.safe_dump({"cam0": cam}, handle, default_flow_style=None, sort_keys=False)


def read_kalibr_camchain(path: str | os.PathLike, camera: str | None = None) -> ToolCalibration:
    """One camera (``cam0`` unless ``camera``) of a Kalibr camchain.yaml."""
    import yaml
    path = os.fspath(path)
    try:
        data = yaml.safe_load(read_text(path, "Kalibr camchain"))
    except yaml.YAMLError as exc:
        raise yaml_error(path, exc) from None
    except RecursionError:
        raise BlockError(path, "not YAML: nested too deeply") from None
    if not isinstance(data, dict) or not any(isinstance(v, dict) and "intrinsics" in v for v in data.values()):
        raise BlockError(path, "not a Kalibr camchain: no camN entry with intrinsics")
    camera = camera or ("cam0" if "cam0" in data else next(k for k, v in data.items()
                                                           if isinstance(v, dict) and "intrinsics" in v))
    if camera not in data:
        raise BlockError(path, f"no camera {camera!r} (it has: {', '.join(map(str, data))})")
    cam = data[camera]
    if not isinstance(cam, dict):
        raise BlockError(path, f"'{camera}' must be a map of camera_model, intrinsics, ..., found {cam!r}"[:200])
    if cam.get("camera_model", "pinhole") != "pinhole":
        raise BlockError(path, f"{camera}: camera_model {cam.get('camera_model')!r} is not supported (pinhole)")
    model = cam.get("distortion_model", "radtan")
    if model not in KALIBR_DISTORTION_NAMES:
        raise BlockError(path, f"{camera}: distortion_model {model!r} is not supported (supported: "
                               f"{', '.join(KALIBR_DISTORTION_NAMES)})")
    try:
        intrinsics = [float(v) for v in cam["intrinsics"]]
        coeffs = [float(v) for v in cam.get("distortion_coeffs", [0.0] * 4)]
        width, height = (_whole(v) for v in cam["resolution"])
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise BlockError(path, f"{camera}: intrinsics [fu, fv, pu, pv], distortion_coeffs and resolution [w, h] "
                               f"are needed ({exc})") from None
    if len(intrinsics) != 4 or len(coeffs) != 4 or width <= 0 or height <= 0:
        raise BlockError(path, f"{camera}: intrinsics and distortion_coeffs need 4 numbers each, resolution 2 "
                               f"positive ones")
    if not all(np.isfinite(intrinsics + coeffs)) or not (intrinsics[0] > 0 and intrinsics[1] > 0):
        raise BlockError(path, f"{camera}: intrinsics {intrinsics} and distortion_coeffs {coeffs} must be finite, "
                               f"fu and fv positive")
    values = dict(zip(("fu", "fv", "pu", "pv"), intrinsics))
    values.update(zip(KALIBR_DISTORTION_NAMES[model], coeffs))
    return ToolCalibration("kalibr", model, values, width, height, camera_id=camera)


# --- any of them ------------------------------------------------------------------------------------------

def read_calibration_file(path: str | os.PathLike) -> ToolCalibration:
    """A calibration file of any of the tools, recognised by its content (then its extension)."""
    from .opencv import read_opencv_calibration
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise BlockError(path, "file not found")
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096).decode("utf-8", "replace")
    except OSError as exc:
        raise BlockError(path, f"cannot read the calibration: {exc.strerror}") from None
    text = head.lstrip("\ufeff \t\r\n")
    if "opencv_storage" in head or text.startswith("%YAML") or "!!opencv-matrix" in head \
            or ('"camera_matrix"' in head and text.startswith("{")):
        return read_opencv_calibration(path)
    if "<calibration" in head or ("<document" in head and "<sensor" in head):
        return read_metashape_xml(path)
    if text.startswith("{") and "projection_type" in head:
        return read_opensfm_cameras(path)
    if "intrinsics" in head and "resolution" in head:
        return read_kalibr_camchain(path)
    ext = os.path.splitext(path)[1].lower()
    raise BlockError(path, f"not a calibration file selfcal recognises (a {ext or 'file without extension'} that "
                           f"is none of: Metashape <calibration> XML, OpenSfM cameras.json with projection_type, "
                           f"OpenCV FileStorage with camera_matrix, Kalibr camchain with intrinsics and "
                           f"resolution)")
