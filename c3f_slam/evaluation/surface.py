"""Surface coverage of a reconstruction (docs/design.md, Evaluation).

- :func:`surface_coverage`: share of the ground-truth surface that the reconstruction reaches;
- :func:`coverage_mesh`: a copy of the ground-truth mesh painted seen / unseen.

Both meshes in the same (ground-truth) frame; lengths in metres, areas in m^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

SEEN_COLOUR = (0.55, 0.75, 0.55)  # grey-green
UNSEEN_COLOUR = (0.9, 0.1, 0.1)  # red


def sample_surface(mesh: o3d.geometry.TriangleMesh, n: int, seed: int = 0) -> tuple[np.ndarray, float]:
    """(n, 3) points uniformly distributed over the mesh area (deterministic); total area (m^2)."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.triangles, dtype=np.int64)
    if len(F) == 0:
        raise ValueError("ground-truth mesh has no triangles")
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = float(areas.sum())
    if total <= 0:
        raise ValueError("ground-truth mesh has zero area")
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(F), size=n, p=areas / total)
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    pts = (1 - r1)[:, None] * a[tri] + (r1 * (1 - r2))[:, None] * b[tri] + (r1 * r2)[:, None] * c[tri]
    return pts, total


def distance_to_mesh(points: np.ndarray, mesh: o3d.geometry.TriangleMesh) -> np.ndarray:
    """Unsigned distance (m) from each point to the nearest triangle; inf for an empty mesh."""
    pts = np.asarray(points, dtype=np.float32)
    if len(mesh.triangles) == 0:
        return np.full(len(pts), np.inf)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_distance(o3d.core.Tensor(pts)).numpy().astype(np.float64)


@dataclass
class CoverageResult:
    """Share of the ground-truth area within ``threshold`` metres of the reconstruction."""

    share: float
    threshold: float
    gt_area_m2: float
    n_samples: int

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def surface_coverage(
    gt_mesh: o3d.geometry.TriangleMesh,
    recon_mesh: o3d.geometry.TriangleMesh,
    threshold: float = 0.0025,
    n_samples: int = 100_000,
    seed: int = 0,
) -> CoverageResult:
    """Coverage: share of points sampled uniformly on the ground-truth surface that lie within
    ``threshold`` metres (default 2.5 mm, about 2.5 voxels of the colon TSDF) of the
    reconstructed mesh. Both meshes in the same (ground-truth) frame: align the
    reconstruction first (e.g. with the ATE's Sim(3))."""
    pts, area = sample_surface(gt_mesh, n_samples, seed)
    d = distance_to_mesh(pts, recon_mesh)
    return CoverageResult(float(np.mean(d <= threshold)), float(threshold), area, int(n_samples))


def coverage_mesh(
    gt_mesh: o3d.geometry.TriangleMesh,
    recon_mesh: o3d.geometry.TriangleMesh,
    threshold: float = 0.0025,
    max_edge: float | None = None,
) -> o3d.geometry.TriangleMesh:
    """Copy of the ground-truth mesh with vertices painted seen (grey-green) or unseen (red).

    A vertex is seen when it lies within ``threshold`` of the reconstruction. With
    ``max_edge`` (metres) the copy is midpoint-subdivided until no edge is longer (at most
    4 rounds), so that the painting is finer than the ground-truth tessellation.
    """
    mesh = o3d.geometry.TriangleMesh(gt_mesh)
    if max_edge is not None:
        for _ in range(4):
            V, F = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
            e = np.linalg.norm(V[F] - V[np.roll(F, 1, axis=1)], axis=2)
            if len(F) == 0 or e.max() <= max_edge:
                break
            mesh = mesh.subdivide_midpoint(1)
    d = distance_to_mesh(np.asarray(mesh.vertices), recon_mesh)
    colours = np.where((d <= threshold)[:, None], np.array(SEEN_COLOUR), np.array(UNSEEN_COLOUR))
    mesh.vertex_colors = o3d.utility.Vector3dVector(colours)
    return mesh
