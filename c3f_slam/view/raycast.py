"""Offscreen renders of a coloured triangle mesh with Open3D's ``RaycastingScene`` (CPU, no display).

Each pixel's ray hits a triangle; its colour is the vertex colours interpolated at the hit
(barycentric), shaded by a light at the eye (two-sided Lambert: the colon wall is seen from
inside and outside). Coordinates are metres; images are (H, W, 3) uint8 RGB; pinhole cameras
follow the project's convention (pixel centres at integer coordinates, camera +z forward,
camera-to-world poses). The demo's still renders and the view's videos both use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

BACKGROUND = (255, 255, 255)  #: the still renders' background
NO_HIT = np.iinfo(np.uint32).max  #: Open3D's primitive id of a ray that hit nothing


@dataclass
class MeshScene:
    """A mesh's arrays and its ray-casting scene, built once and cast many times."""

    vertices: np.ndarray  #: (V, 3) metres
    triangles: np.ndarray  #: (T, 3) vertex indices
    colours: np.ndarray  #: (V, 3) RGB in [0, 1]
    scene: o3d.t.geometry.RaycastingScene

    @classmethod
    def of(cls, mesh: o3d.geometry.TriangleMesh) -> MeshScene:
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        tris = np.asarray(mesh.triangles, dtype=np.int64)
        colours = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else np.full_like(verts, 0.8)
        scene = o3d.t.geometry.RaycastingScene()
        if len(tris):
            scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris.astype(np.uint32)))
        return cls(verts, tris, colours, scene)

    def cast(self, rays: np.ndarray) -> dict[str, np.ndarray]:
        """``rays`` (..., 6) origin + direction: Open3D's hit record as NumPy arrays."""
        hit = self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)))
        return {k: v.numpy() for k, v in hit.items()}

    def shade(self, rays: np.ndarray, hit: dict[str, np.ndarray], background=BACKGROUND,
              falloff: float | None = None, ambient: float = 0.3) -> np.ndarray:
        """(..., 3) uint8: interpolated vertex colour x (ambient + (1 - ambient) Lambert) at each hit,
        ``background`` elsewhere; ``falloff`` (metres): also dim by 1 / (1 + (distance / falloff)^2),
        as an endoscope's light does."""
        ids = hit["primitive_ids"].astype(np.int64)
        ok = ids != NO_HIT
        img = np.empty(ids.shape + (3,), np.float64)
        img[:] = np.asarray(background, np.float64) / 255.0
        uv = hit["primitive_uvs"][ok]
        w = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
        col = np.einsum("nk,nkc->nc", w, self.colours[self.triangles[ids[ok]]])
        dirs = rays[..., 3:][ok].astype(np.float64)
        norm = np.linalg.norm(dirs, axis=1, keepdims=True)
        light = ambient + (1 - ambient) * np.abs(np.sum(hit["primitive_normals"][ok] * dirs / norm, axis=1))
        if falloff is not None:
            light = light / (1 + (hit["t_hit"][ok] * norm[:, 0] / falloff) ** 2)
        img[ok] = col * light[:, None]
        return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def principal_axes(points: np.ndarray) -> np.ndarray:
    """(3, 3) rows: the point cloud's principal directions, longest first."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred[:: max(1, len(centred) // 20000)], full_matrices=False)
    return vt


def pinhole_rays(K: np.ndarray, T_wc: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W, 6) rays of a pinhole camera: origin the camera centre, direction R K^-1 [u, v, 1]
    (so a ray's parameter at a hit is that point's depth along the optical axis, metres)."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    dirs = pix @ np.linalg.inv(K).T @ np.asarray(T_wc[:3, :3], np.float64).T
    origin = np.broadcast_to(np.asarray(T_wc[:3, 3], np.float64), dirs.shape)
    return np.concatenate([origin, dirs], axis=-1)


def render_pinhole(ms: MeshScene, K: np.ndarray, T_wc: np.ndarray, width: int, height: int,
                   background=(0, 0, 0), falloff: float | None = None,
                   ambient: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """The mesh seen by the camera ``K`` at ``T_wc``: (H, W, 3) uint8 RGB (on ``background``; see
    :meth:`MeshScene.shade`) and (H, W) float32 depth along the optical axis in metres (0 where
    no surface)."""
    rays = pinhole_rays(K, T_wc, width, height)
    hit = ms.cast(rays)
    depth = np.where(np.isfinite(hit["t_hit"]), hit["t_hit"], 0.0).astype(np.float32)
    return ms.shade(rays, hit, background, falloff, ambient), depth


def scale_intrinsics(K: np.ndarray, factor: float) -> np.ndarray:
    """``K`` of the same camera with images ``factor`` times as large (pixel centres at integers)."""
    S = np.diag([factor, factor, 1.0])
    S[:2, 2] = (factor - 1) / 2
    return S @ np.asarray(K, np.float64)


def crop_near(mesh: o3d.geometry.TriangleMesh, points: np.ndarray, margin: float) -> o3d.geometry.TriangleMesh:
    """The part of ``mesh`` inside the bounding box of ``points`` (N, 3) grown by ``margin`` metres."""
    box = o3d.geometry.AxisAlignedBoundingBox(points.min(axis=0) - margin, points.max(axis=0) + margin)
    return mesh.crop(box)
