"""Information matrices and residuals of pose-graph edges, in Open3D's conventions.

An edge ``(i, j, T_ij)`` says p_i = T_ij @ p_j (metres). Open3D's residual of an edge is the
linearisation of inv(X) @ inv(pose_t) @ pose_s ~ (w, v), acting on *source*-frame points, with
the 6-vector ordered (rotation, translation). The information matrix is therefore
sum_p G^T G with G = [-[p]x | I] over the matched points p **in the source frame j**; its
(5, 5) entry is the number of correspondences, which Open3D uses for the line-process weight
(see :mod:`c3f_slam.posegraph.open3d_adapter`).
"""

from __future__ import annotations

import numpy as np

from c3f_slam.geometry import invert_pose


def information_from_points(points: np.ndarray) -> np.ndarray:
    """6x6 information matrix sum_p G^T G, G = [-[p]x | I] (Choi et al. 2015, Open3D order).

    ``points`` (N, 3) are the matched 3D points, in metres, in the frame the edge's transform
    maps *from* (frame j of T_ij; Open3D's source frame). Entry (5, 5) equals N. Same values
    as Open3D 0.19's ``get_information_matrix_from_point_clouds`` for these points (which
    takes them from the target cloud instead; a test pins the equality).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    n = len(p)
    G = np.zeros((n, 3, 6))
    # -[p]x = [[0, z, -y], [-z, 0, x], [y, -x, 0]]
    G[:, 0, 1], G[:, 0, 2] = z, -y
    G[:, 1, 0], G[:, 1, 2] = -z, x
    G[:, 2, 0], G[:, 2, 1] = y, -x
    G[:, 0, 3] = G[:, 1, 4] = G[:, 2, 5] = 1.0
    return np.einsum("nki,nkj->ij", G, G)


def linearized_residual(T_ij: np.ndarray, T_wi: np.ndarray, T_wj: np.ndarray) -> np.ndarray:
    """Open3D's edge residual (w, v): linearisation of inv(T_ij) @ inv(T_wi) @ T_wj (radians, m)."""
    M = invert_pose(T_ij) @ invert_pose(T_wi) @ T_wj
    w = 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    return np.concatenate([w, M[:3, 3]])


def transform_information(info: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Information matrix of the same points expressed in another frame: ``info`` was built
    from points p (:func:`information_from_points`), the result equals the one built from
    T @ p. With A = Ad(T) = [[R, 0], [[t]x R, R]] (rotation, translation order) the small
    motions relate by xi' = A xi and the result is A^-T info A^-1. Works on one (6, 6) / (4, 4)
    pair or on stacks (E, 6, 6) / (E, 4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    L = np.asarray(info, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    t = T[..., :3, 3]
    skew = np.zeros(t.shape[:-1] + (3, 3))
    skew[..., 0, 1], skew[..., 0, 2] = -t[..., 2], t[..., 1]
    skew[..., 1, 0], skew[..., 1, 2] = t[..., 2], -t[..., 0]
    skew[..., 2, 0], skew[..., 2, 1] = -t[..., 1], t[..., 0]
    A_inv = np.zeros(t.shape[:-1] + (6, 6))
    A_inv[..., :3, :3] = Rt
    A_inv[..., 3:, 3:] = Rt
    A_inv[..., 3:, :3] = -Rt @ skew
    return np.swapaxes(A_inv, -1, -2) @ L @ A_inv


def edge_rms(T_ij: np.ndarray, information: np.ndarray, n_correspondences: float, T_wi: np.ndarray,
             T_wj: np.ndarray) -> float:
    """RMS point misalignment (metres) of one edge under poses T_wi, T_wj: sqrt(e^T Lambda e / N)."""
    r = linearized_residual(T_ij, T_wi, T_wj)
    return np.sqrt(max(float(r @ information @ r), 0.0) / max(n_correspondences, 1.0))
