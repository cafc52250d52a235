"""Weighted Kabsch: the rigid transform that best maps one point set onto another.

For correspondences between frames i and j (p_i ~ T_ij p_j), call
``kabsch(pts_j, pts_i)`` to get T_ij (the project's convention: T_ij maps j into i).
"""

from __future__ import annotations

import numpy as np


def kabsch(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None = None,
    return_singular_values: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """4x4 rigid T minimising sum_k w_k |R src_k + t - dst_k|^2 (a proper rotation, det +1).

    Args:
        src, dst: (N, 3) corresponding points (N >= 3 for a unique answer), metres.
        weights: optional (N,) non-negative weights (default 1).
        return_singular_values: also return the singular values (descending) of the
            weighted cross-covariance, used for the condition number of the fit.
    """
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if src.shape != dst.shape or len(src) == 0:
        raise ValueError(f"kabsch needs two equal, non-empty (N, 3) point sets, got {src.shape} and {dst.shape}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape[0] != len(src) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("kabsch weights must be (N,) non-negative with a positive sum")
    w = w / w.sum()
    c_src, c_dst = w @ src, w @ dst
    R, S = rotation_from_covariance((src - c_src).T @ ((dst - c_dst) * w[:, None]))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c_dst - R @ c_src
    return (T, S) if return_singular_values else T


def rotation_from_covariance(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The proper rotation R (det +1) maximising trace(R H) for the 3x3 cross-covariance
    H = sum w (src - c_src)(dst - c_dst)^T, and H's singular values (descending)."""
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T, S


def residuals(T: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(N,) Euclidean residuals |T src - dst| in metres."""
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    return np.linalg.norm(src @ T[:3, :3].T + T[:3, 3] - dst, axis=1)
