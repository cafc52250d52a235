"""Colon geometry: a smooth random centreline and a closed triangle mesh of the tube around it.

Coordinates are metres in the world frame. The tube is parametrised by the arc length ``s``
of its centreline (0 .. length) and the angle ``theta`` (radians) around it, measured in the
rotation-minimising frame (N, B) that travels along the centreline with tangent T:

    P(s, theta) = C(s) + r(s, theta) * (cos(theta) N(s) + sin(theta) B(s))

``r(s, theta)`` holds the lumen radius (slow variation), the three taeniae, the haustral
bulges, the haustral folds (partial ring ridges, three crescents between the taeniae,
which really occlude what lies behind them), sessile polyps and a fine relief. Both ends
are closed by domes, so every ray cast from inside the lumen hits the mesh. Triangle
normals point into the lumen.

Every vertex also carries texture coordinates defined on the surface, so the texture is
the same whichever frame looks at it: ``u`` is the surface arc length along the tube at
fixed theta (metres, 0 at the apex of the start dome) and ``theta`` gives the other axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter

from c3f_slam.geometry import transport_frames
from datamodules.synthetic.noise import random_sines
from datamodules.synthetic.params import ColonParams

FOLD_MARGIN = 0.02  # no folds within this distance of either end (m)
CAP_RINGS = 8  # rings of each end dome


@dataclass
class Fold:
    """A haustral fold: axial position (m), Gaussian width (m), crest height per crescent (m)."""

    s: float
    sigma: float
    heights: tuple[float, float, float]
    tilt: float  # axial shift amplitude around the ring, m
    tilt_phase: float  # radians


@dataclass
class Polyp:
    s: float  # m
    theta: float  # radians
    radius: float  # base radius, m
    height: float  # m


@dataclass
class Colon:
    """Centreline, radius field and the closed mesh (float32 vertices, inward normals)."""

    params: ColonParams
    s: np.ndarray  # (S,) arc length of the rings, m
    centre: np.ndarray  # (S, 3)
    tangent: np.ndarray  # (S, 3)
    normal: np.ndarray  # (S, 3) rotation-minimising frame
    binormal: np.ndarray  # (S, 3)
    theta: np.ndarray  # (K,) ring angles, radians
    radius: np.ndarray  # (S, K) r(s, theta), m
    taenia_phase: np.ndarray  # (S,) angle of the first taenia, radians
    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (F, 3) int32
    vertex_normals: np.ndarray  # (V, 3) float32, unit, into the lumen
    tex_u: np.ndarray  # (V,) float32, m
    tex_theta: np.ndarray  # (V,) float32, radians
    tangent_theta: np.ndarray  # (V, 3) float32, unit direction of increasing theta
    grid_u: np.ndarray  # (S, K) u of the main-tube vertices, m
    folds: list[Fold] = field(default_factory=list)
    polyps: list[Polyp] = field(default_factory=list)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @property
    def ring_spacing(self) -> float:
        return float(self.s[1] - self.s[0])

    def frame_at(self, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(C, T, N, B) at arc length ``s`` (clamped to the tube, linear interpolation)."""
        x = min(max(s, 0.0), self.length) / self.ring_spacing
        j = min(int(x), len(self.s) - 2)
        w = x - j
        c = (1 - w) * self.centre[j] + w * self.centre[j + 1]
        t = (1 - w) * self.tangent[j] + w * self.tangent[j + 1]
        t /= np.linalg.norm(t)
        n = (1 - w) * self.normal[j] + w * self.normal[j + 1]
        n -= t * (n @ t)
        n /= np.linalg.norm(n)
        return c, t, n, np.cross(t, n)

    def frames_at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised :meth:`frame_at`: (C, T, N, B), each (M, 3), for (M,) arc lengths."""
        s = np.asarray(s, dtype=np.float64)
        x = np.clip(s, 0.0, self.length) / self.ring_spacing
        j = np.minimum(x.astype(int), len(self.s) - 2)
        w = (x - j)[:, None]
        c = (1 - w) * self.centre[j] + w * self.centre[j + 1]
        t = (1 - w) * self.tangent[j] + w * self.tangent[j + 1]
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        n = (1 - w) * self.normal[j] + w * self.normal[j + 1]
        n -= t * (n * t).sum(1, keepdims=True)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return c, t, n, np.cross(t, n)

    def to_legacy_mesh(self):
        """Open3D legacy ``TriangleMesh`` (the ground-truth mesh written to mesh.ply)."""
        import open3d as o3d

        m = o3d.geometry.TriangleMesh()
        m.vertices = o3d.utility.Vector3dVector(self.vertices.astype(np.float64))
        m.triangles = o3d.utility.Vector3iVector(self.triangles.astype(np.int32))
        return m


# ---------------------------------------------------------------------- construction


def build_colon(p: ColonParams, rng: np.random.Generator) -> Colon:
    """Draw a colon from ``rng``; deterministic for a given generator state."""
    n = max(int(round(p.length / p.ring_spacing)), 8) + 1
    s = np.linspace(0.0, p.length, n)
    centre, tangent = _centreline(p, rng, s)
    normal, binormal = transport_frames(tangent)
    theta = np.arange(p.ring_vertices) * (2 * np.pi / p.ring_vertices)
    radius, phase, folds, polyps = _radius_field(p, rng, s, theta)

    rings = _closed_rings(centre, tangent, normal, binormal, theta, radius)
    m_rings, k = rings.grid.shape[:2]
    vertices = np.concatenate([rings.start_apex[None], rings.grid.reshape(-1, 3), rings.end_apex[None]], axis=0)
    vertices = vertices.astype(np.float32)
    v64 = vertices.astype(np.float64)
    mid = len(s) // 2
    triangles, tri_n = _inward_triangles(v64, _triangulate(m_rings, k), rings.start_rings + mid, k, centre[mid])
    vnormals = _vertex_normals(v64, triangles, tri_n)

    n0 = rings.start_rings
    fold_rows = [n0 + int(round(f.s / (s[1] - s[0]))) for f in folds]
    u_grid, tex_u, tex_theta, tangent_theta = _texture_coordinates(rings, fold_rows, theta, binormal)

    return Colon(
        params=p,
        s=s,
        centre=centre,
        tangent=tangent,
        normal=normal,
        binormal=binormal,
        theta=theta,
        radius=radius,
        taenia_phase=phase,
        vertices=vertices,
        triangles=triangles.astype(np.int32),
        vertex_normals=vnormals.astype(np.float32),
        tex_u=tex_u.astype(np.float32),
        tex_theta=tex_theta.astype(np.float32),
        tangent_theta=tangent_theta.astype(np.float32),
        grid_u=u_grid[n0 : n0 + len(s)],
        folds=folds,
        polyps=polyps,
    )


@dataclass
class _Rings:
    """Vertex rings of the closed tube (world frame, metres) and the apexes of its two end domes."""

    grid: np.ndarray  # (M, K, 3): start dome (apex side first), main tube, end dome
    start_apex: np.ndarray  # (3,)
    end_apex: np.ndarray  # (3,)
    start_rings: int  # rings of the start dome at the beginning of ``grid``


def _closed_rings(centre: np.ndarray, tangent: np.ndarray, normal: np.ndarray, binormal: np.ndarray,
                  theta: np.ndarray, radius: np.ndarray) -> _Rings:
    """The tube's rings P(s, theta) (see the module docstring) closed by a dome at each end."""
    dirs = np.cos(theta)[None, :, None] * normal[:, None, :] + np.sin(theta)[None, :, None] * binormal[:, None, :]
    tube = centre[:, None, :] + radius[..., None] * dirs  # (S, K, 3)

    start_cap = _dome(centre[0], -tangent[0], tube[0])  # rings from the apex side outwards
    end_cap = _dome(centre[-1], tangent[-1], tube[-1])
    start_apex = centre[0] - tangent[0] * 0.7 * radius[0].mean()
    end_apex = centre[-1] + tangent[-1] * 0.7 * radius[-1].mean()
    grid = np.concatenate([start_cap[::-1], tube, end_cap], axis=0)  # (M, K, 3)
    return _Rings(grid=grid, start_apex=start_apex, end_apex=end_apex, start_rings=len(start_cap))


