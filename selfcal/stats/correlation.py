"""Correlation analysis by parameter group (Table 4 of seed 000).

``max_abs_corr`` (summary.json, the report's "Table 4" line), exactly: Q is the cofactor matrix of the adjustment's
unknowns after the object points are eliminated (``AdjustmentResult.Q_theta``: the inverse of the reduced normal
matrix, which is the same block of the inverse of the full one), at the end of the tested adjustment (after data
snooping and screening: the APs and trajectory terms screening held are not in it). The correlation of two
unknowns is rho_ij = Q_ij / sqrt(Q_ii Q_jj) (the variance factor cancels). AP is every active AP coefficient of
every camera; the groups are IOP (the cameras' estimated core parameters: c, x0, y0 of a frame camera), EOP (every
image parameter of every image: X0, Y0, Z0, omega, phi, kappa), GNSS and IMU (the estimated strip shift/drift
terms of each sensor), and intra-AP (the APs among themselves, i != j). The figure of a group is
max |rho_ij| over AP i and group member j: the single most correlated pair, not a group-to-group measure.

What it can and cannot mean. A correlation coefficient belongs to a parametrisation, not to the model: any
invertible linear map of the AP coefficients (another basis of the same span of fields) leaves the fitted field,
sigma0 and every object point unchanged and changes every rho that involves an AP. A basis orthonormal in the
a-posteriori metric (:func:`orthonormal_ap_map`) makes intra-AP exactly 0. What no basis changes is
:func:`canonical_correlation_by_group`: the largest correlation of any AP field with any combination of the
group's parameters, invariant to every reparametrisation within the APs and within the group, and never below the
pairwise figure. The pairwise figure can be spread over the coefficients, not removed: for a group member j whose
multiple correlation with the whole AP span is R_j, some coefficient of any m-coefficient basis correlates with it
by at least R_j / sqrt(m). A figure below 0.01 between APs and the IOP or the EOP therefore says either that the
model's span barely overlaps those parameters' effects (then the canonical correlation is small too), or that it
is another quantity: :func:`design_cosine_by_group`, the angle between the design matrix's columns, is near 0 for
basis functions orthogonal to the IOP and EOP fields over the image whatever the estimates' correlations.
"""
from __future__ import annotations

import numpy as np

__all__ = ["GROUPS", "parameter_groups", "max_abs_correlation_by_group", "correlation_matrix", "orthonormal_ap_map",
           "canonical_correlation_by_group", "design_cosine_by_group", "correlation_figures"]

GROUPS = ("IOP", "intra-AP", "EOP", "GNSS", "IMU")


def parameter_groups(problem) -> dict[str, np.ndarray]:
    """Indices into theta of each group; ``AP`` holds the AP coefficients."""
    n_e = problem.n_e
    iop, ap = [], []
    for cam, start in zip(problem.cameras, problem.d_offset):
        pos = start + np.cumsum(cam.free) - 1
        iop += [int(pos[i]) for i in range(cam.n_core) if cam.free[i]]
        ap += [int(pos[i]) for i in range(cam.n_core, cam.size) if cam.free[i]]
    groups = {"AP": np.array(ap, np.int64), "IOP": np.array(iop, np.int64),
              "EOP": np.arange(n_e, dtype=np.int64)}
    for name in ("GNSS", "IMU"):
        groups[name] = np.array(getattr(problem, "extra_groups", {}).get(name, []), np.int64)
    return groups


