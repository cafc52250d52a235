"""Events of a camera path: close-ups of the wall, fast-motion bursts, quick roll turns and
approaches that fill the view with a fold (occluded frames).

Events act on the per-frame :class:`PathSignals` that :func:`camera_path.plan_path` draws
(speed, off-axis offset, view deflection, roll) and label the frames they hold. Rates are
expected events per 1000 frames; each event takes a free window of frames (with a margin)
and blends the signals in and out with raised-cosine ramps. Angles are radians unless a
name says degrees; arc lengths are metres along the centreline.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from datamodules.synthetic.colon import Colon, Fold
from datamodules.synthetic.params import PathParams


@dataclass
class PathSignals:
    """Per-frame (F,) signals of a path before the arc length is integrated.

    ``v``: speed along the centreline (relative units, scaled to metres per frame later);
    ``m``, ``phi``, ``beta``, ``psi``, ``roll``: as the controls of
    :class:`datamodules.synthetic.camera_path.Controls`.
    """

    v: np.ndarray
    m: np.ndarray
    phi: np.ndarray
    beta: np.ndarray
    psi: np.ndarray
    roll: np.ndarray


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
    """Number of events in ``frames`` frames at ``rate`` per 1000 frames (randomly rounded)."""
    x = rate * frames / 1000.0
    return int(math.floor(x + rng.random()))


def _event_windows(rng: np.random.Generator, rate: float, taken: np.ndarray,
                   draw_length: Callable[[], int]) -> Iterator[tuple[int, int]]:
    """Frame windows [a, b) of the events at ``rate`` per 1000 frames, each ``draw_length()``
    frames long, placed where ``taken`` is free (events that find no room are dropped).

    Lazy: each window is drawn when the caller asks for it, after the caller's draws for
    the previous one, so the order of the random draws follows the events.
    """
    n = len(taken)
    for _ in range(_count(rng, rate, n)):
        w = _place(rng, n, draw_length(), taken)
        if w is not None:
            yield w


def _blend_angle(base: np.ndarray, target: float, e: np.ndarray, centre: int) -> np.ndarray:
    """Blend the angles ``base`` towards ``target`` (radians) by ``e``, taking the turn of
    ``target`` nearest to ``base`` at frame ``centre``."""
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


def _look_at_wall(sig: PathSignals, e: np.ndarray, m_goal: float, angle: float, centre: int,
                  beta_goal: float) -> None:
    """Blend the view (where ``e`` = 1) to offset ``m_goal`` towards the wall in direction
    ``angle`` (radians), deflected by ``beta_goal`` radians towards it."""
    sig.m = sig.m * (1 - e) + m_goal * e
    sig.phi = _blend_angle(sig.phi, angle, e, centre)
    sig.psi = _blend_angle(sig.psi, angle, e, centre)
    sig.beta = sig.beta * (1 - e) + beta_goal * e


def add_closeups(sig: PathSignals, p: PathParams, rng: np.random.Generator, taken: np.ndarray,
                 labels: list[str]) -> None:
    """Slow down and look at the wall at close range (40-70 degrees off the lumen direction)."""
    n = len(labels)
    for a, b in _event_windows(rng, p.closeups, taken, lambda: int(np.clip(0.03 * n, 12, 45))):
        e = _envelope(n, a, b, max(4, (b - a) // 4))
        target = rng.uniform(0, 2 * np.pi)
        sig.v *= 1 - 0.9 * e
        _look_at_wall(sig, e, 0.92, target, (a + b) // 2, math.radians(rng.uniform(40, 70)))
        _label(labels, "closeup", a, b, e)


def add_bursts(sig: PathSignals, p: PathParams, rng: np.random.Generator, taken: np.ndarray,
               labels: list[str]) -> None:
    """Short bursts at ``burst_factor`` times the speed (random paths may reverse), with a jolt
    of roll and deflection."""
    n = len(labels)
    for a, b in _event_windows(rng, p.bursts, taken, lambda: int(rng.integers(3, 9))):
        e = _envelope(n, a, b, 1)
        sig.v = sig.v * (1 + (p.burst_factor - 1) * e)
        if p.kind == "random" and rng.random() < 0.3:
            sig.v = sig.v * (1 - 2 * e)
        sig.roll = sig.roll + e * rng.uniform(-0.3, 0.3)
        sig.beta = sig.beta + e * math.radians(rng.uniform(0, 15))
        _label(labels, "burst", a, b, e)


def add_roll_events(sig: PathSignals, p: PathParams, rng: np.random.Generator, taken: np.ndarray,
                    labels: list[str]) -> None:
    """Quick turns of 60-120 degrees about the optical axis (the roll stays turned)."""
    n = len(labels)
    for a, b in _event_windows(rng, p.roll_events, taken, lambda: int(rng.integers(12, 31))):
        step = np.clip((np.arange(n) - a) / (b - a), 0, 1)
        sig.roll = sig.roll + (0.5 - 0.5 * np.cos(np.pi * step)) * rng.choice([-1, 1]) * math.radians(
            rng.uniform(60, 120))
        _label(labels, "roll", a, b)


def place_occlusions(p: PathParams, rng: np.random.Generator, taken: np.ndarray) -> list[tuple[int, int]]:
    """Frame windows [a, b) of the fold approaches (applied once the arc length is known)."""
    return list(_event_windows(rng, p.occlusions, taken, lambda: int(rng.integers(12, 30))))


def _fold_to_approach(colon: Colon, p: PathParams, s0: float, ramp: int, s_hi: float) -> tuple[float, Fold] | None:
    """The fold nearest to arc length ``s0`` (m) that a smooth approach of ``ramp`` frames can
    reach, and the arc length (m) to stop at in front of it; None without one."""
    ahead = []
    for f in colon.folds:
        goal = min(f.s - (3 * f.sigma + abs(f.tilt) + p.min_wall_distance + 0.002), s_hi)
        if goal > s0 - 0.5 * p.max_step * ramp and abs(goal - s0) <= p.max_step * ramp:
            ahead.append((goal, f))
    if not ahead:
        return None
    return min(ahead, key=lambda x: abs(x[0] - s0))


def add_occlusion(colon: Colon, p: PathParams, sig: PathSignals, s: np.ndarray, labels: list[str],
                  window: tuple[int, int], s_hi: float) -> np.ndarray:
    """Approach a fold during frames ``window`` so that it fills the view, stay, then carry on
    from there (the rest of the path shifts); returns the new (F,) arc lengths (m). Without
    a fold within a smooth approach, nothing changes."""
    n = len(s)
    a, b = window
    c = (a + b) // 2
    ramp = max(4, (b - a) // 2)
    s0 = s[max(a - ramp, 0)]  # where the approach starts
    found = _fold_to_approach(colon, p, s0, ramp, s_hi)
    if found is None:
        return s
    goal, fold = found
    e = _envelope(n, a, b, ramp)
    after = np.arange(n) >= b
    s = np.where(after, goal + (s - s[min(b, n - 1)]), s * (1 - e) + goal * e)
    j = int(round(fold.s / colon.ring_spacing))
    crest = int(np.argmax(fold.heights))
    target = colon.taenia_phase[j] + (crest + 0.5) * 2 * np.pi / 3  # the highest crescent's middle
    _look_at_wall(sig, e, 0.9, target, c, math.radians(15))
    _label(labels, "occluded", a, b, e)
    return s