def _inward_triangles(v64: np.ndarray, triangles: np.ndarray, probe_row: int, k: int,
                      probe_centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles wound so that their normals point into the lumen, and those (unnormalised) normals.

    The winding is decided on the triangles of grid row ``probe_row`` (K vertices per row,
    vertex 0 = start apex) against the centreline point ``probe_centre`` of that ring.
    """
    tri_n = np.cross(v64[triangles[:, 1]] - v64[triangles[:, 0]], v64[triangles[:, 2]] - v64[triangles[:, 0]])
    sel = slice(1 + probe_row * k, 1 + (probe_row + 1) * k)
    probe = np.isin(triangles[:, 0], np.arange(sel.start, sel.stop))
    outward = (tri_n[probe] * (v64[triangles[probe, 0]] - probe_centre)).sum(1).mean()
    if outward > 0:
        triangles = triangles[:, [0, 2, 1]]
        tri_n = -tri_n
    return triangles, tri_n


def _vertex_normals(v64: np.ndarray, triangles: np.ndarray, tri_n: np.ndarray) -> np.ndarray:
    """(V, 3) unit vertex normals: sums of the area-weighted normals of the adjacent triangles."""
    vnormals = np.zeros_like(v64)
    for c in range(3):
        for corner in range(3):
            vnormals[:, c] += np.bincount(triangles[:, corner], weights=tri_n[:, c], minlength=len(v64))
    vnormals /= np.maximum(np.linalg.norm(vnormals, axis=1, keepdims=True), 1e-12)
    return vnormals


def _texture_coordinates(rings: _Rings, fold_rows: list[int], theta: np.ndarray,
                         binormal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-vertex texture coordinates of the closed mesh.

    Returns the (M, K) grid of u (surface arc length along the tube, m, resynchronised
    between folds), per-vertex u (m) and theta (radians), and the (V, 3) unit direction of
    increasing theta; vertex 0 is the start apex, the last one the end apex.
    """
    grid = rings.grid
    m_rings = grid.shape[0]
    u_grid = _surface_u(grid, rings.start_apex, fold_rows)
    end_u = u_grid[-1] + np.linalg.norm(grid[-1] - rings.end_apex, axis=1)
    tex_u = np.concatenate([[0.0], u_grid.reshape(-1), [end_u.mean()]])
    tex_theta = np.concatenate([[0.0], np.tile(theta, m_rings), [0.0]])
    tang = np.roll(grid, -1, axis=1) - np.roll(grid, 1, axis=1)
    tang /= np.maximum(np.linalg.norm(tang, axis=2, keepdims=True), 1e-12)
    tangent_theta = np.concatenate([binormal[:1], tang.reshape(-1, 3), binormal[-1:]], axis=0)
    return u_grid, tex_u, tex_theta, tangent_theta


def _centreline(p: ColonParams, rng: np.random.Generator, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arc-length-parametrised smooth random curve: (C, T), each (S, 3)."""
    ds = s[1] - s[0]
    kappa_max = 1.0 / p.min_bend_radius
    r_out = (p.radius + p.radius_variation) * (1 + p.haustra_bulge)
    scale = 1.0
    for _attempt in range(40):
        yaw_shape = random_sines(rng, s, (0.18, 0.7), 4)
        pitch_shape = random_sines(rng, s, (0.18, 0.7), 3)
        amp = scale * p.tortuosity
        for _ in range(20):  # shrink until the curvature bound holds
            yaw, pitch = 2.2 * amp * yaw_shape, 0.8 * amp * pitch_shape
            d = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)
            kappa = np.linalg.norm(np.gradient(d, ds, axis=0), axis=1).max() if len(s) > 2 else 0.0
            if kappa <= kappa_max:
                break
            amp *= 0.97 * kappa_max / kappa
        else:
            amp, d = 0.0, np.tile([1.0, 0.0, 0.0], (len(s), 1))
        c = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (d[1:] + d[:-1]) * ds, axis=0)])
        if _no_self_contact(c, s, r_out):
            t = np.gradient(c, ds, axis=0)
            return c, t / np.linalg.norm(t, axis=1, keepdims=True)
        scale *= 0.9
    c = np.outer(s, [1.0, 0.0, 0.0])
    return c, np.tile([1.0, 0.0, 0.0], (len(s), 1))


def _no_self_contact(c: np.ndarray, s: np.ndarray, r_out: float) -> bool:
    """True when parts of the tube far apart along the centreline stay apart in space."""
    step = max(1, int(round(0.005 / (s[1] - s[0]))))
    cs, ss = c[::step], s[::step]
    d = np.linalg.norm(cs[:, None] - cs[None], axis=2)
    far = np.abs(ss[:, None] - ss[None]) > 3.5 * r_out
    return bool(np.all(d[far] > 2 * r_out + 0.01))


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _radius_field(p: ColonParams, rng: np.random.Generator, s: np.ndarray,
                  theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[Fold], list[Polyp]]:
    """r(s, theta) (S, K, metres) with taeniae, haustra, folds, polyps and relief; also the
    (S,) angle of the first taenia (radians), the folds and the polyps."""
    base = p.radius + p.radius_variation * random_sines(rng, s, (0.08, 0.35), 4)  # (S,)
    phase, tau = _taeniae(rng, s, theta)
    positions = _fold_positions(p, rng)
    bulge = _haustral_bulge(s, positions)
    r = base[:, None] * (1 + p.haustra_bulge * bulge[:, None] * (1 - tau)) * (1 - p.taenia_depth * tau)
    folds = [_carve_fold(r, s, theta, _draw_fold(p, rng, pos, base[int(round(pos / (s[1] - s[0])))]), phase)
             for pos in positions]
    polyps = [_carve_polyp(r, s, theta, _draw_polyp(p, rng), base) for _ in range(p.polyps)]
    if p.relief > 0:
        _add_relief(p, rng, s, theta, r)
    r = np.maximum(r, 0.25 * p.radius)
    return r, phase, folds, polyps


def _taeniae(rng: np.random.Generator, s: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S,) angle of the first of the three taeniae (radians, slowly twisting along s) and
    the (S, K) taenia profile: 1 on a taenia, falling to 0 between them."""
    phase = rng.uniform(0, 2 * np.pi) + rng.uniform(-3.0, 3.0) * s + 0.25 * random_sines(rng, s, (0.1, 0.4), 2)
    rel = theta[None, :] - phase[:, None]  # (S, K)
    tau = sum(np.exp(-0.5 * (_wrap(rel - 2 * np.pi * m / 3) / 0.14) ** 2) for m in range(3))
    return phase, tau


def _fold_positions(p: ColonParams, rng: np.random.Generator) -> list[float]:
    """Arc lengths (m) of the folds: about ``fold_spacing`` apart, FOLD_MARGIN clear of both ends."""
    pos = FOLD_MARGIN + rng.uniform(0, p.fold_spacing)
    positions = []
    while pos < p.length - FOLD_MARGIN:
        positions.append(pos)
        pos += p.fold_spacing * rng.uniform(0.7, 1.3)
    return positions


def _haustral_bulge(s: np.ndarray, positions: list[float]) -> np.ndarray:
    """(S,) 0..1 half-sine bulge between consecutive folds (0 at the folds and outside them)."""
    bulge = np.zeros_like(s)
    for a, b in zip(positions[:-1], positions[1:]):
        m = (s >= a) & (s < b)
        bulge[m] = np.sin(np.pi * (s[m] - a) / (b - a))
    return bulge


def _draw_fold(p: ColonParams, rng: np.random.Generator, pos: float, base_radius: float) -> Fold:
    """The fold at arc length ``pos`` (m) where the lumen radius is ``base_radius`` (m)."""
    present = rng.random(3) < p.fold_coverage
    if not present.any():
        present[rng.integers(3)] = True
    crescents = np.where(present, rng.uniform(0.55, 1.0, 3), 0.0)
    amp = p.fold_height * base_radius * rng.uniform(0.75, 1.15)
    sigma = p.fold_width * rng.uniform(0.8, 1.3)
    tilt = rng.uniform(-0.25, 0.25) * base_radius
    tilt_phase = rng.uniform(0, 2 * np.pi)
    return Fold(float(pos), float(sigma), tuple(float(amp * c) for c in crescents), float(tilt), float(tilt_phase))


def _carve_fold(r: np.ndarray, s: np.ndarray, theta: np.ndarray, fold: Fold, phase: np.ndarray) -> Fold:
    """Subtract ``fold``'s three crescents (between the taeniae at ``phase``, radians) from
    the (S, K) radius field ``r`` in place; returns the fold."""
    ds = s[1] - s[0]
    third = 2 * np.pi / 3
    pos, sigma, tilt = fold.s, fold.sigma, fold.tilt
    j = int(round(pos / ds))
    ang = (theta - phase[j]) % (2 * np.pi)
    idx = np.minimum((ang // third).astype(int), 2)
    g = np.sqrt(np.abs(np.sin(1.5 * (ang - idx * third))))
    h = np.asarray(fold.heights)[idx] * g  # (K,)
    centre_s = pos + tilt * np.cos(theta - fold.tilt_phase)  # (K,)
    reach = 5 * sigma + abs(tilt)
    lo, hi = max(0, int((pos - reach) / ds)), min(len(s), int((pos + reach) / ds) + 2)
    prof = np.exp(-0.5 * ((s[lo:hi, None] - centre_s[None]) / sigma) ** 2)
    r[lo:hi] -= h[None] * prof
    return fold


def _draw_polyp(p: ColonParams, rng: np.random.Generator) -> Polyp:
    """A sessile polyp somewhere in the middle 80 % of the colon."""
    ps = rng.uniform(0.1, 0.9) * p.length
    pt = rng.uniform(0, 2 * np.pi)
    pr = p.polyp_radius * rng.uniform(0.7, 1.4)
    ph = pr * rng.uniform(0.5, 0.9)
    return Polyp(float(ps), float(pt), float(pr), float(ph))


def _carve_polyp(r: np.ndarray, s: np.ndarray, theta: np.ndarray, polyp: Polyp, base: np.ndarray) -> Polyp:
    """Raise ``polyp`` (a smooth bump into the lumen) on the (S, K) radius field ``r`` in place;
    ``base`` is the (S,) mean radius (m). Returns the polyp."""
    ds = s[1] - s[0]
    ps, pr = polyp.s, polyp.radius
    j = int(round(ps / ds))
    lo, hi = max(0, int((ps - 2 * pr) / ds)), min(len(s), int((ps + 2 * pr) / ds) + 2)
    d2 = (s[lo:hi, None] - ps) ** 2 + (base[j] * _wrap(theta[None] - polyp.theta)) ** 2
    r[lo:hi] -= polyp.height * np.exp(-2.5 * (d2 / pr**2) ** 2)
    return polyp


def _add_relief(p: ColonParams, rng: np.random.Generator, s: np.ndarray, theta: np.ndarray, r: np.ndarray) -> None:
    """Add the fine random relief (std ``relief`` m, correlated over ~3 mm, clipped at 3 std) to ``r`` in place."""
    ds = s[1] - s[0]
    corr_s = 0.003 / ds
    corr_t = 0.003 / (p.radius * (theta[1] - theta[0]))
    noise = gaussian_filter(rng.standard_normal(r.shape), (corr_s, corr_t), mode=("reflect", "wrap"))
    noise /= max(noise.std(), 1e-12)
    r += p.relief * np.clip(noise, -3, 3)


def _surface_u(grid: np.ndarray, apex: np.ndarray, fold_rows: list[int]) -> np.ndarray:
    """(M, K) texture coordinate u (m): surface arc length along each theta column, rescaled
    per stretch between fold midpoints so that all columns agree at every midpoint.

    A column that climbs over a tall fold is longer than one along a taenia; plain per-column
    arc length would shear the texture by centimetres after a few folds. Within each stretch
    every column is scaled uniformly to the stretch's mean length instead.
    """
    seg = np.linalg.norm(np.diff(grid, axis=0), axis=2)  # (M-1, K)
    first = np.linalg.norm(grid[0] - apex, axis=1)
    cum = np.concatenate([np.zeros((1, grid.shape[1])), np.cumsum(seg, axis=0)], axis=0)  # (M, K)
    rows = sorted(fold_rows)
    bounds = [0] + [(a + b) // 2 for a, b in zip(rows[:-1], rows[1:])] + [grid.shape[0] - 1]
    bounds = sorted(set(bounds))
    u = np.empty_like(cum)
    start = float(first.mean())
    for a, b in zip(bounds[:-1], bounds[1:]):
        length = cum[b] - cum[a]  # (K,)
        mean = float(length.mean())
        scale = mean / np.maximum(length, 1e-12)
        u[a : b + 1] = start + (cum[a : b + 1] - cum[a]) * scale
        start += mean
    return u


def _dome(c: np.ndarray, t: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """CAP_RINGS-1 rings closing ``ring`` towards an apex 0.7 r along ``t`` (outermost first)."""
    h = 0.7 * np.linalg.norm(ring - c, axis=1).mean()
    out = []
    for i in range(1, CAP_RINGS):
        phi = 0.5 * np.pi * i / CAP_RINGS
        out.append(c + t * h * math.sin(phi) + math.cos(phi) * (ring - c))
    return np.stack(out)


def _triangulate(m_rings: int, k: int) -> np.ndarray:
    """Triangles of M rings of K vertices (vertex 0 = start apex, last = end apex)."""
    idx = 1 + np.arange(m_rings * k).reshape(m_rings, k)
    a = idx[:-1]
    b = np.roll(idx[:-1], -1, axis=1)
    c = np.roll(idx[1:], -1, axis=1)
    d = idx[1:]
    quads = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)], axis=0
    )
    end_apex = 1 + m_rings * k
    first, last = idx[0], idx[-1]
    start_fan = np.stack([np.zeros(k, int), np.roll(first, -1), first], -1)
    end_fan = np.stack([last, np.roll(last, -1), np.full(k, end_apex)], -1)
    return np.concatenate([start_fan, quads, end_fan], axis=0)
