"""An ISIS control network and its images' usgscsm/ALE ISDs as a selfcal block (jigsaw's settings)."""
from __future__ import annotations

import os

import numpy as np

from ..block import Block, Images, Observations, Points

FREE_SIGMA_M = 1.0e6


def block_from_isis(network, images: dict, image_sigma_px: float = 0.35, name: str = "isis",
                    camera_settings: dict | None = None, fixed_sigma_m: float = 0.001,
                    hold_radii_m: float | None = None) -> tuple[Block, dict]:
    """A block from an ISIS control network (:func:`selfcal.io.isis.read_control_network`) and the images of
    its measures (``images``: serial number -> (cube label, sensor file), :func:`selfcal.io.isis.read_image_folder`).

    One ``usgscsm`` camera per instrument (spacecraft and instrument id), each image's ISD as its sensor_file;
    Fixed and Constrained points become ``gcp`` (Fixed held by ``fixed_sigma_m``, Constrained with their
    a-priori sigmas: the mean of latitude and longitude sigma in plan, the radius sigma in height, ISIS's
    body-fixed covariance turned into north, east, radial), Free points ``tie`` with their a-priori XYZ as
    start values. Ignored points and measures, and measures of images not in ``images``, are left out and
    counted (the second return value). Points are body-fixed metres (``crs = "body-fixed"``). With
    ``hold_radii_m`` Free points with a-priori coordinates keep their radius within that sigma, latitude and
    longitude free (sigma :data:`FREE_SIGMA_M`): jigsaw's ``radius=no``; they are then ``gcp`` of the block.
    ``image_sigma_px`` (cube pixels): jigsaw's default weight of a measure is 1.4 detector pixels, 0.35
    pixels of the Apollo cubes reduced 4x. ``camera_settings``: block.toml keys of the cameras (sigmas)."""
    from ..geometry.body import sigmas_from_covariance
    from ..sensors.usgscsm_frame import UsgscsmCamera

    counts = {"ignored_points": 0, "ignored_measures": 0, "measures_without_image": 0}
    used: dict[str, int] = {}
    for point in network.points:
        if point.ignored:
            counts["ignored_points"] += 1
            continue
        for m in point.measures:
            if m.ignored:
                counts["ignored_measures"] += 1
            elif m.serial_number not in images:
                counts["measures_without_image"] += 1
            else:
                used.setdefault(m.serial_number, len(used))
    serials = sorted(used, key=lambda s: os.path.basename(images[s][1]))
    index = {s: k for k, s in enumerate(serials)}
    instrument = {s: f"{images[s][0].spacecraft_name}_{images[s][0].instrument_id}".replace(" ", "_") for s in serials}
    settings = dict(camera_settings or {})
    cameras = {c: UsgscsmCamera(c, **settings) for c in dict.fromkeys(instrument.values())}
    image_ids = [os.path.splitext(os.path.basename(images[s][1]))[0] for s in serials]
    n_img = len(serials)
    nan3 = np.full((n_img, 3), np.nan)
    block_images = Images(np.array(image_ids, object), np.array([instrument[s] for s in serials], object),
                          np.full(n_img, "", object), np.full(n_img, np.nan), nan3, nan3.copy(), np.arange(2, n_img + 2))
    ids: list[str] = []
    roles: list[str] = []
    xyz: list[np.ndarray] = []
    sigma: list[list[float]] = []
    lines: list[int] = []
    obs_img: list[int] = []
    obs_pt: list[int] = []
    pixel: list[tuple[float, float]] = []
    for point in network.points:
        measures = [m for m in point.measures if not point.ignored and not m.ignored and m.serial_number in index]
        if point.ignored or not measures:
            continue
        k = len(ids)
        ids.append(point.point_id)
        start = point.apriori_xyz_m if point.apriori_xyz_m is not None else np.full(3, np.nan)
        xyz.append(start)
        if point.point_type == "Fixed":
            roles.append("gcp")
            sigma.append([fixed_sigma_m] * 3)
        elif point.point_type == "Constrained" and point.apriori_covariance_m2 is not None:
            roles.append("gcp")
            s_lat, s_lon, s_rad = sigmas_from_covariance(start, point.apriori_covariance_m2)
            s_xy = float(np.sqrt((s_lat ** 2 + s_lon ** 2) / 2))
            sigma.append([s_xy, s_xy, s_rad])
        elif hold_radii_m is not None and point.apriori_xyz_m is not None:
            roles.append("gcp")
            sigma.append([FREE_SIGMA_M, FREE_SIGMA_M, hold_radii_m])
        else:
            roles.append("tie")
            sigma.append([np.nan] * 3)
        lines.append(point.source_line)
        for m in measures:
            obs_img.append(index[m.serial_number])
            obs_pt.append(k)
            pixel.append((m.col_px, m.row_px))
    points = Points(np.array(ids, object), np.array(roles, object), np.array(xyz, float).reshape(-1, 3),
                    np.array(sigma, float).reshape(-1, 3), np.array(lines))
    m = len(obs_img)
    observations = Observations(np.array(obs_img, np.int64), np.array(obs_pt, np.int64), np.array(pixel, float),
                                np.full(m, image_sigma_px), np.arange(2, m + 2))
    files = {image_id: os.path.abspath(images[s][1]) for image_id, s in zip(image_ids, serials)}
    block = Block(name=name, crs="body-fixed", cameras=cameras, images=block_images, points=points,
                  observations=observations, image_sigma_px=image_sigma_px, image_files=files)
    return block, counts


