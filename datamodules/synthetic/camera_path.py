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
fold (occluded frames), quick roll turns (drawn in :mod:`datamodules.synthetic.path_events`).

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
from datamodules.synthetic.path_events import (
    EventLimits,
    PathSignals,
    add_bursts,
    add_closeups,
    add_occlusion,
    add_roll_events,
    place_occlusions,
)

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

    sig = _base_signals(p, rng, n, corr)
    # events that change the speed and view, their ramps within the path's rate limits
    limits = EventLimits.from_params(p, float(np.mean(colon.radius)))
    add_closeups(sig, p, rng, taken, labels, limits)
    add_bursts(sig, p, rng, taken, labels, limits)
    add_roll_events(sig, p, rng, taken, labels, limits)
    occlusions = place_occlusions(p, rng, taken)

    s = _arc_length(sig.v, p, s_lo, s_hi)
    for window in occlusions:
        s = add_occlusion(colon, p, sig, s=s, labels=labels, window=window, s_hi=s_hi, limits=limits)
    s = np.clip(s, 0.5 * START_MARGIN, L - 0.5 * END_MARGIN)

    ctl = Controls(s=s, m=sig.m, phi=sig.phi, beta=sig.beta, psi=sig.psi, roll=sig.roll)
    allowed = AllowedRadius(colon, p.min_wall_distance)
    wall = _enforce_clearance(colon, ctl, allowed, scene, p.min_wall_distance)
    poses = poses_from_controls(colon, allowed, ctl.at_many(np.arange(n, dtype=np.float64)))
    return CameraPath(poses=poses, controls=ctl, labels=labels, wall_distance=wall, colon=colon, allowed=allowed)


def _speed_profile(p: PathParams, noise_v: np.ndarray) -> np.ndarray:
    """(F,) signed relative speed along the centreline from unit noise ``noise_v``: forward
    for ``A``, backward for ``B``, drifting forward for ``random``; ``loop`` turns round halfway."""
    if p.kind == "random":
        v = 0.45 + 0.9 * noise_v
    else:
        v = np.clip(1.0 + 0.35 * noise_v, 0.15, None)
        if p.kind == "B":
            v = -v
    if p.loop:
        n = len(noise_v)
        t = np.arange(n)
        turn = np.clip((t - 0.5 * n) / max(2.0, 0.06 * n) + 0.5, 0.0, 1.0)
        sign = np.cos(np.pi * turn)
        v = np.abs(v) * sign if p.kind != "B" else -np.abs(v) * sign
    return v


def _base_signals(p: PathParams, rng: np.random.Generator, n: int, corr: float) -> PathSignals:
    """Smooth random signals of ``n`` frames (correlated over ``corr`` frames) before any event:
    speed, a wandering offset of about ``lateral``, a small deflection and a slow roll of
    about ``roll`` degrees."""
    v = _speed_profile(p, smooth_1d(rng, n, corr))
    m = np.clip(p.lateral * (0.55 + 0.45 * smooth_1d(rng, n, corr)), 0.0, 1.0)
    phi = rng.uniform(0, 2 * np.pi) + 1.5 * smooth_1d(rng, n, 2 * corr)
    beta = np.abs(0.06 + 0.05 * smooth_1d(rng, n, corr))
    psi = rng.uniform(0, 2 * np.pi) + 1.5 * smooth_1d(rng, n, 2 * corr)
    roll = math.radians(p.roll) * smooth_1d(rng, n, 1.5 * corr)
    return PathSignals(v=v, m=m, phi=phi, beta=beta, psi=psi, roll=roll)


def _arc_length(v: np.ndarray, p: PathParams, s_lo: float, s_hi: float) -> np.ndarray:
    """(F,) arc length (m) from the speed profile ``v``: it covers ``coverage`` of [s_lo, s_hi]
    without exceeding ``max_step`` per frame (90th percentile of the speed)."""
    n = len(v)
    cum = np.concatenate([[0.0], np.cumsum(v[:-1])])
    span = float(cum.max() - cum.min())
    cover = p.coverage * (s_hi - s_lo)
    if span > 1e-12:
        typical = float(np.percentile(np.abs(v), 90)) + 1e-12
        k = min(cover / span, p.max_step / typical)
        # withdrawal starts deep in the colon; everything else starts near the entry
        return s_hi - k * (cum.max() - cum) if p.kind == "B" else s_lo + k * (cum - cum.min())
    return np.full(n, s_hi if p.kind == "B" else s_lo)


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
