"""Which wall points some frame observed: in its image, in the fused depth range, not occluded.

Frames are pinhole cameras (``K``, ``width`` x ``height``; pixel centres at integer
coordinates, the image spanning [-0.5, W - 0.5] x [-0.5, H - 0.5]) with camera-to-world
poses ``T_wc``. A point is hidden when a ray cast from the camera centre towards it
(Open3D ``RaycastingScene`` on the reconstructed — or, for the truth, the true — surface)
stops before it by more than the tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from c3f_slam.geometry import invert_pose, project, transform_points


@dataclass(frozen=True, kw_only=True)
class ViewSettings:
    """Image size (pixels), depth range (metres, along z) and occlusion tolerance
    (``tol`` + ``tol_rel`` x distance, metres) of the visibility test; ``mask`` (height, width)
    bool: the pixels that observe (the tissue area, :mod:`c3f_slam.frames.tissue`; None: all)."""

    width: int
    height: int
    depth_min: float
    depth_max: float
    tol: float = 0.001
    tol_rel: float = 0.02
    mask: np.ndarray | None = field(default=None, compare=False, repr=False)


def raycasting_scene(mesh: o3d.geometry.TriangleMesh) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    if len(mesh.triangles):
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def subsample_poses(poses: np.ndarray, max_frames: int) -> np.ndarray:
    """At most ``max_frames`` of the finite camera-to-world ``poses`` (F, 4, 4), evenly spaced."""
    P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    P = P[np.all(np.isfinite(P), axis=(1, 2))]
    if len(P) > max_frames:
        P = P[np.linspace(0, len(P) - 1, max_frames).round().astype(int)]
    return P


def in_view(points: np.ndarray, T_wc: np.ndarray, K: np.ndarray, view: ViewSettings) -> np.ndarray:
    """(N,) bool: world ``points`` inside the image of the camera at ``T_wc`` (inside
    ``view.mask`` when given) and its depth range."""
    pc = transform_points(invert_pose(T_wc), points)
    uv, z = project(pc, K)
    with np.errstate(invalid="ignore"):
        ok = ((z >= view.depth_min) & (z <= view.depth_max)
              & (uv[:, 0] >= -0.5) & (uv[:, 0] < view.width - 0.5)
              & (uv[:, 1] >= -0.5) & (uv[:, 1] < view.height - 0.5))
    if view.mask is not None and ok.any():
        i = np.flatnonzero(ok)
        px = np.rint(uv[i]).astype(np.int64)
        ok[i] = view.mask[np.clip(px[:, 1], 0, view.height - 1), np.clip(px[:, 0], 0, view.width - 1)]
    return ok


def observed(points: np.ndarray, poses: np.ndarray, K: np.ndarray, view: ViewSettings,
             scene: o3d.t.geometry.RaycastingScene, chunk: int = 16) -> np.ndarray:
    """(N,) bool: each world point (N, 3) is observed by at least one of ``poses``
    (camera-to-world (F, 4, 4)). Frames are taken ``chunk`` at a time; points already
    observed are not tested again."""
    pts = np.asarray(points, dtype=np.float64)
    seen = np.zeros(len(pts), dtype=bool)
    for start in range(0, len(poses), chunk):
        idx, origins = [], []
        for T in poses[start:start + chunk]:
            cand = np.flatnonzero(~seen & in_view(pts, T, K, view))
            idx.append(cand)
            origins.append(np.broadcast_to(T[:3, 3], (len(cand), 3)))
        idx_all = np.concatenate(idx)
        if len(idx_all) == 0:
            continue
        seen[idx_all[_unoccluded(pts[idx_all], np.concatenate(origins), view, scene)]] = True
    return seen


def _unoccluded(points: np.ndarray, origins: np.ndarray, view: ViewSettings,
                scene: o3d.t.geometry.RaycastingScene) -> np.ndarray:
    """(N,) bool: the ray from each origin reaches its point (within the tolerance)."""
    d = points - origins
    dist = np.linalg.norm(d, axis=1)
    rays = np.concatenate([origins, d / dist[:, None]], axis=1).astype(np.float32)
    t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return t_hit >= dist - (view.tol + view.tol_rel * dist)