def correlation_matrix(Q: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Correlation coefficients of the unknowns ``index`` from the cofactor matrix Q."""
    sub = Q[np.ix_(index, index)]
    s = 1.0 / np.sqrt(np.diag(sub))
    return sub * s[:, None] * s[None, :]


def max_abs_correlation_by_group(problem, Q, ap_map: np.ndarray | None = None) -> dict[str, float | None]:
    """max ``|rho|`` between the APs and each group (module docstring); None where a group is empty or there are no
    APs. ``ap_map`` (m, m): the figures of the AP coefficients b = ap_map a instead of a (e.g.
    :func:`orthonormal_ap_map`), from the same Q."""
    groups = parameter_groups(problem)
    ap = groups["AP"]
    out: dict[str, float | None] = {name: None for name in GROUPS}
    if ap.size == 0:
        return out
    if ap_map is not None:
        others = [g for g in GROUPS if g != "intra-AP"]
        Q = _mapped(Q, ap, ap_map, [groups[g] for g in others])
        start, mapped = ap.size, {}
        for g in others:
            mapped[g] = np.arange(start, start + len(groups[g]))
            start += len(groups[g])
        groups, ap = mapped, np.arange(ap.size)
    d = np.sqrt(Q.diagonal())
    for name in GROUPS:
        other = ap if name == "intra-AP" else groups[name]
        if other.size == 0 or (name == "intra-AP" and ap.size < 2):
            continue
        rho = Q[np.ix_(ap, other)] / d[ap][:, None] / d[other][None, :]
        if name == "intra-AP":
            np.fill_diagonal(rho, 0.0)
        out[name] = float(np.max(np.abs(rho)))
    return out


def _mapped(Q, ap: np.ndarray, ap_map: np.ndarray, others: list[np.ndarray]) -> np.ndarray:
    """The cofactors of [b = ap_map a, then the unknowns ``others``] as one dense matrix."""
    index = np.concatenate([ap, *others]).astype(np.int64)
    dense = np.asarray(Q[index[:, None], index[None, :]], float)
    m = ap.size
    T = np.eye(index.size)
    T[:m, :m] = ap_map
    return T @ dense @ T.T


def _group_index(problem, groups: dict, name: str) -> np.ndarray:
    """A group's estimated unknowns (EOP: the free image parameters only: held ones carry a unit cofactor)."""
    if name == "EOP":
        return np.flatnonzero(np.asarray(problem.image_free, bool).ravel())
    return groups[name]


def orthonormal_ap_map(problem, Q) -> np.ndarray | None:
    """T (m, m): the AP coefficients b = T a of a basis orthonormal over the block's own observations after every
    other unknown is eliminated (cofactor of b: the identity, so intra-AP correlations vanish), rotated so that its
    first coefficients are the canonical directions of the APs' span towards the IOP (those alone correlate with
    it, with the canonical correlations; the others are uncorrelated with every IOP). A linear reparametrisation:
    the field B a = (B T^-1) b, sigma0 and every estimate are those of the APs as they are. None without APs."""
    groups = parameter_groups(problem)
    ap = groups["AP"]
    if ap.size == 0:
        return None
    C_aa = np.asarray(Q[ap[:, None], ap[None, :]], float)
    L = np.linalg.cholesky(C_aa)                                   # C_aa = L L^T: L^-1 a has cofactor I
    W = np.linalg.inv(L)
    iop = groups["IOP"]
    if iop.size:
        C_ai = np.asarray(Q[ap[:, None], iop[None, :]], float)
        L_i = np.linalg.cholesky(np.asarray(Q[iop[:, None], iop[None, :]], float))
        K = W @ C_ai @ np.linalg.inv(L_i).T                         # whitened cross-covariance
        U, _, _ = np.linalg.svd(K)                                  # canonical directions first
        W = U.T @ W
    return W


def canonical_correlation_by_group(problem, Q) -> dict[str, float | None]:
    """The largest canonical correlation between the APs' span and each group: max over AP combinations u and
    group combinations v of corr(u^T a, v^T g) (the square root of the largest eigenvalue of C_aa^-1 C_ag C_gg^-1
    C_ga). Invariant to every invertible reparametrisation within the APs and within the group; not smaller than
    any max |rho| between a single AP and a single member. None where a group or the APs are empty. intra-AP has
    no such figure (a span with itself: 1)."""
    groups = parameter_groups(problem)
    ap = groups["AP"]
    out: dict[str, float | None] = {name: None for name in GROUPS if name != "intra-AP"}
    if ap.size == 0:
        return out
    L_a = np.linalg.cholesky(np.asarray(Q[ap[:, None], ap[None, :]], float))
    for name in out:
        g = _group_index(problem, groups, name)
        if g.size == 0:
            continue
        L_g = np.linalg.cholesky(np.asarray(Q[g[:, None], g[None, :]], float))
        C = np.asarray(Q[ap[:, None], g[None, :]], float)
        K = np.linalg.solve(L_a, np.linalg.solve(L_g, C.T).T)
        out[name] = float(min(np.linalg.svd(K, compute_uv=False)[0], 1.0))
    return out


def design_cosine_by_group(problem, linearisation) -> dict[str, float | None]:
    """max |cos| between an AP's column and a group member's column of the whitened design matrix over the image
    observations, N_ij / sqrt(N_ii N_jj) with N the normal matrix of the image observations (the points not
    eliminated): how far the basis functions, seen at the block's observations, are from orthogonal to the other
    unknowns' effects. Not a correlation of the estimates (those come from N's inverse, after the points are
    eliminated). The trajectory terms have no image observation: their cosine with an AP is 0. None where a group
    or the APs are empty."""
    groups = parameter_groups(problem)
    ap = groups["AP"]
    out: dict[str, float | None] = {name: None for name in GROUPS}
    if ap.size == 0:
        return out
    n_e = problem.n_e
    U_dd, U_ed = linearisation.U_dd, linearisation.U_ed
    d_ap = np.sqrt(np.diag(U_dd)[ap - n_e])
    for name in GROUPS:
        if name == "intra-AP":
            if ap.size < 2:
                continue
            block = U_dd[np.ix_(ap - n_e, ap - n_e)] / d_ap[:, None] / d_ap[None, :]
            np.fill_diagonal(block, 0.0)
        elif name == "EOP":
            eop = np.flatnonzero(np.asarray(problem.image_free, bool).ravel())
            d_e = np.sqrt(np.einsum("nii->ni", linearisation.U_ee).ravel()[eop])
            block = U_ed[np.ix_(eop, ap - n_e)] / d_e[:, None] / d_ap[None, :]
        elif name == "IOP":
            iop = groups["IOP"]
            if iop.size == 0:
                continue
            block = U_dd[np.ix_(iop - n_e, ap - n_e)] / np.sqrt(np.diag(U_dd)[iop - n_e])[:, None] / d_ap[None, :]
        else:
            block = np.zeros(1) if groups[name].size else None
            if block is None:
                continue
        out[name] = float(np.max(np.abs(block)))
    return out


def correlation_figures(result) -> dict:
    """summary.json's further figures of Table 4 (``selfcal adjust --orthonormal``): ``max_abs_corr_orthonormal``
    (max_abs_corr of the AP coefficients in the basis of :func:`orthonormal_ap_map`), ``canonical_corr``
    (:func:`canonical_correlation_by_group`) and ``design_cosine`` (:func:`design_cosine_by_group`)."""
    problem, Q = result.problem, result.Q_theta
    T = orthonormal_ap_map(problem, Q)
    return {"max_abs_corr_orthonormal": max_abs_correlation_by_group(problem, Q, T) if T is not None else
            {name: None for name in GROUPS},
            "canonical_corr": canonical_correlation_by_group(problem, Q),
            "design_cosine": design_cosine_by_group(problem, result.linearisation)}
