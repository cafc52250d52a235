"""Refit of a pairwise rigid transform by symmetric reprojection error.

The match filter fits ``T_ij`` (p_i = T_ij p_j) to 3D-3D correspondences (Kabsch), which
trusts each point's depth as much as its pixel position. On predicted depth the depth is the
noisy part (a few per cent of it, correlated over the image) while the keypoints' pixels are
accurate, so the 3D-3D fit puts the depth's error into the rotation and the direction of the
translation. This refit keeps the filter's correspondences and starts from its transform, then
minimises the reprojection error of each frame's points in the other frame:

    sum_k  rho(| pi(T_ij p_j,k) - pi(p_i,k) |)  +  rho(| pi(T_ij^-1 p_i,k) - pi(p_j,k) |)

with ``pi`` the pinhole projection (pixels) and ``rho`` the Huber norm (``huber_px``). The
observations are the points' own projections, i.e. the keypoints they were lifted from, so
the callers need no pixel arrays. Depth still sets the translation's length (each term moves
one frame's points), but no longer the bearing of either frame's points.

Gauss-Newton on a left perturbation ``T <- exp(xi) T``, xi = (rho, phi), with iteratively
reweighted Huber weights; the result is kept only if its robust cost is below the start's.
Units: metres and pixels.
"""

from __future__ import annotations

import numpy as np

from c3f_slam.geometry import axis_angle_to_matrix, project


def _skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices (a batch of :mod:`c3f_slam.geometry`'s)."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], 1),
                     np.stack([v[:, 2], z, -v[:, 0]], 1),
                     np.stack([-v[:, 1], v[:, 0], z], 1)], 1)


def _project(q: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of camera points (N, 3) and d(pixel)/d(point) (N, 2, 3); unlike
    :func:`c3f_slam.geometry.project`, finite behind the camera too (those points are weighted
    out, and a NaN would spread through the normal equations)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    iz = 1.0 / z
    uv = np.stack([fx * x * iz + cx, fy * y * iz + cy], 1)
    J = np.zeros((len(q), 2, 3))
    J[:, 0, 0] = fx * iz
    J[:, 0, 2] = -fx * x * iz * iz
    J[:, 1, 1] = fy * iz
    J[:, 1, 2] = -fy * y * iz * iz
    return uv, J


def _terms(R: np.ndarray, t: np.ndarray, p_i: np.ndarray, p_j: np.ndarray, *, K: np.ndarray,
           x_i: np.ndarray, x_j: np.ndarray, huber_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (2N, 2) in units of the Huber threshold (pixels / ``huber_px``), their
    Jacobians (2N, 2, 6) w.r.t. xi, and validity (2N,: positive depth after the transform)."""
    q = p_j @ R.T + t                    # frame j's points in frame i
    s = (p_i - t) @ R                    # frame i's points in frame j (R^T (p_i - t))
    uv_q, Jq = _project(q, K)
    uv_s, Js = _project(s, K)
    dq = np.concatenate([np.broadcast_to(np.eye(3), (len(q), 3, 3)), -_skew(q)], axis=2)
    RT = np.broadcast_to(R.T, (len(s), 3, 3))
    ds = np.concatenate([-RT, RT @ _skew(p_i)], axis=2)
    r = np.concatenate([uv_q - x_i, uv_s - x_j]) / huber_px
    J = np.concatenate([Jq @ dq, Js @ ds]) / huber_px
    ok = np.concatenate([q[:, 2], s[:, 2]]) > 1e-9
    return r, J, ok


def _robust_cost(r: np.ndarray, ok: np.ndarray) -> float:
    """Huber cost of per-point residuals already divided by the threshold (an invalid point costs 1)."""
    e = np.linalg.norm(r[ok], axis=1)
    return float(np.sum(np.where(e <= 1.0, 0.5 * e * e, e - 0.5)) + np.sum(~ok))


def refine_by_reprojection(
    T_ij: np.ndarray,
    p_i: np.ndarray,
    p_j: np.ndarray,
    K: np.ndarray,
    huber_px: float,
    iterations: int = 10,
) -> np.ndarray:
    """``T_ij`` (4x4, p_i = T_ij p_j) refitted to the symmetric reprojection error of the
    corresponding camera points ``p_i``, ``p_j`` (N, 3, metres, positive depth) under the 3x3
    intrinsics ``K``, Huber threshold ``huber_px`` pixels (the run's
    ``match_filter.reprojection_huber_px``); the input transform when fewer than 3 points or no
    lower cost is found."""
    p_i = np.asarray(p_i, dtype=np.float64).reshape(-1, 3)
    p_j = np.asarray(p_j, dtype=np.float64).reshape(-1, 3)
    T0 = np.asarray(T_ij, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    good = np.isfinite(p_i).all(1) & np.isfinite(p_j).all(1) & (p_i[:, 2] > 0) & (p_j[:, 2] > 0)
    p_i, p_j = p_i[good], p_j[good]
    if len(p_i) < 3:
        return T0
    x_i, _ = project(p_i, K)  # the keypoints the points were lifted from
    x_j, _ = project(p_j, K)
    R, t = T0[:3, :3].copy(), T0[:3, 3].copy()
    r, J, ok = _terms(R, t, p_i, p_j, K=K, x_i=x_i, x_j=x_j, huber_px=huber_px)
    start = best = _robust_cost(r, ok)
    best_R, best_t = R, t
    for _ in range(iterations):
        e = np.linalg.norm(r, axis=1)
        w = np.where(ok, np.where(e <= 1.0, 1.0, 1.0 / np.maximum(e, 1e-12)), 0.0)  # Huber (IRLS)
        H = np.einsum("n,nai,naj->ij", w, J, J)
        g = np.einsum("n,nai,na->i", w, J, r)
        H[np.diag_indices(6)] += 1e-9 * max(np.trace(H), 1.0)
        try:
            xi = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        dR = axis_angle_to_matrix(xi[3:])
        R, t = dR @ R, dR @ t + xi[:3]
        r, J, ok = _terms(R, t, p_i, p_j, K=K, x_i=x_i, x_j=x_j, huber_px=huber_px)
        cost = _robust_cost(r, ok)
        if cost < best:
            best, best_R, best_t = cost, R, t
        if np.linalg.norm(xi) < 1e-10:
            break
    if not best < start:
        return T0
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = best_R, best_t
    return T


__all__ = ["refine_by_reprojection"]
