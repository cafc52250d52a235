"""Ground-truth keypoint matches from depth, poses and intrinsics (docs/design.md, ContraFeat).

Each keypoint of frame i is lifted with its depth, moved into frame j with the known
poses (T_ji = inv(T_wj) @ T_wi), projected, and kept when it lands inside j and agrees
with j's depth there (otherwise it is occluded or has left the view); it is then paired
with the nearest keypoint of j within ``pixel_radius`` pixels, one-to-one.

This is the one implementation used by ContraFeat training, its evaluation and the SLAM
tests. Units: pixels, metres; poses camera-to-world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from c3f_slam.geometry import project, relative_pose, transform_points
from c3f_slam.matching.points import inside_image, lift_keypoints, sample_depth

#: a match is correct, and a ground-truth match exists, within this distance of the true position (pixels)
PIXEL_RADIUS = 2.0
#: a projected point is visible when the depth there agrees within this share (the occlusion test)
DEPTH_TOLERANCE = 0.05


@dataclass(frozen=True)
class Projection:
    """Where frame i's keypoints land in frame j.

    Attributes:
        uv: (N, 2) pixel coordinates in j (NaN where the keypoint has no depth in i or
            lands behind camera j).
        depth: (N,) z of the point in camera j, metres (NaN where unknown).
        visible: (N,) bool: has depth in i, lands inside j, and j's depth agrees (not occluded).
    """

    uv: np.ndarray
    depth: np.ndarray
    visible: np.ndarray


def _depth_agrees(z: np.ndarray, d: np.ndarray, tolerance: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return (d > 0) & np.isfinite(z) & (np.abs(z - d) <= tolerance * d)


def project_keypoints(
    kp_i: np.ndarray,
    depth_i: np.ndarray,
    depth_j: np.ndarray,
    K: np.ndarray,
    *,
    T_wi: np.ndarray,
    T_wj: np.ndarray,
    depth_tolerance: float = DEPTH_TOLERANCE,
    K_j: np.ndarray | None = None,
    depth_sampling: str = "bilinear",
) -> Projection:
    """Project frame i's keypoints (N, 2) into frame j and test their visibility there.

    Args:
        kp_i: (N, 2) pixel coordinates in i.
        depth_i, depth_j: (H, W) depth maps in metres (0 = none).
        K: 3x3 intrinsics of i (and of j unless ``K_j`` is given).
        T_wi, T_wj: camera-to-world poses.
        depth_tolerance: relative agreement |z - d_j| <= tol * d_j for "not occluded".
        depth_sampling: ``nearest`` or ``bilinear`` (edge-aware), for both depth maps.
    """
    K = np.asarray(K, dtype=np.float64)
    K_j = K if K_j is None else np.asarray(K_j, dtype=np.float64)
    pts_i = lift_keypoints(kp_i, depth_i, K, depth_sampling)
    pts_j = transform_points(relative_pose(T_wj, T_wi), pts_i)  # T_ji maps i into j
    uv, z = project(pts_j, K_j)
    h, w = np.asarray(depth_j).shape
    inside = inside_image(uv, w, h)
    d_j = np.zeros(len(uv))
    d_j[inside] = sample_depth(depth_j, uv[inside], depth_sampling)
    visible = inside & _depth_agrees(z, d_j, depth_tolerance)
    return Projection(uv=uv, depth=z, visible=visible)


def ground_truth_matches(
    kp_i: np.ndarray,
    kp_j: np.ndarray,
    depth_i: np.ndarray,
    depth_j: np.ndarray,
    *,
    K: np.ndarray,
    T_wi: np.ndarray,
    T_wj: np.ndarray,
    pixel_radius: float,
    depth_tolerance: float = DEPTH_TOLERANCE,
    K_j: np.ndarray | None = None,
    depth_sampling: str = "bilinear",
    return_projection: bool = False,
) -> np.ndarray | tuple[np.ndarray, Projection]:
    """(M, 2) int64 ground-truth matches (index in kp_i, index in kp_j).

    A keypoint a of i matches keypoint b of j when a is visible in j (see
    :func:`project_keypoints`), b is the nearest keypoint of j to a's projection and lies
    within ``pixel_radius`` pixels, and b's own depth agrees with the projected depth (b
    is on the same surface, not across a depth edge). Matches are one-to-one: a keypoint
    of j claimed by several keypoints of i goes to the closest projection. Rows are sorted
    by the index in i. With ``return_projection`` the :class:`Projection` comes too.
    ``pixel_radius`` has no default: it is the caller's setting (ContraFeat's
    ``model.ground_truth.pixel_radius``).
    """
    kp_i = np.asarray(kp_i, dtype=np.float64).reshape(-1, 2)
    kp_j = np.asarray(kp_j, dtype=np.float64).reshape(-1, 2)
    proj = project_keypoints(kp_i, depth_i, depth_j, K, T_wi=T_wi, T_wj=T_wj, depth_tolerance=depth_tolerance, K_j=K_j,
                             depth_sampling=depth_sampling)
    matches = np.zeros((0, 2), np.int64)
    cand = np.flatnonzero(proj.visible)
    if len(cand) and len(kp_j):
        dist, nn = cKDTree(kp_j).query(proj.uv[cand], k=1, distance_upper_bound=pixel_radius)
        ok = np.isfinite(dist)
        a, b, dist = cand[ok], nn[ok], dist[ok]
        d_b = sample_depth(depth_j, kp_j[b], depth_sampling)
        same_surface = _depth_agrees(proj.depth[a], d_b, depth_tolerance)
        a, b, dist = a[same_surface], b[same_surface], dist[same_surface]
        order = np.lexsort((a, dist))  # closest first
        _, first = np.unique(b[order], return_index=True)
        keep = order[first]
        matches = np.stack([a[keep], b[keep]], axis=1).astype(np.int64)
        matches = matches[np.argsort(matches[:, 0], kind="stable")]
    return (matches, proj) if return_projection else matches
