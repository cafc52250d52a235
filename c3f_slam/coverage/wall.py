"""A generalized-cylinder model of the complete colon wall along the centreline.

The wall is ``r(s, theta)``: the distance from the centreline at arc length ``s`` and angle
``theta`` (:mod:`.centreline`), on a grid of cells (``cell_length`` metres x
``2 pi / angle_bins``). :func:`fit_wall` takes the median distance of the surface points
(mesh vertices and triangle centroids) that fall into each cell; cells without any (wall
that was never reconstructed) are interpolated: along the centreline across short gaps,
then around it, then along it again. The mean colour of the points is kept per cell for the
unrolled map. Lengths in metres, areas in m^2 (of the unrolled wall: :meth:`WallModel.areas`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from c3f_slam.coverage.centreline import Centreline


@dataclass
class WallModel:
    """``radius`` (S, A) metres per cell, ``measured`` (S, A) cells with surface points,
    ``colour`` (S, A, 3) in [0, 1] (NaN where unmeasured or uncoloured), ``anchors`` (S, A, 3)
    the surface point of median radius of each measured cell (NaN elsewhere)."""

    centreline: Centreline
    radius: np.ndarray
    measured: np.ndarray
    colour: np.ndarray
    anchors: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.radius.shape

    @property
    def cell_length(self) -> float:
        return self.centreline.length / self.shape[0]

    @property
    def cell_angle(self) -> float:
        return 2 * np.pi / self.shape[1]

    @property
    def s_centres(self) -> np.ndarray:
        return (np.arange(self.shape[0]) + 0.5) * self.cell_length

    @property
    def theta_centres(self) -> np.ndarray:
        return -np.pi + (np.arange(self.shape[1]) + 0.5) * self.cell_angle

    def points(self, radius: np.ndarray | None = None) -> np.ndarray:
        """(S, A, 3) world points of the cell centres (at ``radius``, default the wall's)."""
        s, th = np.meshgrid(self.s_centres, self.theta_centres, indexing="ij")
        return self.centreline.wall_points(s, th, self.radius if radius is None else radius)

    def probe_points(self) -> np.ndarray:
        """(S, A, 3) the point whose visibility stands for each cell: a real surface point where
        the cell has one (on steep fold flanks the median radius at the cell centre can lie in
        the lumen, in view of cameras that cannot see the wall), else the model's."""
        return np.where(self.measured[..., None], self.anchors, self.points())

    def areas(self) -> np.ndarray:
        """(S, A) area of each cell on the unrolled wall (m^2): cell length x angle x the mean
        radius of its ring. Folds are not unfolded: a fold's flanks, whose true area the
        reconstruction cannot know where they were never seen, weigh as the wall they stand on."""
        ring = np.mean(self.radius, axis=1, keepdims=True)
        return np.broadcast_to(ring * self.cell_length * self.cell_angle, self.shape).copy()


def surface_samples(mesh: o3d.geometry.TriangleMesh) -> tuple[np.ndarray, np.ndarray | None]:
    """Vertices and triangle centroids of ``mesh`` (K, 3) with their colours (K, 3) or None."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.triangles, dtype=np.int64)
    pts = np.concatenate([V, V[F].mean(axis=1)]) if len(F) else V
    if not mesh.has_vertex_colors():
        return pts, None
    C = np.asarray(mesh.vertex_colors, dtype=np.float64)
    return pts, (np.concatenate([C, C[F].mean(axis=1)]) if len(F) else C)


def fit_wall(centreline: Centreline, points: np.ndarray, *, colours: np.ndarray | None, cell_length: float,
             angle_bins: int, max_radius: float, fill_gap: float) -> WallModel | None:
    """The wall model from surface ``points`` (K, 3) and their ``colours``; None when no point
    lies on the wall of the explored segment."""
    n_s = max(2, int(round(centreline.length / cell_length)))
    s, theta, r, valid = centreline.locate(points)
    valid &= r <= max_radius
    if not valid.any():
        return None
    i = np.clip((s[valid] / centreline.length * n_s).astype(int), 0, n_s - 1)
    j = np.clip(((theta[valid] + np.pi) / (2 * np.pi) * angle_bins).astype(int), 0, angle_bins - 1)
    cell, rv = i * angle_bins + j, r[valid]
    radius, which = _cell_medians(cell, rv, n_s * angle_bins)
    radius = radius.reshape(n_s, angle_bins)
    measured = np.isfinite(radius)
    anchors = np.full((n_s * angle_bins, 3), np.nan)
    anchors[which >= 0] = points[valid][which[which >= 0]]
    colour = np.full((n_s * angle_bins, 3), np.nan)
    if colours is not None:
        count = np.bincount(cell, minlength=n_s * angle_bins)
        for c in range(3):
            total = np.bincount(cell, weights=colours[valid, c], minlength=n_s * angle_bins)
            colour[count > 0, c] = total[count > 0] / count[count > 0]
    gap_cells = int(round(fill_gap / (centreline.length / n_s)))
    return WallModel(centreline, fill_radius(radius, gap_cells), measured, colour.reshape(n_s, angle_bins, 3),
                     anchors.reshape(n_s, angle_bins, 3))


def _cell_medians(cell: np.ndarray, values: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Median of ``values`` per cell id (NaN for empty cells) and the index of the (lower)
    median element in ``values`` (-1 for empty cells)."""
    order = np.lexsort((values, cell))
    cell_s, values_s = cell[order], values[order]
    counts = np.bincount(cell_s, minlength=n_cells)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out, which = np.full(n_cells, np.nan), np.full(n_cells, -1)
    has = counts > 0
    lo = starts[has] + (counts[has] - 1) // 2
    hi = starts[has] + counts[has] // 2
    out[has] = 0.5 * (values_s[lo] + values_s[hi])
    which[has] = order[lo]
    return out, which


def _interp_gaps(col: np.ndarray, max_gap: int | None, period: float | None = None) -> np.ndarray:
    """NaNs of a 1-D array interpolated linearly from known neighbours; with ``max_gap`` only
    runs bounded on both sides and at most that long; ``period``: circular."""
    known = np.flatnonzero(np.isfinite(col))
    if len(known) == 0 or len(known) == len(col):
        return col
    x = np.arange(len(col), dtype=np.float64)
    if period is not None:
        return np.interp(x, known, col[known], period=period)
    out = col.copy()
    filled = np.interp(x, known, col[known])
    missing = ~np.isfinite(col)
    if max_gap is None:
        out[missing] = filled[missing]
        return out
    prev_k = np.maximum.accumulate(np.where(np.isfinite(col), x, -1))
    next_k = np.minimum.accumulate(np.where(np.isfinite(col), x, np.inf)[::-1])[::-1]
    ok = missing & (prev_k >= 0) & np.isfinite(next_k) & (next_k - prev_k - 1 <= max_gap)
    out[ok] = filled[ok]
    return out


def fill_radius(radius: np.ndarray, max_gap: int) -> np.ndarray:
    """(S, A) radii with NaNs filled: along s across gaps of at most ``max_gap`` cells, then
    around (circular), then along s everywhere (rows with no point at all)."""
    r = np.array(radius, dtype=np.float64)
    for j in range(r.shape[1]):
        r[:, j] = _interp_gaps(r[:, j], max_gap)
    for i in range(r.shape[0]):
        r[i] = _interp_gaps(r[i], None, period=r.shape[1])
    for j in range(r.shape[1]):
        r[:, j] = _interp_gaps(r[:, j], None)
    return r
