"""Offscreen renders of a triangle mesh from three viewpoints around it (Open3D ``RaycastingScene``,
no display, no GPU; the ray casting and shading are :mod:`c3f_slam.view.raycast`'s).

Coordinates are metres; images are (H, W, 3) uint8 RGB on a white background.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from c3f_slam.view.raycast import MeshScene, crop_near, principal_axes

__all__ = ["crop_near", "render", "render_views", "view_directions"]


def view_directions(mesh: o3d.geometry.TriangleMesh) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, direction from the centre to the eye, up vector) of three views: two side views
    across the longest axis and an oblique one."""
    a = principal_axes(np.asarray(mesh.vertices))
    oblique = a[0] + a[1] + a[2]
    return [("side", a[1], a[2]), ("top", a[2], a[1]), ("oblique", oblique / np.linalg.norm(oblique), a[2])]


def render(mesh: o3d.geometry.TriangleMesh, direction: np.ndarray, up: np.ndarray, size: int = 360,
           fov_deg: float = 40.0) -> np.ndarray:
    """(size, size, 3) uint8 image of ``mesh`` seen from ``direction`` (unit, centre -> eye)."""
    ms = MeshScene.of(mesh)
    lo, hi = ms.vertices.min(axis=0), ms.vertices.max(axis=0)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    eye = centre + direction * radius / np.tan(np.radians(fov_deg) / 2) * 0.9
    rays = ms.scene.create_rays_pinhole(fov_deg=fov_deg, center=centre.tolist(), eye=eye.tolist(), up=up.tolist(),
                                        width_px=size, height_px=size).numpy()
    return ms.shade(rays, ms.cast(rays))


def render_views(mesh: o3d.geometry.TriangleMesh, size: int = 360) -> list[tuple[str, np.ndarray]]:
    """Renders of ``mesh`` from :func:`view_directions` (empty list for an empty mesh)."""
    if len(mesh.triangles) == 0:
        return []
    mesh.compute_triangle_normals()
    return [(name, render(mesh, d, up, size)) for name, d, up in view_directions(mesh)]
