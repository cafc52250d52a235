"""Offscreen renders of a triangle mesh with Open3D's ``RaycastingScene`` (no display, no GPU).

Each pixel's ray hits a triangle; its colour is the vertex colours interpolated at the hit
(barycentric), shaded by a light at the eye (two-sided Lambert: the colon wall is seen from
inside and outside). Coordinates are metres; images are (H, W, 3) uint8 RGB.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

BACKGROUND = (255, 255, 255)


def _principal_axes(points: np.ndarray) -> np.ndarray:
    """(3, 3) rows: the point cloud's principal directions, longest first."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred[:: max(1, len(centred) // 20000)], full_matrices=False)
    return vt


def view_directions(mesh: o3d.geometry.TriangleMesh) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, direction from the centre to the eye, up vector) of three views: two side views
    across the longest axis and an oblique one."""
    a = _principal_axes(np.asarray(mesh.vertices))
    oblique = a[0] + a[1] + a[2]
    return [("side", a[1], a[2]), ("top", a[2], a[1]), ("oblique", oblique / np.linalg.norm(oblique), a[2])]


def render(mesh: o3d.geometry.TriangleMesh, direction: np.ndarray, up: np.ndarray, size: int = 360,
           fov_deg: float = 40.0) -> np.ndarray:
    """(size, size, 3) uint8 image of ``mesh`` seen from ``direction`` (unit, centre -> eye)."""
    verts = np.asarray(mesh.vertices)
    colours = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else np.full_like(verts, 0.8)
    tris = np.asarray(mesh.triangles)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris.astype(np.uint32)))
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    eye = centre + direction * radius / np.tan(np.radians(fov_deg) / 2) * 0.9
    rays = scene.create_rays_pinhole(fov_deg=fov_deg, center=centre.tolist(), eye=eye.tolist(), up=up.tolist(),
                                     width_px=size, height_px=size)
    hit = scene.cast_rays(rays)
    ids = hit["primitive_ids"].numpy().astype(np.int64)
    ok = ids != np.iinfo(np.uint32).max
    img = np.empty((size, size, 3), np.float64)
    img[:] = np.array(BACKGROUND) / 255.0
    uv = hit["primitive_uvs"].numpy()[ok]
    t = tris[ids[ok]]
    w = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
    col = np.einsum("nk,nkc->nc", w, colours[t])
    dirs = rays.numpy()[..., 3:][ok]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lambert = np.abs(np.sum(hit["primitive_normals"].numpy()[ok] * dirs, axis=1))
    img[ok] = col * (0.3 + 0.7 * lambert)[:, None]
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def crop_near(mesh: o3d.geometry.TriangleMesh, points: np.ndarray, margin: float) -> o3d.geometry.TriangleMesh:
    """The part of ``mesh`` inside the bounding box of ``points`` (N, 3) grown by ``margin`` metres."""
    box = o3d.geometry.AxisAlignedBoundingBox(points.min(axis=0) - margin, points.max(axis=0) + margin)
    return mesh.crop(box)


def render_views(mesh: o3d.geometry.TriangleMesh, size: int = 360) -> list[tuple[str, np.ndarray]]:
    """Renders of ``mesh`` from :func:`view_directions` (empty list for an empty mesh)."""
    if len(mesh.triangles) == 0:
        return []
    mesh.compute_triangle_normals()
    return [(name, render(mesh, d, up, size)) for name, d, up in view_directions(mesh)]
