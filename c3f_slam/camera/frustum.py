"""View-frustum overlap between two frames (fragment condition (2), docs/design.md, Fragments and keyframes).

The overlap of frame i with frame j is the share of frame i's valid pixels (on a subsampled
grid, back-projected with frame i's depth) whose 3D points land inside frame j's image, in
front of its camera, and (optionally) agree with frame j's depth. It is asymmetric, in
[0, 1]. Poses are camera-to-world ``T_wc``; depths are metres along z; pixel centres at
integer coordinates, the image spanning [-0.5, W - 0.5] x [-0.5, H - 0.5].
"""

from __future__ import annotations

import numpy as np

from c3f_slam.geometry import backproject_pixels, invert_pose, project, transform_points


def grid_pixels(width: int, height: int, stride: int) -> np.ndarray:
    """(N, 2) integer pixel coordinates (u, v) of a grid with ``stride`` px spacing, centred."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    us = np.arange(stride // 2, width, stride)
    vs = np.arange(stride // 2, height, stride)
    u, v = np.meshgrid(us, vs)
    return np.stack([u.ravel(), v.ravel()], axis=-1)


def frustum_overlap(
    depth_i: np.ndarray | float,
    K_i: np.ndarray,
    T_wi: np.ndarray,
    T_wj: np.ndarray,
    size_j: tuple[int, int] | None = None,
    K_j: np.ndarray | None = None,
    depth_j: np.ndarray | None = None,
    depth_tol: float = 0.1,
    stride: int = 4,
    size_i: tuple[int, int] | None = None,
) -> float:
    """Share in [0, 1] of frame i's valid grid pixels seen by frame j.

    - ``depth_i``: (H, W) depth of frame i in metres (0/NaN = invalid), or one number: a
      fronto-parallel plane at that depth (for frames without depth; give ``size_i``).
    - ``T_wi``, ``T_wj``: camera-to-world poses; ``K_j``/``size_j`` = (width, height) default
      to frame i's.
    - ``depth_j``: if given, a point also needs |z_j - depth_j(u, v)| <= depth_tol * depth_j
      (relative tolerance, nearest pixel) to count: occluded or disagreeing points do not.
    Returns 0.0 when frame i has no valid pixel.
    """
    K_i = np.asarray(K_i, dtype=np.float64)
    if np.isscalar(depth_i) or np.ndim(depth_i) == 0:
        if size_i is None:
            raise ValueError("a scalar depth_i needs size_i = (width, height)")
        wi, hi = size_i
        uv = grid_pixels(wi, hi, stride)
        z = np.full(len(uv), float(depth_i))
    else:
        d = np.asarray(depth_i, dtype=np.float64)
        hi, wi = d.shape
        uv = grid_pixels(wi, hi, stride)
        z = d[uv[:, 1], uv[:, 0]]
    valid = np.isfinite(z) & (z > 0)
    if not valid.any():
        return 0.0
    p_i = backproject_pixels(uv[valid], z[valid], K_i)
    p_j = transform_points(invert_pose(T_wj) @ np.asarray(T_wi, dtype=np.float64), p_i)

    K_j = K_i if K_j is None else np.asarray(K_j, dtype=np.float64)
    if size_j is None:
        size_j = (depth_j.shape[1], depth_j.shape[0]) if depth_j is not None else (wi, hi)
    wj, hj = size_j
    uv_j, z_j = project(p_j, K_j)
    with np.errstate(invalid="ignore"):
        inside = (
            (z_j > 0)
            & (uv_j[:, 0] >= -0.5) & (uv_j[:, 0] < wj - 0.5)
            & (uv_j[:, 1] >= -0.5) & (uv_j[:, 1] < hj - 0.5)
        )
    if depth_j is not None and inside.any():
        dj = np.asarray(depth_j, dtype=np.float64)
        cols = np.clip(np.rint(uv_j[inside, 0]).astype(int), 0, wj - 1)
        rows = np.clip(np.rint(uv_j[inside, 1]).astype(int), 0, hj - 1)
        ref = dj[rows, cols]
        ok = np.isfinite(ref) & (ref > 0) & (np.abs(z_j[inside] - ref) <= depth_tol * ref)
        inside[np.flatnonzero(inside)[~ok]] = False
    return float(inside.sum() / valid.sum())