def adjusted_network(network, image_of_serial: dict[str, str], points: dict, residuals: dict,
                     detector_scale: dict[str, tuple[float, float]] | None = None):
    """The ISIS control network ``network`` with a selfcal adjustment in it, as jigsaw writes its ``onet``.

    ``points``/``residuals``: the columns of the results folder's points.csv and residuals.csv;
    ``image_of_serial``: serial number -> image id of the block. Each point the adjustment estimated gets its
    ``AdjustedX/Y/Z`` (body-fixed m, points.csv's X, Y, Z) and ``AprioriXYZSource`` unchanged; each measure it
    used gets ``SampleResidual``/``LineResidual`` in ISIS's sense: measured minus computed, in *detector*
    pixels (ISIS ``ControlPoint::ComputeResiduals``), i.e. ``-vx_px`` and ``vy_px`` (residuals.csv's v is
    computed minus observed in cube pixels, y up) times ``detector_scale[serial]`` (detector pixels per cube
    pixel along sample and line, the cube label's AlphaCube: 4 for the Apollo cubes reduced 4x; 1 where not
    given). Measured on the Apollo block: jigsaw's spot-checked residuals and per-image RMS are selfcal's times
    4. A measure residuals.csv marks rejected is ``JigsawRejected`` (not ``Ignore``, as jigsaw's
    outlier rejection). Points and measures the adjustment left out (ignored, of images not in the block) are
    as they were. Returns (network, counts of the points and measures written)."""
    import dataclasses
    xyz = {pid: np.array([points["X"][k], points["Y"][k], points["Z"][k]], float)
           for k, pid in enumerate(points["point_id"])}
    rows = {(str(i), str(p)): k for k, (i, p) in enumerate(zip(residuals["image_id"], residuals["point_id"]))}
    rejected = np.asarray(residuals["rejected"]).astype(float) != 0
    counts = {"points_adjusted": 0, "measures_with_residuals": 0, "measures_rejected": 0}
    new_points = []
    for point in network.points:
        adjusted = xyz.get(point.point_id) if not point.ignored else None
        measures = []
        for m in point.measures:
            k = rows.get((image_of_serial.get(m.serial_number, ""), point.point_id)) \
                if adjusted is not None and not m.ignored else None
            if k is not None:
                vx, vy = float(residuals["vx_px"][k]), float(residuals["vy_px"][k])
                s_scale, l_scale = (detector_scale or {}).get(m.serial_number, (1.0, 1.0))
                m = dataclasses.replace(m, sample_residual_px=-vx * s_scale if np.isfinite(vx) else float("nan"),
                                        line_residual_px=vy * l_scale if np.isfinite(vy) else float("nan"),
                                        rejected=bool(rejected[k]))
                counts["measures_with_residuals"] += 1
                counts["measures_rejected"] += int(rejected[k])
            measures.append(m)
        if adjusted is not None and np.all(np.isfinite(adjusted)):
            point = dataclasses.replace(point, adjusted_xyz_m=adjusted, adjusted_covariance_m2=None,
                                        measures=tuple(measures))
            counts["points_adjusted"] += 1
        else:
            point = dataclasses.replace(point, measures=tuple(measures))
        new_points.append(point)
    return dataclasses.replace(network, points=tuple(new_points)), counts
