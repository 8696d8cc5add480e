"""Write a tie-only ``rpc`` block folder of the Pleiades stereo crops over Mont Ventoux.

    python examples/ventoux/make_block.py OUT [--bias shift|affine|none] [--sigma-bias-px 10] [--data DIR]

DIR (default ``../shared/data/pushbroom/pleiades/phr_ventoux``) holds ``left_image.tif`` / ``right_image.tif``
(crops of the full images; the GeoTIFF transform ``(1, 0, c, 0, 1, f)`` is the crop's offset) and each full
image's RPC as an OSSIM ``.geom``. Tie points: OpenCV SIFT on the crops (8-bit stretch between the 1st and
99th percentile), Lowe's ratio test 0.75, a fundamental matrix by RANSAC (1 px). Pixel coordinates are
converted once to the full images in selfcal's convention (0, 0 at the upper-left corner of the upper-left
pixel): an OpenCV keypoint (x, y) -- pixel centres at integers -- becomes (col, row) = (x + 0.5 + c, y + 0.5 + f);
the RPCs are used as they are (copied into OUT as each image's ``sensor_file``). See
tests/test_pleiades_stereo.py for how that convention was checked against shareloc.
"""
from __future__ import annotations

import argparse
import os
import shutil

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.normpath(os.path.join(HERE, "..", "..", "..", "shared", "data", "pushbroom", "pleiades", "phr_ventoux"))
CROPS = ("left", "right")


def crop(data: str, name: str):
    """The crop as 8-bit and its offset (c, f) in the full image."""
    import rasterio
    with rasterio.open(os.path.join(data, f"{name}_image.tif")) as dataset:
        pixels = dataset.read(1).astype(float)
        t = dataset.transform
    if (t.a, t.b, t.d, t.e) != (1.0, 0.0, 0.0, 1.0):
        raise SystemExit(f"{name}_image.tif: the transform is not a translation by whole pixels: {t}")
    lo, hi = np.percentile(pixels[pixels > 0], [1, 99])
    return np.clip((pixels - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8), np.array([t.c, t.f])


def _once(points) -> np.ndarray:
    """Whether each position occurs once among ``points`` (to 0.01 px)."""
    _, inverse, counts = np.unique(np.round(points, 2), axis=0, return_inverse=True, return_counts=True)
    return counts[inverse.ravel()] == 1


def tie_points(data: str, ratio: float = 0.75, ransac_px: float = 1.0, local_px: float = 10.0):
    """(counts after each filter, full-image (col, row) of the tie points in the left and in the right image)."""
    import cv2
    from scipy.spatial import cKDTree
    (left, off_left), (right, off_right) = (crop(data, n) for n in CROPS)
    sift = cv2.SIFT_create()
    k1, d1 = sift.detectAndCompute(left, None)
    k2, d2 = sift.detectAndCompute(right, None)
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(d1, d2, k=2)
    good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < ratio * n.distance]
    counts = {"ratio_test": len(good)}
    p1 = np.float64([k1[m.queryIdx].pt for m in good])
    p2 = np.float64([k2[m.trainIdx].pt for m in good])
    # SIFT gives a keypoint with two dominant orientations twice: one tie point per pair of positions, and none
    # where a position is paired with two different ones
    _, first = np.unique(np.round(np.hstack([p1, p2]), 2), axis=0, return_index=True)
    p1, p2 = p1[np.sort(first)], p2[np.sort(first)]
    keep = _once(p1) & _once(p2)
    p1, p2 = p1[keep], p2[keep]
    counts["unique"] = len(p1)
    _, inlier = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, ransac_px, 0.999)
    inlier = inlier.ravel().astype(bool)
    p1, p2 = p1[inlier], p2[inlier]
    counts["ransac"] = len(p1)
    # a mismatch along its epipolar line passes RANSAC, and with two rays the adjustment cannot see it either (it
    # becomes a wrong height): keep the matches whose displacement is within local_px of the median displacement
    # of their 8 nearest neighbours (10 px: about 15 m of height at this pair's base-to-height ratio of 0.34)
    d = p2 - p1
    _, near = cKDTree(p1).query(p1, k=9)
    keep = np.linalg.norm(d - np.median(d[near[:, 1:]], axis=1), axis=1) <= local_px
    p1, p2 = p1[keep], p2[keep]
    counts["local"] = len(p1)
    # OpenCV puts pixel centres at integers: + 0.5 to selfcal's corner convention, + the crop's offset
    return counts, p1 + 0.5 + off_left, p2 + 0.5 + off_right


def write_block(out: str, data: str, bias: str, sigma_bias_px: float, image_sigma_px: float, left, right,
                size: bool = True) -> None:
    """The block folder (``size``: block.toml states the full images' size; without it the RPCs' scales give it)."""
    os.makedirs(out, exist_ok=True)
    for name in CROPS:
        shutil.copyfile(os.path.join(data, f"{name}_image.geom"), os.path.join(out, f"{name}_image.geom"))
    with open(os.path.join(out, "block.toml"), "w") as f:
        f.write(f'name = "ventoux"\n'
                f'crs = "EPSG:4979"                 # points: longitude, latitude (deg), ellipsoidal height (m)\n\n'
                f'[cameras.phr]\nmodel = "rpc"\nbias = "{bias}"\n'
                + ("width_px = 39182\nheight_px = 41801\n" if size else "")
                + f"sigma_bias_px = {sigma_bias_px!r}       # the datum of this tie-only block\n\n"
                f"[observations]\nimage_sigma_px = {image_sigma_px!r}\n")
    with open(os.path.join(out, "images.csv"), "w") as f:
        f.write("image_id,camera_id,strip_id,time_s,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sensor_file\n")
        f.writelines(f"{name},phr,pair,,,,,,,,{name}_image.geom\n" for name in CROPS)
    with open(os.path.join(out, "points.csv"), "w") as f:
        f.write("point_id,role,X,Y,Z,sigma_xy_m,sigma_z_m\n")
        f.writelines(f"t{k},tie,,,,,\n" for k in range(len(left)))
    with open(os.path.join(out, "observations.csv"), "w") as f:
        f.write("image_id,point_id,col_px,row_px\n")
        for k, (a, b) in enumerate(zip(left, right)):
            f.write(f"left,t{k},{a[0]:.4f},{a[1]:.4f}\nright,t{k},{b[0]:.4f},{b[1]:.4f}\n")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out")
    parser.add_argument("--bias", choices=("shift", "affine", "none"), default="shift")
    parser.add_argument("--sigma-bias-px", type=float, default=10.0,
                        help="a-priori sigma of each bias shift (px; the linear terms by it over 41801 px)")
    parser.add_argument("--image-sigma-px", type=float, default=0.3)
    parser.add_argument("--data", default=DATA)
    args = parser.parse_args(argv)
    if not os.path.isdir(args.data):
        raise SystemExit(f"data folder not found: {args.data}")
    counts, left, right = tie_points(args.data)
    write_block(args.out, args.data, args.bias, args.sigma_bias_px, args.image_sigma_px, left, right)
    print(f"{args.out}: SIFT {counts['ratio_test']} ratio-test matches, {counts['unique']} unique, "
          f"{counts['ransac']} RANSAC inliers, {counts['local']} tie points consistent with their neighbours; "
          f"bias {args.bias}, sigma_bias_px {args.sigma_bias_px}")


if __name__ == "__main__":
    main()
