"""Camera trajectories inside the colon: insertion, withdrawal, random paths and events.

A path is a set of per-frame *controls* in the colon's own coordinates, turned into
camera-to-world poses (4x4, x right, y down, z forward) by :func:`pose_from_controls`:

- ``s``: arc length of the centreline point the camera is at (m);
- ``m``, ``phi``: off-axis offset, as a fraction of the free radius in direction ``phi``
  (radians, in the centreline's (N, B) frame);
- ``beta``, ``psi``: deflection of the view from the lumen direction by ``beta`` radians
  towards direction ``psi`` (looks at the wall);
- ``roll``: rotation about the optical axis (radians).

The view always looks deeper into the colon (+s, as a colonoscope does during insertion
and withdrawal); path ``A`` inserts, ``B`` withdraws, ``random`` goes back and forth with a
forward drift; ``loop`` goes forward and then back over the same stretch. Events (per 1000
frames): close-ups of the wall, fast-motion bursts, approaches that fill the view with a
fold (occluded frames), quick roll turns.

Safety: every frame and sub-frame position is checked against the mesh with Open3D's
``compute_distance``; offsets shrink until the camera keeps ``min_wall_distance`` from the
surface everywhere along the path, so it never touches the wall or passes through a fold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.ndimage import minimum_filter1d

from datamodules.synthetic.colon import Colon
from datamodules.synthetic.noise import smooth_1d
from datamodules.synthetic.params import PathParams

START_MARGIN = 0.025  # m of colon kept free at the start (dome)
END_MARGIN = 0.03  # and at the end
LOOKAHEAD = 0.03  # the view aims at the centreline this far ahead (m)
SECTOR = math.radians(35.0)  # half-width of the wall sector that limits an offset


@dataclass
class Controls:
    s: np.ndarray
    m: np.ndarray
    phi: np.ndarray
    beta: np.ndarray
    psi: np.ndarray
    roll: np.ndarray

    def at(self, t: float) -> tuple[float, ...]:
        """Controls at fractional frame time ``t`` (linear interpolation)."""
        n = len(self.s)
        t = min(max(t, 0.0), n - 1.0)
        i = min(int(t), n - 2) if n > 1 else 0
        w = t - i if n > 1 else 0.0
        j = min(i + 1, n - 1)
        return tuple(float((1 - w) * a[i] + w * a[j])
                     for a in (self.s, self.m, self.phi, self.beta, self.psi, self.roll))

    def at_many(self, t: np.ndarray) -> np.ndarray:
        """(M, 6) controls at fractional frame times ``t`` (same interpolation as :meth:`at`)."""
        grid = np.arange(len(self.s), dtype=np.float64)
        return np.stack([np.interp(t, grid, a) for a in (self.s, self.m, self.phi, self.beta, self.psi, self.roll)],
                        axis=1)


@dataclass
class CameraPath:
    """Per-frame camera-to-world poses with their controls, labels and wall clearance."""

    poses: np.ndarray  # (F, 4, 4)
    controls: Controls
    labels: list[str]  # '' or the event ('closeup', 'burst', 'occluded', 'roll'), ramps included
    wall_distance: np.ndarray  # (F,) distance of each camera centre to the mesh, m
    colon: Colon = field(repr=False)
    allowed: AllowedRadius = field(repr=False)

    def pose_at(self, t: float) -> np.ndarray:
        """Camera-to-world pose at fractional frame time ``t``."""
        return pose_from_controls(self.colon, self.allowed, *self.controls.at(t))


class AllowedRadius:
    """Largest off-axis offset (m) at (s, phi) that keeps ``clearance`` from the nearby wall."""

    def __init__(self, colon: Colon, clearance: float) -> None:
        ds = colon.ring_spacing
        k = len(colon.theta)
        win_s = 2 * int(math.ceil((clearance + 0.002) / ds)) + 1
        win_t = 2 * int(math.ceil(SECTOR / (2 * math.pi / k))) + 1
        r = minimum_filter1d(colon.radius, win_s, axis=0, mode="nearest")
        r = minimum_filter1d(r, win_t, axis=1, mode="wrap")
        self.table = np.maximum(r - clearance, 0.0)
        self.ds, self.k = ds, k

    def __call__(self, s: np.ndarray, phi: np.ndarray) -> np.ndarray:
        i = np.clip(np.round(np.asarray(s) / self.ds).astype(int), 0, len(self.table) - 1)
        j = np.round(np.asarray(phi) / (2 * math.pi) * self.k).astype(int) % self.k
        return self.table[i, j]


def camera_centres(colon: Colon, allowed: AllowedRadius, s: np.ndarray, m: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(M, 3) camera centres for arrays of controls."""
    c, _, n, b = colon.frames_at(s)
    rho = (m * allowed(s, phi))[:, None]
    return c + rho * (np.cos(phi)[:, None] * n + np.sin(phi)[:, None] * b)


