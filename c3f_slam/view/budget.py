"""How much geometry a view page carries, and decimation to that budget.

A page embeds its meshes (float32 positions, uint8 colours, uint32 indices, base64): about
:data:`BYTES_PER_TRIANGLE` bytes per triangle. Each mesh layer has a triangle budget
(:class:`ViewBudget`, defined with the view's other settings in :mod:`c3f_slam.view.settings`);
a mesh above it is decimated (Open3D quadric decimation, vertex colours averaged) and the page
links the full-resolution file. ``view.html``'s budget is ``budget`` of the view's settings
(default at most 250,000 triangles, about 7 MB), :data:`REPORT_BUDGET` the demo report's
(105,000 triangles, about 3 MB).
"""

from __future__ import annotations

import open3d as o3d

from c3f_slam.view.settings import BYTES_PER_TRIANGLE, REPORT_BUDGET, ViewBudget


def decimate(mesh: o3d.geometry.TriangleMesh, max_triangles: int) -> tuple[o3d.geometry.TriangleMesh, bool]:
    """``mesh`` with at most ``max_triangles`` triangles (quadric decimation, colours kept) and
    whether it was decimated."""
    if len(mesh.triangles) <= max_triangles:
        return mesh, False
    return mesh.simplify_quadric_decimation(int(max_triangles)), True


__all__ = ["BYTES_PER_TRIANGLE", "REPORT_BUDGET", "ViewBudget", "decimate"]
