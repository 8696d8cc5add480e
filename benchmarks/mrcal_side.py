"""mrcal's half of benchmarks/peer_mrcal_uncertainty.py: run by Debian's /usr/bin/python3 (python3-mrcal lives
there, not in the virtual environment), so it imports NumPy and mrcal only.

    /usr/bin/python3 benchmarks/mrcal_side.py IN.npz OUT.npz

IN.npz: ``observations`` (Nframes, Nh, Nw, 2) chessboard corners in mrcal's pixels (the centre of the first pixel
at 0, 0), ``object_width_n``, ``object_height_n``, ``spacing``, ``imagersize`` (W, H), ``lensmodel``,
``intrinsics`` and ``frames_rt_toref`` (the seed), ``query`` (m, 2) mrcal pixels, ``distance``, ``sigma`` (the
observations' sigma, px), ``regularization`` (0/1).
OUT.npz: the solved ``intrinsics`` and ``frames_rt_toref``, ``rms_px``, ``var_intrinsics`` (Var of the intrinsics
at ``sigma``, mrcal's own propagation), ``p_cam`` (the query points at ``distance`` through the solved model) and
``cov_q`` (m, 2, 2): ``mrcal.projection_uncertainty(p_cam, model, what="covariance",
observed_pixel_uncertainty=sigma)``; ``projected`` (Nframes, Nh, Nw, 2) the corners through the seed (a check of
the pixel conventions).
"""
import sys

import mrcal
import numpy as np


def main(inp: str, out: str) -> None:
    d = np.load(inp)
    frames = np.array(d["frames_rt_toref"], float)
    observations = np.concatenate([d["observations"], np.ones(d["observations"].shape[:-1] + (1,))], axis=-1)
    lensmodel = str(d["lensmodel"])
    W, H = (int(v) for v in d["imagersize"])
    Nw, Nh, spacing = int(d["object_width_n"]), int(d["object_height_n"]), float(d["spacing"])
    board = mrcal.ref_calibration_object(Nw, Nh, spacing)
    projected = mrcal.project(mrcal.transform_point_rt(frames[:, None, None, :], board), lensmodel,
                              np.array(d["intrinsics"], float))
    oi = dict(intrinsics=np.array(d["intrinsics"], float)[None, :], extrinsics_rt_fromref=np.zeros((0, 6)),
              frames_rt_toref=frames, points=None, observations_board=observations,
              indices_frame_camintrinsics_camextrinsics=np.array([(i, 0, -1) for i in range(len(frames))], np.int32),
              observations_point=None, indices_point_camintrinsics_camextrinsics=None, lensmodel=lensmodel,
              imagersizes=np.array([(W, H)], np.int32), do_optimize_intrinsics_core=True,
              do_optimize_intrinsics_distortions=True, do_optimize_extrinsics=True, do_optimize_frames=True,
              do_optimize_calobject_warp=False, calibration_object_spacing=spacing,
              do_apply_outlier_rejection=False, do_apply_regularization=bool(d["regularization"]), verbose=False)
    stats = mrcal.optimize(**oi)
    model = mrcal.cameramodel(optimization_inputs=oi, icam_intrinsics=0)
    sigma = float(d["sigma"])
    p_cam = float(d["distance"]) * mrcal.unproject(np.array(d["query"], float), *model.intrinsics(), normalize=True)
    cov_q = mrcal.projection_uncertainty(p_cam, model, what="covariance", observed_pixel_uncertainty=sigma)
    # Var(intrinsics) by mrcal's own propagation (its private helper, as projection_uncertainty calls it)
    _, _, J, factorization = mrcal.optimizer_callback(**oi)
    n_state = J.shape[-1]
    n_intrinsics = oi["intrinsics"].shape[-1]
    start = mrcal.state_index_intrinsics(0, **oi)
    dF_db = np.zeros((n_intrinsics, n_state))
    dF_db[np.arange(n_intrinsics), start + np.arange(n_intrinsics)] = 1.0
    mrcal.unpack_state(dF_db, **oi)
    n_boards = mrcal.num_measurements_boards(**oi)
    n_boards = None if n_boards == mrcal.num_measurements(**oi) else n_boards
    var_intrinsics = mrcal.model_analysis._propagate_calibration_uncertainty(dF_db, factorization, J, n_boards, sigma,
                                                                             "covariance")
    np.savez(out, intrinsics=oi["intrinsics"][0], frames_rt_toref=oi["frames_rt_toref"],
             rms_px=stats["rms_reproj_error__pixels"], var_intrinsics=var_intrinsics, p_cam=p_cam, cov_q=cov_q,
             projected=projected)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
