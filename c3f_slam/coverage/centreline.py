"""The centreline of the explored colon segment, from the registered camera path.

The camera path wanders across the lumen, turns to the wall, goes back and forth; its
*forward progress* follows the colon. :func:`centreline_from_path` keeps a node each time
the camera has moved ``node_spacing`` beyond the last node along the current direction of
travel (revisits and sideways motion add nothing), smooths the nodes and resamples them at
equal arc length. Arc length ``s`` (metres) is 0 at the first camera position and ends at
the farthest one: the explored segment. Angles ``theta`` (radians, [-pi, pi)) are measured
in the parallel-transport frame (N, B) around the tangent T
(:func:`c3f_slam.geometry.transport_frames`):

    P(s, theta, r) = C(s) + r (cos(theta) N(s) + sin(theta) B(s))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree

from c3f_slam.geometry import transport_frames


@dataclass
class Centreline:
    """Samples (M, 3) ``points`` at arc lengths ``s`` (M,), unit tangents ``T``, frame ``N``, ``B``."""

    points: np.ndarray
    s: np.ndarray
    T: np.ndarray
    N: np.ndarray
    B: np.ndarray

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def locate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(s, theta, r, valid) of world ``points`` (K, 3): in the normal plane of the nearest
        sample; valid when 0 <= s <= length and the point lies within one sample spacing of
        that plane."""
        p = np.asarray(points, dtype=np.float64)
        _, k = cKDTree(self.points).query(p)
        d = p - self.points[k]
        a = np.einsum("ij,ij->i", d, self.T[k])
        perp = d - a[:, None] * self.T[k]
        s = self.s[k] + a
        theta = np.arctan2(np.einsum("ij,ij->i", perp, self.B[k]), np.einsum("ij,ij->i", perp, self.N[k]))
        spacing = self.s[1] - self.s[0]
        valid = (s >= 0) & (s <= self.length) & (np.abs(a) <= spacing)
        return s, theta, np.linalg.norm(perp, axis=1), valid

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre, N and B at arc lengths ``s`` (linear interpolation of the samples; N, B not re-normalised)."""
        s = np.asarray(s, dtype=np.float64)
        out = [np.stack([np.interp(s, self.s, a[:, i]) for i in range(3)], axis=-1)
               for a in (self.points, self.N, self.B)]
        return out[0], out[1], out[2]

    def wall_points(self, s: np.ndarray, theta: np.ndarray, r: np.ndarray) -> np.ndarray:
        """World points P(s, theta, r) for arrays of the same shape (..., 3)."""
        c, n, b = self.at(s)
        return c + r[..., None] * (np.cos(theta)[..., None] * n + np.sin(theta)[..., None] * b)


def forward_nodes(positions: np.ndarray, spacing: float) -> np.ndarray:
    """Camera positions (F, 3), in time order, reduced to nodes of forward progress: a position
    becomes a node when it lies at least ``spacing`` beyond the last node along the direction
    of travel (the mean direction over the last three nodes)."""
    P = np.asarray(positions, dtype=np.float64)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) == 0:
        return P.reshape(0, 3)
    nodes, tangent, best, best_step = [P[0]], None, None, 0.0
    for p in P[1:]:
        d = p - nodes[-1]
        step = np.linalg.norm(d) if tangent is None else d @ tangent
        if step >= spacing:
            nodes.append(p)
            t = nodes[-1] - nodes[max(0, len(nodes) - 4)]
            tangent, best, best_step = t / np.linalg.norm(t), None, 0.0
        elif step > best_step:
            best, best_step = p, step
    if best is not None and best_step > 0.2 * spacing:  # the farthest position, short of a full spacing
        nodes.append(best)
    return np.array(nodes)


def smooth_path(nodes: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing (sigma in nodes) that keeps both end points and straight lines: the
    path is extended past each end by its point reflection before filtering."""
    pad = min(len(nodes) - 1, int(np.ceil(4 * sigma)))
    if pad < 1 or sigma <= 0:
        return nodes
    ext = np.concatenate([2 * nodes[0] - nodes[pad:0:-1], nodes, 2 * nodes[-1] - nodes[-2:-pad - 2:-1]])
    return gaussian_filter1d(ext, sigma, axis=0, mode="nearest")[pad:pad + len(nodes)]


def centreline_from_path(positions: np.ndarray, spacing: float, smoothing: float,
                         sample: float) -> Centreline | None:
    """The centreline of camera ``positions`` (F, 3, time order, metres): forward nodes every
    ``spacing``, Gaussian-smoothed with sigma ``smoothing`` metres, resampled every ~``sample``
    metres. None when the camera moved less than two node spacings forward."""
    nodes = forward_nodes(positions, spacing)
    if len(nodes) < 3:
        return None
    nodes = smooth_path(nodes, smoothing / spacing)
    seg = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    nodes, arc = nodes[keep], np.concatenate([[0.0], np.cumsum(seg[seg > 1e-9])])
    n = max(2, int(np.ceil(arc[-1] / sample)) + 1)
    s = np.linspace(0.0, arc[-1], n)
    pts = np.stack([np.interp(s, arc, nodes[:, i]) for i in range(3)], axis=-1)
    T = np.gradient(pts, axis=0)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    N, B = transport_frames(T)
    return Centreline(pts, s, T, N, B)
