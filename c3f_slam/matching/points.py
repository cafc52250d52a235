"""Depth at keypoints and the keypoints' 3D points (camera frame, metres).

Pixel (u, v) with integer coordinates is the pixel centre; an image covers
[-0.5, W-0.5] x [-0.5, H-0.5]. Depth is z in metres, 0 = no depth.
"""

from __future__ import annotations

import numpy as np

from c3f_slam.geometry import backproject_pixels

DEPTH_SAMPLING = ("nearest", "bilinear")


def inside_image(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N,) bool: pixel coordinates inside the image area [-0.5, W-0.5) x [-0.5, H-0.5)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        return (
            np.isfinite(uv).all(axis=1)
            & (uv[:, 0] >= -0.5) & (uv[:, 0] < width - 0.5)
            & (uv[:, 1] >= -0.5) & (uv[:, 1] < height - 0.5)
        )


def sample_depth(
    depth: np.ndarray, uv: np.ndarray, mode: str = "bilinear", edge_tolerance: float = 0.05
) -> np.ndarray:
    """(N,) depth (metres) at (N, 2) pixel coordinates; 0 where there is none.

    ``nearest`` reads the pixel containing (u, v). ``bilinear`` interpolates the four
    neighbouring pixel centres (clamped at the border) when all four have depth and agree
    within ``edge_tolerance`` (relative: max/min - 1); across a depth edge or a hole it falls
    back to ``nearest`` so that two surfaces are never averaged. Outside the image: 0.
    """
    if mode not in DEPTH_SAMPLING:
        raise ValueError(f"depth sampling mode must be one of {DEPTH_SAMPLING}, got {mode!r}")
    d = np.asarray(depth, dtype=np.float64)
    h, w = d.shape
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    out = np.zeros(len(uv), np.float64)
    ok = inside_image(uv, w, h)
    if not ok.any():
        return out
    u, v = uv[ok, 0], uv[ok, 1]
    xn = np.clip(np.floor(u + 0.5).astype(np.int64), 0, w - 1)
    yn = np.clip(np.floor(v + 0.5).astype(np.int64), 0, h - 1)
    near = d[yn, xn]
    if mode == "nearest":
        vals = near
    else:
        uc, vc = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
        x0 = np.minimum(np.floor(uc).astype(np.int64), max(w - 2, 0))
        y0 = np.minimum(np.floor(vc).astype(np.int64), max(h - 2, 0))
        x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
        ax, ay = uc - x0, vc - y0
        q = np.stack([d[y0, x0], d[y0, x1], d[y1, x0], d[y1, x1]], axis=1)
        wts = np.stack([(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay], axis=1)
        bil = (q * wts).sum(axis=1)
        qmin, qmax = q.min(axis=1), q.max(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            smooth = (qmin > 0) & (qmax <= qmin * (1.0 + edge_tolerance))
        vals = np.where(smooth, bil, near)
    vals = np.where(np.isfinite(vals) & (vals > 0), vals, 0.0)
    out[ok] = vals
    return out


def lift_keypoints(
    xy: np.ndarray, depth: np.ndarray, K: np.ndarray, mode: str = "bilinear"
) -> np.ndarray:
    """(N, 3) camera-frame points (metres) of keypoints; rows are NaN where there is no depth."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    z = sample_depth(depth, xy, mode)
    pts = backproject_pixels(xy, z, np.asarray(K, dtype=np.float64))
    pts[z <= 0] = np.nan
    return pts
