"""Mutual-nearest-neighbour descriptor matching.

``metric="cosine"`` (ContraFeat): descriptors are L2-normalised and compared by cosine
similarity; the returned distance is the L2 distance of the unit vectors,
sqrt(2 - 2 cos), so that smaller is better for both metrics. ``metric="l2"`` (SIFT):
plain Euclidean distance.
"""

from __future__ import annotations

import numpy as np

METRICS = ("cosine", "l2")


def _normalise(d: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.maximum(n, 1e-12)


def descriptor_distances(desc_i: np.ndarray, desc_j: np.ndarray, metric: str = "cosine") -> np.ndarray:
    """(N_i, N_j) distance matrix (float32); see the module docstring for the metrics."""
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    a = np.asarray(desc_i, dtype=np.float32)
    b = np.asarray(desc_j, dtype=np.float32)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"descriptors must be (N, C) with the same C, got {a.shape} and {b.shape}")
    # in place, the same bits as 2 - 2 a.b (cosine) and |a|^2 + |b|^2 - 2 a.b (l2), then sqrt(max(., 0))
    if metric == "cosine":
        a, b = _normalise(a), _normalise(b)
        sq = a @ b.T
        sq *= -2.0
        sq += 2.0
    else:
        prod = a @ b.T
        prod *= 2.0
        sq = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :]
        sq -= prod
        del prod
    np.maximum(sq, 0.0, out=sq)
    return np.sqrt(sq, out=sq)


def mutual_nearest_neighbours(
    desc_i: np.ndarray,
    desc_j: np.ndarray,
    metric: str = "cosine",
    ratio: float | None = None,
    max_distance: float | None = None,
    allowed: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours between two descriptor sets.

    Args:
        desc_i, desc_j: (N_i, C) and (N_j, C) descriptors.
        metric: ``cosine`` (ContraFeat) or ``l2`` (SIFT).
        ratio: optional Lowe ratio test: keep a match when its distance is below
            ``ratio`` x the distance to the second-nearest neighbour (in j).
        max_distance: optional absolute distance cap.
        allowed: optional (N_i, N_j) bool mask of the pairs that may match (guided matching:
            the pairs near where a motion prior puts them); the nearest neighbours and the
            ratio test's second neighbour are taken among the allowed pairs only.

    Returns:
        (M, 2) int64 matches (index in i, index in j), sorted by distance (best first), and
        their (M,) float32 distances.
    """
    n_i, n_j = len(desc_i), len(desc_j)
    if n_i == 0 or n_j == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.float32)
    dist = descriptor_distances(desc_i, desc_j, metric)
    if allowed is not None:
        dist = np.where(allowed, dist, np.inf)
    nn_ij = dist.argmin(axis=1)
    nn_ji = dist.argmin(axis=0)
    a = np.arange(n_i)
    mutual = nn_ji[nn_ij] == a
    d_best = dist[a, nn_ij]
    keep = mutual
    if ratio is not None and n_j >= 2:
        rows = np.flatnonzero(keep)  # the second neighbour of the mutual rows only
        others = dist[rows]
        others[np.arange(len(rows)), nn_ij[rows]] = np.inf
        second = np.full(n_i, np.inf, dist.dtype)
        second[rows] = others.min(axis=1)  # the second-smallest distance of the row (ties included)
        keep = keep & (d_best < ratio * second)
    if max_distance is not None:
        keep = keep & (d_best <= max_distance)
    if allowed is not None:
        keep = keep & np.isfinite(d_best)
    a = a[keep]
    matches = np.stack([a, nn_ij[keep]], axis=1).astype(np.int64)
    d = d_best[keep].astype(np.float32)
    order = np.argsort(d, kind="stable")
    return matches[order], d[order]


def sample_descriptor_map(descriptor_map: np.ndarray, xy: np.ndarray, normalise: bool = True) -> np.ndarray:
    """(N, C) descriptors at (N, 2) pixel coordinates of a dense (C, H, W) map (e.g. ContraFeat ONNX output).

    Bilinear, pixel centres at integer coordinates, coordinates clamped to the image (the
    NumPy twin of ``c3f_models.contrafeat.network.sample_descriptors``); with ``normalise``
    the result is L2-normalised again.
    """
    m = np.asarray(descriptor_map, dtype=np.float32)
    c, h, w = m.shape
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        return np.zeros((0, c), np.float32)
    u = np.clip(xy[:, 0], 0, w - 1)
    v = np.clip(xy[:, 1], 0, h - 1)
    x0 = np.minimum(np.floor(u).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(v).astype(np.int64), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ax, ay = (u - x0)[:, None], (v - y0)[:, None]
    out = (m[:, y0, x0].T * (1 - ax) * (1 - ay) + m[:, y0, x1].T * ax * (1 - ay)
           + m[:, y1, x0].T * (1 - ax) * ay + m[:, y1, x1].T * ax * ay).astype(np.float32)
    return _normalise(out) if normalise else out