def poses_from_controls(colon: Colon, allowed: AllowedRadius, ctl: np.ndarray) -> np.ndarray:
    """(M, 4, 4) camera-to-world poses for (M, 6) controls (s, m, phi, beta, psi, roll)."""
    s, m, phi, beta, psi, roll = (ctl[:, k] for k in range(6))
    c, _, n, b = colon.frames_at(s)
    rho = (m * allowed(s, phi))[:, None]
    eye = c + rho * (np.cos(phi)[:, None] * n + np.sin(phi)[:, None] * b)
    ahead = s + LOOKAHEAD
    target = colon.frames_at(ahead)[0] + np.maximum(ahead - colon.length, 0.0)[:, None] * colon.tangent[-1]
    z0 = target - c
    z0 /= np.linalg.norm(z0, axis=1, keepdims=True)
    x0 = n - z0 * (n * z0).sum(1, keepdims=True)
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    R0 = np.stack([x0, np.cross(z0, x0), z0], axis=2)  # columns x, y, z
    o = np.einsum("mji,mj->mi", R0, np.cos(psi)[:, None] * n + np.sin(psi)[:, None] * b)
    ang = np.arctan2(o[:, 1], o[:, 0])
    # deflection: rotation by beta about (-sin ang, cos ang, 0), then roll about z
    kx, ky = -np.sin(ang), np.cos(ang)
    sb, cb = np.sin(beta), np.cos(beta)
    D = np.zeros((len(s), 3, 3))
    D[:, 0, 0] = cb + kx * kx * (1 - cb)
    D[:, 0, 1] = kx * ky * (1 - cb)
    D[:, 0, 2] = ky * sb
    D[:, 1, 0] = kx * ky * (1 - cb)
    D[:, 1, 1] = cb + ky * ky * (1 - cb)
    D[:, 1, 2] = -kx * sb
    D[:, 2, 0] = -ky * sb
    D[:, 2, 1] = kx * sb
    D[:, 2, 2] = cb
    Z = np.zeros((len(s), 3, 3))
    Z[:, 0, 0] = Z[:, 1, 1] = np.cos(roll)
    Z[:, 0, 1] = -np.sin(roll)
    Z[:, 1, 0] = np.sin(roll)
    Z[:, 2, 2] = 1.0
    R = R0 @ D @ Z
    u, _, vt = np.linalg.svd(R)  # re-orthonormalise (float round-off only)
    out = np.zeros((len(s), 4, 4))
    out[:, :3, :3] = u @ vt
    out[:, :3, 3] = eye
    out[:, 3, 3] = 1.0
    return out


def pose_from_controls(colon: Colon, allowed: AllowedRadius, s: float, m: float, phi: float,
                       beta: float, psi: float, roll: float) -> np.ndarray:
    """Camera-to-world pose (4x4) for one set of controls (see the module docstring)."""
    return poses_from_controls(colon, allowed, np.array([[s, m, phi, beta, psi, roll]], dtype=np.float64))[0]


# ---------------------------------------------------------------------- planning


def _envelope(n: int, a: int, b: int, ramp: int) -> np.ndarray:
    """(n,) 0..1: raised-cosine ramps of ``ramp`` frames into and out of [a, b)."""
    t = np.arange(n, dtype=np.float64)
    ramp = max(ramp, 1)
    up = np.clip((t - (a - ramp)) / ramp, 0, 1)
    down = np.clip(((b - 1 + ramp) - t) / ramp, 0, 1)
    e = np.minimum(up, down)
    return 0.5 - 0.5 * np.cos(np.pi * e)


def _place(rng: np.random.Generator, n: int, length: int, taken: np.ndarray) -> tuple[int, int] | None:
    """A free window of ``length`` frames (with a margin), or None."""
    if length + 4 > n:
        return None
    for _ in range(30):
        a = int(rng.integers(2, n - length - 1))
        lo, hi = max(0, a - 3), min(n, a + length + 3)
        if not taken[lo:hi].any():
            taken[lo:hi] = True
            return a, a + length
    return None


