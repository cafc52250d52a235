"""The unseen-wall estimate kept up to date frame by frame (the live view: docs/live.md).

The cells are those of the estimate at the end of a run (:mod:`.estimate`): ``cell_length``
metres of centreline by ``angle_bins`` angles, shares of wall area, segments of ``segment``
metres from the first camera position. They are built as the camera moves:

- the centreline grows from the camera path by forward nodes (the rule of
  :func:`.centreline.forward_nodes`); a node is smoothed (a centred Gaussian of
  ``coverage.smoothing``, cut at two sigma) once the nodes it needs exist, so rows of cells
  appear about ``2 * smoothing`` behind the farthest camera position and never move afterwards.
  The frames (N, B) are carried along by parallel transport, as at the end;
- a frame's depth, inside the tissue area and the depth range, is back-projected with the
  frame's pose when it was placed and thinned to one point per voxel; each point lands in the
  cell of the nearest row within reach of the camera (the depth range plus ``max_radius``).
  A depth map holds the first surface along each ray, so points in a cell are that cell seen
  unoccluded, with surface (``require_surface``); the cell counts as observed once
  ``coverage.live_min_points`` points landed in it (a stray point of noisy predicted depth is
  not a view of the wall). A cell's radius is the mean of its points';
- points beyond the last row wait, voxel-thinned (the wall within the depth range ahead),
  until the rows reach them.

A frame therefore costs the same wherever the camera is: its points, the rows within reach
and the waiting points, never the length mapped so far. Differences to the estimate at the
end: poses are those when each frame was placed (the end uses the optimised ones), the cell
is tested with depth points rather than rays cast on the fused mesh, and the last
``2 * smoothing`` of the path has no rows until :meth:`IncrementalWall.finish`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from c3f_slam.config import CoverageConfig
from c3f_slam.geometry import transform_points

#: at most this many depth pixels per frame are back-projected (an even pixel stride)
POINTS_PER_FRAME = 6000
#: waiting points beyond the last row are kept up to this many (the farthest from the camera go first)
MAX_WAITING = 60000
#: the smoothing Gaussian is cut at this many sigma (the lag of the rows behind the camera)
SMOOTHING_CUT = 2.0


def thinning_voxel(cfg: CoverageConfig) -> float:
    """Metres: two thirds of a cell's smaller side (its width around a wall of radius
    ``max_radius / 3``, the colon's typical), so that thinning leaves points in every cell seen."""
    return min(cfg.cell_length, 2 * math.pi * cfg.max_radius / 3 / cfg.angle_bins) / 1.5


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 per point naming its voxel (cubes of ``voxel`` metres; 21 bits per axis:
    +-1,000 m at a millimetre)."""
    v = np.floor(np.asarray(points) / voxel).astype(np.int64) + (1 << 20)
    return (v[:, 0] << 42) | (v[:, 1] << 21) | v[:, 2]


class _Grow:
    """A growing float64/int array along axis 0 (capacity doubled): rows never move."""

    def __init__(self, shape: tuple[int, ...], dtype) -> None:
        self.data = np.zeros((16, *shape), dtype)
        self.n = 0

    def append(self, values: np.ndarray) -> None:
        values = np.asarray(values)
        k = len(values)
        if self.n + k > len(self.data):
            cap = max(2 * len(self.data), self.n + k)
            grown = np.zeros((cap, *self.data.shape[1:]), self.data.dtype)
            grown[:self.n] = self.data[:self.n]
            self.data = grown
        self.data[self.n:self.n + k] = values
        self.n += k

    @property
    def view(self) -> np.ndarray:
        return self.data[:self.n]


class GrowingCentreline:
    """Forward nodes of the camera path, smoothed once their neighbours exist, and rows of
    cells every ``cell_length`` metres of the smoothed line: ``centre``, ``T``, ``N``, ``B``."""

    def __init__(self, cfg: CoverageConfig) -> None:
        self.spacing, self.cell = cfg.node_spacing, cfg.cell_length
        sigma = cfg.smoothing / cfg.node_spacing
        self.pad = int(math.ceil(SMOOTHING_CUT * sigma)) if sigma > 0 else 0
        k = np.arange(-self.pad, self.pad + 1, dtype=np.float64)
        w = np.exp(-0.5 * (k / sigma) ** 2) if sigma > 0 else np.ones(1)
        self.weights = w / w.sum()
        self.raw: list[np.ndarray] = []
        self._tangent: np.ndarray | None = None
        self._best: np.ndarray | None = None
        self._best_step = 0.0
        self.smooth: list[np.ndarray] = []
        self.arc = [0.0]  # arc length at each smoothed node
        self.centre, self.T, self.N, self.B = (_Grow((3,), np.float64) for _ in range(4))
        self.finished = False

    @property
    def n_rows(self) -> int:
        return self.centre.n

    @property
    def rows_end(self) -> float:
        """Arc length (metres) up to which rows exist."""
        return self.n_rows * self.cell

    def push(self, position: np.ndarray) -> int:
        """Add a camera position (metres); returns the number of rows created."""
        p = np.asarray(position, np.float64)
        if not np.all(np.isfinite(p)) or self.finished:
            return 0
        if not self.raw:
            self.raw.append(p)
            return 0
        d = p - self.raw[-1]
        step = float(np.linalg.norm(d)) if self._tangent is None else float(d @ self._tangent)
        if step < self.spacing:
            if step > self._best_step:
                self._best, self._best_step = p, step
            return 0
        self.raw.append(p)
        t = self.raw[-1] - self.raw[max(0, len(self.raw) - 4)]
        self._tangent, self._best, self._best_step = t / np.linalg.norm(t), None, 0.0
        while len(self.smooth) + self.pad < len(self.raw):
            self._smooth_node(len(self.smooth))
        return self._make_rows(final=False)

    def finish(self) -> int:
        """The end of the path: the last nodes smoothed (reflected past the end) and their rows."""
        if self.finished:
            return 0
        if self._best is not None and self._best_step > 0.2 * self.spacing:
            self.raw.append(self._best)
        self.finished = True
        while len(self.smooth) < len(self.raw):
            self._smooth_node(len(self.smooth))
        return self._make_rows(final=True)

    def _raw_at(self, j: int) -> np.ndarray:
        """Raw node j, reflected about the first (j < 0) and, once finished, the last node."""
        n = len(self.raw)
        if j < 0:
            return 2 * self.raw[0] - self.raw[min(-j, n - 1)]
        if j >= n:
            return 2 * self.raw[-1] - self.raw[max(2 * (n - 1) - j, 0)]
        return self.raw[j]

    def _smooth_node(self, k: int) -> None:
        pts = np.stack([self._raw_at(k + j) for j in range(-self.pad, self.pad + 1)])
        node = self.weights @ pts
        if self.smooth:
            step = float(np.linalg.norm(node - self.smooth[-1]))
            if step <= 1e-9:
                return
            self.arc.append(self.arc[-1] + step)
        self.smooth.append(node)

    def _point_at(self, s: float) -> np.ndarray:
        arc = self.arc
        s = min(max(s, 0.0), arc[-1])
        k = int(np.searchsorted(arc, s, side="right")) - 1
        k = min(max(k, 0), len(arc) - 2)
        f = (s - arc[k]) / (arc[k + 1] - arc[k])
        return (1 - f) * self.smooth[k] + f * self.smooth[k + 1]

    def _make_rows(self, *, final: bool) -> int:
        if len(self.smooth) < 2:
            return 0
        end = self.arc[-1]
        made = 0
        while True:
            i = self.n_rows
            s_c = (i + 0.5) * self.cell
            if s_c + (0.5 if final else 1.0) * self.cell > end + 1e-12:
                return made
            c = self._point_at(s_c)
            t = self._point_at(s_c + self.cell) - self._point_at(s_c - self.cell)
            t /= np.linalg.norm(t)
            if i == 0:
                a = np.array([0.0, 0.0, 1.0]) if abs(t[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
                n = a - t * (a @ t)
            else:
                n = self.N.view[-1] - t * (self.N.view[-1] @ t)
            n /= np.linalg.norm(n)
            for grow, v in ((self.centre, c), (self.T, t), (self.N, n), (self.B, np.cross(t, n))):
                grow.append(v[None])
            made += 1


@dataclass(frozen=True)
class WallUpdate:
    """What one frame changed: the ``rows`` (indices) whose cells or radii changed, the
    thinned world ``points`` (n, 3) metres of its depth and their ``colours`` (n, 3) uint8 (the
    live map), and the camera's arc length ``s`` (metres, None before the first row)."""

    rows: np.ndarray
    points: np.ndarray
    colours: np.ndarray
    s: float | None


