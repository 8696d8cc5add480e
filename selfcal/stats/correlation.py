"""Correlation analysis by parameter group (Table 4 of seed 000).

For the additional parameters (APs) of each camera, the largest absolute
correlation coefficient with each group of unknowns: the interior orientation
(IOP), the other APs (intra-AP), the exterior orientation (EOP), and the
trajectory shift/drift parameters (GNSS, IMU) when the block has them.
"""
from __future__ import annotations

import numpy as np

__all__ = ["GROUPS", "parameter_groups", "max_abs_correlation_by_group", "correlation_matrix"]

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


def max_abs_correlation_by_group(problem, Q) -> dict[str, float | None]:
    """max ``|rho|`` between the APs and each group; None where a group is empty or there are no APs."""
    groups = parameter_groups(problem)
    ap = groups["AP"]
    out: dict[str, float | None] = {name: None for name in GROUPS}
    if ap.size == 0:
        return out
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