def _count(rng: np.random.Generator, rate: float, frames: int) -> int:
    x = rate * frames / 1000.0
    return int(math.floor(x + rng.random()))


def _blend_angle(base: np.ndarray, target: float, e: np.ndarray, centre: int) -> np.ndarray:
    target = target + 2 * math.pi * round((base[centre] - target) / (2 * math.pi))
    return base * (1 - e) + target * e


def _label(labels: list[str], name: str, a: int, b: int, e: np.ndarray | None = None) -> None:
    """Label the event's frames [a, b) and, where its envelope ``e`` ramps in and out
    beyond them (the fastest motion of an event), the ramp frames no other event holds."""
    for i in range(a, b):
        labels[i] = name
    if e is not None:
        for i in np.flatnonzero(e > 0).tolist():
            if not labels[i]:
                labels[i] = name


def plan_path(colon: Colon, p: PathParams, rng: np.random.Generator,
              scene: o3d.t.geometry.RaycastingScene) -> CameraPath:
    """Draw a trajectory (deterministic for a given generator state)."""
    n = p.frames
    L = colon.length
    s_lo, s_hi = START_MARGIN, L - END_MARGIN
    if s_hi <= s_lo:
        s_lo = s_hi = 0.5 * L
    corr = float(np.clip(n / 15.0, 4.0, 90.0))
    labels = [""] * n
    taken = np.zeros(n, bool)

    # base signals
    noise_v = smooth_1d(rng, n, corr)
    if p.kind == "random":
        v = 0.45 + 0.9 * noise_v
    else:
        v = np.clip(1.0 + 0.35 * noise_v, 0.15, None)
        if p.kind == "B":
            v = -v
    if p.loop:
        t = np.arange(n)
        turn = np.clip((t - 0.5 * n) / max(2.0, 0.06 * n) + 0.5, 0.0, 1.0)
        sign = np.cos(np.pi * turn)
        v = np.abs(v) * sign if p.kind != "B" else -np.abs(v) * sign
    m = np.clip(p.lateral * (0.55 + 0.45 * smooth_1d(rng, n, corr)), 0.0, 1.0)
    phi = rng.uniform(0, 2 * np.pi) + 1.5 * smooth_1d(rng, n, 2 * corr)
    beta = np.abs(0.06 + 0.05 * smooth_1d(rng, n, corr))
    psi = rng.uniform(0, 2 * np.pi) + 1.5 * smooth_1d(rng, n, 2 * corr)
    roll = math.radians(p.roll) * smooth_1d(rng, n, 1.5 * corr)

    # events that change the speed and view
    for _ in range(_count(rng, p.closeups, n)):
        w = _place(rng, n, int(np.clip(0.03 * n, 12, 45)), taken)
        if w is None:
            continue
        a, b = w
        e = _envelope(n, a, b, max(4, (b - a) // 4))
        target = rng.uniform(0, 2 * np.pi)
        v *= 1 - 0.9 * e
        m = m * (1 - e) + 0.92 * e
        phi = _blend_angle(phi, target, e, (a + b) // 2)
        psi = _blend_angle(psi, target, e, (a + b) // 2)
        beta = beta * (1 - e) + math.radians(rng.uniform(40, 70)) * e
        _label(labels, "closeup", a, b, e)
    for _ in range(_count(rng, p.bursts, n)):
        w = _place(rng, n, int(rng.integers(3, 9)), taken)
        if w is None:
            continue
        a, b = w
        e = _envelope(n, a, b, 1)
        v = v * (1 + (p.burst_factor - 1) * e)
        if p.kind == "random" and rng.random() < 0.3:
            v = v * (1 - 2 * e)
        roll = roll + e * rng.uniform(-0.3, 0.3)
        beta = beta + e * math.radians(rng.uniform(0, 15))
        _label(labels, "burst", a, b, e)
    for _ in range(_count(rng, p.roll_events, n)):
        w = _place(rng, n, int(rng.integers(12, 31)), taken)
        if w is None:
            continue
        a, b = w
        step = np.clip((np.arange(n) - a) / (b - a), 0, 1)
        roll = roll + (0.5 - 0.5 * np.cos(np.pi * step)) * rng.choice([-1, 1]) * math.radians(rng.uniform(60, 120))
        _label(labels, "roll", a, b)
    occlusions = [w for w in (_place(rng, n, int(rng.integers(12, 30)), taken)
                              for _ in range(_count(rng, p.occlusions, n))) if w]

    # arc length from the speed profile
    cum = np.concatenate([[0.0], np.cumsum(v[:-1])])
    span = float(cum.max() - cum.min())
    cover = p.coverage * (s_hi - s_lo)
    if span > 1e-12:
        typical = float(np.percentile(np.abs(v), 90)) + 1e-12
        k = min(cover / span, p.max_step / typical)
        # withdrawal starts deep in the colon; everything else starts near the entry
        s = s_hi - k * (cum.max() - cum) if p.kind == "B" else s_lo + k * (cum - cum.min())
    else:
        s = np.full(n, s_hi if p.kind == "B" else s_lo)

    for a, b in occlusions:
        c = (a + b) // 2
        ramp = max(4, (b - a) // 2)
        s0 = s[max(a - ramp, 0)]  # where the approach starts
        ahead = []
        for f in colon.folds:
            goal = min(f.s - (3 * f.sigma + abs(f.tilt) + p.min_wall_distance + 0.002), s_hi)
            if goal > s0 - 0.5 * p.max_step * ramp and abs(goal - s0) <= p.max_step * ramp:
                ahead.append((goal, f))
        if not ahead:  # no fold within a smooth approach: skip
            continue
        goal, fold = min(ahead, key=lambda x: abs(x[0] - s0))
        e = _envelope(n, a, b, ramp)
        # approach the fold, stay, then carry on from there (the rest of the path shifts)
        after = np.arange(n) >= b
        s = np.where(after, goal + (s - s[min(b, n - 1)]), s * (1 - e) + goal * e)
        j = int(round(fold.s / colon.ring_spacing))
        crest = int(np.argmax(fold.heights))
        target = colon.taenia_phase[j] + (crest + 0.5) * 2 * np.pi / 3
        m = m * (1 - e) + 0.9 * e
        phi = _blend_angle(phi, target, e, c)
        psi = _blend_angle(psi, target, e, c)
        beta = beta * (1 - e) + math.radians(15) * e
        _label(labels, "occluded", a, b, e)
    s = np.clip(s, 0.5 * START_MARGIN, L - 0.5 * END_MARGIN)

    ctl = Controls(s=s, m=m, phi=phi, beta=beta, psi=psi, roll=roll)
    allowed = AllowedRadius(colon, p.min_wall_distance)
    wall = _enforce_clearance(colon, ctl, allowed, scene, p.min_wall_distance)
    poses = poses_from_controls(colon, allowed, ctl.at_many(np.arange(n, dtype=np.float64)))
    return CameraPath(poses=poses, controls=ctl, labels=labels, wall_distance=wall, colon=colon, allowed=allowed)


def _substeps(ctl: Controls, centres: np.ndarray) -> list[tuple[int, float]]:
    """(frame, time) samples between consecutive frames, one per ~0.5 mm of motion."""
    out = []
    for i in range(1, len(ctl.s)):
        k = int(min(32, math.ceil(np.linalg.norm(centres[i] - centres[i - 1]) / 0.0005)))
        out += [(i, i - 1 + j / k) for j in range(1, k)]
    return out


def _enforce_clearance(colon: Colon, ctl: Controls, allowed: AllowedRadius,
                       scene: o3d.t.geometry.RaycastingScene, clearance: float) -> np.ndarray:
    """Shrink offsets until all frame and sub-frame centres keep ``clearance`` from the mesh."""
    n = len(ctl.s)
    for it in range(60):
        centres = camera_centres(colon, allowed, ctl.s, ctl.m, ctl.phi)
        sub = _substeps(ctl, centres)
        if sub:
            cs = ctl.at_many(np.array([t for _, t in sub]))
            pts = np.concatenate([centres, camera_centres(colon, allowed, cs[:, 0], cs[:, 1], cs[:, 2])])
            owner = np.concatenate([np.arange(n), [i for i, _ in sub]])
            owner_prev = np.concatenate([np.arange(n), [i - 1 for i, _ in sub]])
        else:
            pts, owner, owner_prev = centres, np.arange(n), np.arange(n)
        d = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
        bad = d < clearance
        if not bad.any():
            return d[:n].astype(np.float64)
        factor = np.ones(n)
        shrink = 0.8 if it < 40 else 0.0
        factor[owner[bad]] = shrink
        factor[owner_prev[bad]] = shrink
        ctl.m = ctl.m * minimum_filter1d(factor, 3, mode="nearest")
    raise RuntimeError("camera path: could not keep the minimum wall distance (colon too narrow for the camera)")