@dataclass(frozen=True)
class Gap:
    """The largest connected region of unseen cells of a segment: arc lengths (metres), its area
    (m^2), its cells, and the world direction from the centreline to it (unit (3,)) at ``centre``."""

    s_from: float
    s_to: float
    area: float
    cells: int
    direction: np.ndarray
    centre: np.ndarray


class IncrementalWall:
    """Wall cells observed so far, updated frame by frame (:meth:`add_frame`).

    ``K``: intrinsics of the depth maps given; ``depth_range``: (near, far) metres of the
    depth that observes (fusion's, as at the end); ``mask``: the tissue area of the depth
    maps' grid (None: every pixel); ``voxel``: metres of the thinning of points (default
    :func:`thinning_voxel`)."""

    def __init__(self, cfg: CoverageConfig, K: np.ndarray, depth_range: tuple[float, float],
                 mask: np.ndarray | None = None, voxel: float | None = None) -> None:
        self.cfg, self.K = cfg, np.asarray(K, np.float64)
        self.near, self.far = depth_range
        self.mask = mask
        self.voxel = voxel or thinning_voxel(cfg)
        self.A = cfg.angle_bins
        self.reach = self.far + cfg.max_radius
        self.line = GrowingCentreline(cfg)
        self.count = _Grow((self.A,), np.int32)
        self.r_sum = _Grow((self.A,), np.float64)
        self.c_sum = _Grow((self.A, 3), np.float32)
        self.ring_area = _Grow((), np.float64)  # per row: L x 2 pi x mean radius (m^2)
        self.seen_area = _Grow((), np.float64)  # per row: its observed part
        self.seg_area: list[float] = []  # per segment: sums of the rows'
        self.seg_seen: list[float] = []
        self.wait_xyz = np.zeros((0, 3), np.float64)
        self.wait_rgb = np.zeros((0, 3), np.uint8)
        self._cursor = 0
        self.frames = 0

    # ------------------------------------------------------------------ frames
    def add_frame(self, T_wc: np.ndarray, depth: np.ndarray, rgb: np.ndarray | None = None) -> WallUpdate:
        """A placed frame: camera-to-world ``T_wc`` (4, 4) metres, ``depth`` (H, W) metres on the
        grid of ``K`` (0 / NaN: none), ``rgb`` (H, W, 3) uint8 of the same grid or None."""
        self.frames += 1
        T = np.asarray(T_wc, np.float64)
        before = self.line.n_rows
        self.line.push(T[:3, 3])
        pts, cols = self._frame_points(T, depth, rgb)
        changed = [np.arange(before, self.line.n_rows)]
        self._grow_cells(before)
        if self.line.n_rows > before:
            changed.append(self._drain(before))
        s_cam = self.locate_camera(T[:3, 3])
        if self.line.n_rows:
            lo, hi = self._window(s_cam)
            rows, ahead = self._assign(pts, cols, lo, hi)
            changed.append(rows)
            self._wait(pts[ahead], cols[ahead], T[:3, 3])
        else:
            self._wait(pts, cols, T[:3, 3])
        rows = np.unique(np.concatenate(changed)).astype(np.int64)
        self._account(rows)
        return WallUpdate(rows, pts, cols, s_cam)

    def finish(self) -> np.ndarray:
        """The end of the path: the last rows made and the waiting points placed; returns the
        rows changed."""
        before = self.line.n_rows
        self.line.finish()
        self._grow_cells(before)
        rows = np.arange(before, self.line.n_rows)
        if self.line.n_rows > before:
            rows = np.unique(np.concatenate([rows, self._drain(before)]))
        self._account(rows)
        return rows

    def _frame_points(self, T: np.ndarray, depth: np.ndarray, rgb: np.ndarray | None):
        """World points (n, 3) of the depth inside the mask and range, one per voxel, and colours."""
        h, w = depth.shape
        stride = max(1, int(math.ceil(math.sqrt(h * w / POINTS_PER_FRAME))))
        v, u = np.mgrid[stride // 2:h:stride, stride // 2:w:stride]
        z = depth[v, u].astype(np.float64)
        ok = np.isfinite(z) & (z >= self.near) & (z <= self.far) & (z > 0)
        if self.mask is not None:
            ok &= self.mask[v, u]
        u, v, z = u[ok], v[ok], z[ok]
        K = self.K
        pc = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
        pts = transform_points(T, pc)
        cols = rgb[v, u].astype(np.uint8) if rgb is not None else np.full((len(pts), 3), 180, np.uint8)
        if len(pts):
            _, first = np.unique(voxel_keys(pts, self.voxel), return_index=True)
            pts, cols = pts[first], cols[first]
        return pts, cols

    # ------------------------------------------------------------------ cells
    def _grow_cells(self, before: int) -> None:
        n = self.line.n_rows - before
        if n <= 0:
            return
        self.count.append(np.zeros((n, self.A), np.int32))
        self.r_sum.append(np.zeros((n, self.A)))
        self.c_sum.append(np.zeros((n, self.A, 3), np.float32))
        self.ring_area.append(np.zeros(n))
        self.seen_area.append(np.zeros(n))

    def _window(self, s_cam: float | None) -> tuple[int, int]:
        """Rows [lo, hi) within reach of the camera at arc length ``s_cam``."""
        n, L = self.line.n_rows, self.cfg.cell_length
        if s_cam is None:
            return 0, 0
        lo = max(0, int(math.floor((s_cam - self.reach) / L)))
        hi = min(n, int(math.ceil((s_cam + self.reach) / L)) + 1)
        return lo, max(lo, hi)

    def locate_camera(self, position: np.ndarray) -> float | None:
        """Arc length (metres) of a position: on the nearest row near the last camera position
        (the whole line when that is out of reach), beyond the last row along its tangent."""
        n = self.line.n_rows
        if n == 0:
            return None
        p = np.asarray(position, np.float64)
        L = self.cfg.cell_length
        span = int(math.ceil(self.reach / L))
        lo, hi = max(0, self._cursor - span), min(n, self._cursor + span + 1)
        C = self.line.centre.view
        d = np.linalg.norm(C[lo:hi] - p, axis=1)
        k = lo + int(np.argmin(d))
        if d[k - lo] > self.reach:  # a jump (a revisit far away): search every row
            k = int(np.argmin(np.linalg.norm(C - p, axis=1)))
        self._cursor = k
        a = float((p - C[k]) @ self.line.T.view[k])
        return (k + 0.5) * L + a

    def _locate(self, pts: np.ndarray, lo: int, hi: int):
        """(row, angle bin, radius, on-wall, ahead) of points against rows [lo, hi)."""
        line, L = self.line, self.cfg.cell_length
        C, T = line.centre.view[lo:hi], line.T.view[lo:hi]
        k = cKDTree(C).query(pts)[1]
        rel = pts - C[k]
        a = np.einsum("ij,ij->i", rel, T[k])
        perp = rel - a[:, None] * T[k]
        r = np.linalg.norm(perp, axis=1)
        th = np.arctan2(np.einsum("ij,ij->i", perp, line.B.view[lo:hi][k]),
                        np.einsum("ij,ij->i", perp, line.N.view[lo:hi][k]))
        s = (lo + k + 0.5) * L + a
        row = np.floor(s / L).astype(np.int64)
        ahead = s >= line.rows_end
        ok = (np.abs(a) <= L) & (row >= 0) & (row < line.n_rows) & (r <= self.cfg.max_radius) & ~ahead
        j = np.clip(((th + np.pi) / (2 * np.pi) * self.A).astype(np.int64), 0, self.A - 1)
        return row, j, r, ok, ahead

    def _assign(self, pts: np.ndarray, cols: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """Points into the cells of rows [lo, hi); returns the rows changed and the points ahead."""
        if hi <= lo or not len(pts):
            return np.zeros(0, np.int64), np.zeros(len(pts), bool)
        row, j, r, ok, ahead = self._locate(pts, lo, hi)
        ahead &= row >= self.line.n_rows - 1  # ahead of the last row, not off to the side of an earlier one
        row, j, r, c = row[ok], j[ok], r[ok], cols[ok]
        np.add.at(self.count.data, (row, j), 1)
        np.add.at(self.r_sum.data, (row, j), r)
        np.add.at(self.c_sum.data, (row, j), c.astype(np.float32))
        return np.unique(row), ahead

    def _wait(self, pts: np.ndarray, cols: np.ndarray, camera: np.ndarray) -> None:
        """Keep points beyond the last row (one per voxel, the nearest ``MAX_WAITING`` to the camera)."""
        if not len(pts):
            return
        xyz = np.concatenate([self.wait_xyz, pts])
        rgb = np.concatenate([self.wait_rgb, cols])
        _, first = np.unique(voxel_keys(xyz, self.voxel), return_index=True)
        xyz, rgb = xyz[first], rgb[first]
        if len(xyz) > MAX_WAITING:
            keep = np.argsort(np.linalg.norm(xyz - camera, axis=1))[:MAX_WAITING]
            xyz, rgb = xyz[keep], rgb[keep]
        self.wait_xyz, self.wait_rgb = xyz, rgb

    def _drain(self, first_new: int) -> np.ndarray:
        """Waiting points into the rows from ``first_new`` on (and the row before); those the rows
        passed without taking them are dropped. Returns the rows changed."""
        if not len(self.wait_xyz):
            return np.zeros(0, np.int64)
        lo = max(0, first_new - 1)
        row, j, r, ok, ahead = self._locate(self.wait_xyz, lo, self.line.n_rows)
        ahead &= row >= self.line.n_rows - 1
        rows = row[ok]
        np.add.at(self.count.data, (rows, j[ok]), 1)
        np.add.at(self.r_sum.data, (rows, j[ok]), r[ok])
        np.add.at(self.c_sum.data, (rows, j[ok]), self.wait_rgb[ok].astype(np.float32))
        self.wait_xyz, self.wait_rgb = self.wait_xyz[ahead], self.wait_rgb[ahead]
        return np.unique(rows)

    def _account(self, rows: np.ndarray) -> None:
        """Update the areas of ``rows`` and the sums of their segments."""
        if not len(rows):
            return
        L, seg = self.cfg.cell_length, self.cfg.segment
        radius = self.radius(rows)
        area = 2 * np.pi * L * radius.mean(axis=1)
        seen = area * (self.count.data[rows] >= self.cfg.live_min_points).mean(axis=1)
        k = ((rows + 0.5) * L / seg).astype(np.int64)
        need = int(k.max()) + 1 if len(k) else 0
        while len(self.seg_area) < need:
            self.seg_area.append(0.0)
            self.seg_seen.append(0.0)
        d_area = area - self.ring_area.data[rows]
        d_seen = seen - self.seen_area.data[rows]
        self.ring_area.data[rows], self.seen_area.data[rows] = area, seen
        for kk, da, ds in zip(k.tolist(), d_area.tolist(), d_seen.tolist()):
            self.seg_area[kk] += da
            self.seg_seen[kk] += ds

    # ------------------------------------------------------------------ queries
    @property
    def n_rows(self) -> int:
        return self.line.n_rows

    def observed(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(n, A) bool: cells observed."""
        return self.count.view[rows] >= self.cfg.live_min_points

    def radius(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(n, A) metres: the mean radius of the points of each cell; unobserved cells filled
        around their ring (circular interpolation), rings without a point from the nearest
        earlier ring with one (``max_radius / 2`` before any)."""
        idx = np.arange(self.n_rows)[rows]
        cnt = self.count.data[idx]
        with np.errstate(invalid="ignore", divide="ignore"):
            r = self.r_sum.data[idx] / cnt
        out = np.empty_like(r)
        x = np.arange(self.A, dtype=np.float64)
        for n, (row, c) in enumerate(zip(r, cnt)):
            known = np.flatnonzero(c > 0)
            if len(known) == 0:
                out[n] = self._earlier_radius(int(idx[n]))
            elif len(known) == self.A:
                out[n] = row
            else:
                out[n] = np.interp(x, known, row[known], period=self.A)
        return out

    def _earlier_radius(self, i: int) -> float:
        """Mean measured radius of the nearest ring before ``i`` with points (a bounded look-back)."""
        L = self.cfg.cell_length
        for k in range(i - 1, max(-1, i - 1 - int(self.cfg.segment / L)), -1):
            c = self.count.data[k]
            if (c > 0).any():
                return float((self.r_sum.data[k][c > 0] / c[c > 0]).mean())
        return self.cfg.max_radius / 2

    def colour(self, rows: np.ndarray) -> np.ndarray:
        """(n, A, 3) uint8 mean colour of each cell's points (0 where none)."""
        cnt = self.count.data[rows][..., None]
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.where(cnt > 0, self.c_sum.data[rows] / np.maximum(cnt, 1), 0)
        return np.clip(c, 0, 255).astype(np.uint8)

    def unseen_share(self) -> float | None:
        """Unseen share of the wall area of every row so far (None before the first row)."""
        total = float(np.sum(self.ring_area.view))
        return 1 - float(np.sum(self.seen_area.view)) / total if total > 0 else None

    def segments(self) -> list[dict]:
        """``{index, start_m, end_m, unseen_share, complete}`` per segment with rows (complete:
        its rows reach its end)."""
        seg, end = self.cfg.segment, self.line.rows_end
        out = []
        for k, (a, s) in enumerate(zip(self.seg_area, self.seg_seen)):
            if a <= 0:
                continue
            out.append({"index": k, "start_m": k * seg, "end_m": min((k + 1) * seg, end),
                        "unseen_share": 1 - s / a, "complete": end >= (k + 1) * seg - 1e-9})
        return out

    def segment_share(self, k: int) -> float | None:
        if k >= len(self.seg_area) or self.seg_area[k] <= 0:
            return None
        return 1 - self.seg_seen[k] / self.seg_area[k]

    def largest_gap(self, k: int) -> Gap | None:
        """The largest connected region of unseen cells of segment ``k`` (around the ring
        wrapping; None without one)."""
        L, seg = self.cfg.cell_length, self.cfg.segment
        lo = int(round(k * seg / L))
        hi = min(self.n_rows, int(round((k + 1) * seg / L)))
        if hi <= lo:
            return None
        unseen = ~self.observed(slice(lo, hi))
        labels, n = ndimage.label(unseen)
        if n == 0:
            return None
        for a, b in zip(labels[:, 0], labels[:, -1]):  # join the regions that meet across the seam
            if a and b and a != b:
                labels[labels == b] = a
        area = np.broadcast_to(self.ring_area.data[lo:hi, None] / self.A, labels.shape)
        ids = np.unique(labels[labels > 0])
        sizes = np.array([area[labels == i].sum() for i in ids])
        best = ids[int(np.argmax(sizes))]
        cells = labels == best
        rr, jj = np.nonzero(cells)
        th = -np.pi + (jj + 0.5) * 2 * np.pi / self.A
        w = area[cells]
        mean_th = math.atan2(float((np.sin(th) * w).sum()), float((np.cos(th) * w).sum()))
        mid = lo + int(round(float(np.average(rr, weights=w))))
        N, B = self.line.N.view[mid], self.line.B.view[mid]
        direction = math.cos(mean_th) * N + math.sin(mean_th) * B
        return Gap(s_from=(lo + rr.min()) * L, s_to=(lo + rr.max() + 1) * L, area=float(w.sum()),
                   cells=int(cells.sum()), direction=direction, centre=self.line.centre.view[mid].copy())

    def rows_geometry(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        """Per row of ``rows``: ``centre``, ``N``, ``B`` (n, 3), ``radius`` (n, A) metres (filled),
        ``observed`` (n, A) bool, ``colour`` (n, A, 3) uint8."""
        rows = np.asarray(rows, np.int64)
        line = self.line
        return {"centre": line.centre.data[rows], "N": line.N.data[rows], "B": line.B.data[rows],
                "radius": self.radius(rows), "observed": self.observed(rows), "colour": self.colour(rows)}


def clock_position(direction: np.ndarray, T_wc: np.ndarray) -> int:
    """Where a world ``direction`` points as seen by the camera at ``T_wc``: a clock hour 1..12
    (12 = image up, 3 = image right; the image's x right, y down)."""
    d = np.asarray(T_wc, np.float64)[:3, :3].T @ np.asarray(direction, np.float64)
    angle = math.degrees(math.atan2(d[0], -d[1])) % 360  # clockwise from up
    hour = int(round(angle / 30)) % 12
    return 12 if hour == 0 else hour
