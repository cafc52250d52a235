"""How much geometry a view page carries, and decimation to that budget.

A page embeds its meshes (float32 positions, uint8 colours, uint32 indices, base64): about
26 bytes per triangle. Each mesh layer has a triangle budget; a mesh above it is decimated
(Open3D quadric decimation, vertex colours averaged) and the page links the full-resolution
file. :data:`PAGE_BUDGET` is ``view.html``'s (at most 250,000 triangles, about 7 MB),
:data:`REPORT_BUDGET` the demo report's (105,000 triangles, about 3 MB).
"""

from __future__ import annotations

from dataclasses import dataclass

import open3d as o3d

BYTES_PER_TRIANGLE = 26  #: base64 page bytes per triangle of a typical TSDF mesh (measured, docs/view.md)


@dataclass(frozen=True)
class ViewBudget:
    """Triangles per mesh layer: the reconstruction, the unseen wall patches, the ground-truth
    surface, and all components together."""

    surface: int = 150_000
    unseen: int = 30_000
    gt_surface: int = 50_000
    components: int = 20_000

    @property
    def triangles(self) -> int:
        return self.surface + self.unseen + self.gt_surface + self.components

    @property
    def approx_mb(self) -> float:
        """Page geometry at the full budget, MB (1e6 bytes)."""
        return self.triangles * BYTES_PER_TRIANGLE / 1e6


PAGE_BUDGET = ViewBudget()
REPORT_BUDGET = ViewBudget(surface=60_000, unseen=15_000, gt_surface=20_000, components=10_000)


def decimate(mesh: o3d.geometry.TriangleMesh, max_triangles: int) -> tuple[o3d.geometry.TriangleMesh, bool]:
    """``mesh`` with at most ``max_triangles`` triangles (quadric decimation, colours kept) and
    whether it was decimated."""
    if len(mesh.triangles) <= max_triangles:
        return mesh, False
    return mesh.simplify_quadric_decimation(int(max_triangles)), True
