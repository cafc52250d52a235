"""Events of a camera path: close-ups of the wall, fast-motion bursts, quick roll turns and
approaches that fill the view with a fold (occluded frames).

Events act on the per-frame :class:`PathSignals` that :func:`camera_path.plan_path` draws
(speed, off-axis offset, view deflection, roll) and label the frames they hold. Rates are
expected events per 1000 frames; each event takes a free window of frames (with a margin)
and blends the signals in and out with raised-cosine ramps. Angles are radians unless a
name says degrees; arc lengths are metres along the centreline.

Ramps are long enough for :class:`EventLimits` (``path.max_turn_rate`` deg/s,
``path.max_event_speed`` m/s, at the sequence's fps): a ramp starts at its length in frames
and lengthens until the event's fastest frame-to-frame turn of the view (and, for close-ups
and fold approaches, its fastest motion) is within the limit, or within the base path's own
motion over the same frames where that is faster. Without limits (None), ramps keep their
length in frames, as in the simulator before the limits existed (whose close-ups turned up to
~38 degrees per frame); those paths differ from then only after fold approaches, which now
ramp back up to speed instead of resuming it at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

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


@dataclass(frozen=True)
class EventLimits:
    """Per-frame bounds of an event's ramps: ``turn`` radians, ``step`` metres (None: no
    bound); ``radius``: metres of lumen radius, to turn offsets (a fraction of the free
    radius) into metres."""

    turn: float | None = None
    step: float | None = None
    radius: float = 0.025

    @classmethod
    def from_params(cls, p: PathParams, radius: float) -> EventLimits:
        turn = None if p.max_turn_rate is None else math.radians(p.max_turn_rate) / p.fps
        step = None if p.max_event_speed is None else p.max_event_speed / p.fps
        return cls(turn, step, radius)

    @property
    def active(self) -> bool:
        return self.turn is not None or self.step is not None


def _view_motion(sig: PathSignals, lo: int, hi: int, radius: float) -> tuple[float, float]:
    """Largest frame-to-frame turn (radians: view direction from deflection ``beta`` towards
    ``psi``, plus ``roll``) and off-axis motion (metres, offset ``m`` x ``radius`` at angle
    ``phi``) of ``sig`` over frames [lo, hi)."""
    lo, hi = max(lo, 0), min(hi, len(sig.m))
    if hi - lo < 2:
        return 0.0, 0.0
    b, q = sig.beta[lo:hi], sig.psi[lo:hi]
    d = np.stack([np.sin(b) * np.cos(q), np.sin(b) * np.sin(q), np.cos(b)], axis=1)
    view = np.arccos(np.clip(np.sum(d[1:] * d[:-1], axis=1), -1.0, 1.0))
    turn = np.hypot(view, np.diff(sig.roll[lo:hi]))
    rho = sig.m[lo:hi] * radius
    xy = np.stack([rho * np.cos(sig.phi[lo:hi]), rho * np.sin(sig.phi[lo:hi])], axis=1)
    return float(turn.max()), float(np.linalg.norm(np.diff(xy, axis=0), axis=1).max())


def _over(value: float, limit: float | None, base: float) -> float:
    """How many times ``value`` exceeds ``limit`` (or the base motion ``base`` where that
    is faster); 1 or less: within it."""
    if limit is None:
        return 0.0
    return value / max(limit, 1.05 * base, 1e-12)


def fit_ramp(ramp: int, apply: Callable[[int], tuple[PathSignals, float]], base: PathSignals,
             span: Callable[[int], tuple[int, int]], limits: EventLimits, max_ramp: int) -> int:
    """The shortest ramp of at least ``ramp`` frames (at most ``max_ramp``) whose event keeps
    ``limits``: ``apply(r)`` gives the signals with the event applied with ramp ``r`` and its
    fastest extra arc-length step (m per frame, 0 if none); ``span(r)`` the frames it moves."""
    if not limits.active:
        return ramp
    for _ in range(8):
        sig, step_s = apply(ramp)
        lo, hi = span(ramp)
        turn, move = _view_motion(sig, lo, hi, limits.radius)
        turn0, move0 = _view_motion(base, lo, hi, limits.radius)
        excess = max(_over(turn, limits.turn, turn0), _over(math.hypot(move, step_s), limits.step, move0))
        if excess <= 1.0 or ramp >= max_ramp:
            return ramp
        ramp = min(max_ramp, int(math.ceil(ramp * excess * 1.02)))
    return ramp


def _copy(sig: PathSignals) -> PathSignals:
    return replace(sig, **{k: getattr(sig, k).copy() for k in ("v", "m", "phi", "beta", "psi", "roll")})


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
                 labels: list[str], limits: EventLimits | None = None) -> None:
    """Slow down and look at the wall at close range (40-70 degrees off the lumen direction)."""
    n = len(labels)
    limits = limits or EventLimits()
    for a, b in _event_windows(rng, p.closeups, taken, lambda: int(np.clip(0.03 * n, 12, 45))):
        target = rng.uniform(0, 2 * np.pi)
        beta_goal = math.radians(rng.uniform(40, 70))

        def look(ramp: int, sig: PathSignals = sig, a: int = a, b: int = b, target: float = target,
                 beta_goal: float = beta_goal) -> tuple[PathSignals, float]:
            out = _copy(sig)
            _look_at_wall(out, _envelope(n, a, b, ramp), 0.92, target, (a + b) // 2, beta_goal)
            return out, 0.0

        ramp = fit_ramp(max(4, (b - a) // 4), look, sig, lambda r, a=a, b=b: (a - r - 1, b + r + 1), limits, n // 3)
        e = _envelope(n, a, b, ramp)
        sig.v *= 1 - 0.9 * e
        _look_at_wall(sig, e, 0.92, target, (a + b) // 2, beta_goal)
        _label(labels, "closeup", a, b, e)


def add_bursts(sig: PathSignals, p: PathParams, rng: np.random.Generator, taken: np.ndarray,
               labels: list[str], limits: EventLimits | None = None) -> None:
    """Short bursts at ``burst_factor`` times the speed (random paths may reverse), with a jolt
    of roll and deflection (its ramps within ``limits.turn``; the speed is not bounded)."""
    n = len(labels)
    limits = replace(limits or EventLimits(), step=None)
    for a, b in _event_windows(rng, p.bursts, taken, lambda: int(rng.integers(3, 9))):
        reverse = p.kind == "random" and rng.random() < 0.3
        d_roll, d_beta = rng.uniform(-0.3, 0.3), math.radians(rng.uniform(0, 15))

        def jolt(ramp: int, sig: PathSignals = sig, a: int = a, b: int = b, d_roll: float = d_roll,
                 d_beta: float = d_beta) -> tuple[PathSignals, float]:
            e = _envelope(n, a, b, ramp)
            return replace(sig, roll=sig.roll + e * d_roll, beta=sig.beta + e * d_beta), 0.0

        e = _envelope(n, a, b, fit_ramp(1, jolt, sig, lambda r, a=a, b=b: (a - r - 1, b + r + 1), limits, n // 3))
        sig.v = sig.v * (1 + (p.burst_factor - 1) * e)
        if reverse:
            sig.v = sig.v * (1 - 2 * e)
        sig.roll = sig.roll + e * d_roll
        sig.beta = sig.beta + e * d_beta
        _label(labels, "burst", a, b, e)


def add_roll_events(sig: PathSignals, p: PathParams, rng: np.random.Generator, taken: np.ndarray,
                    labels: list[str], limits: EventLimits | None = None) -> None:
    """Quick turns of 60-120 degrees about the optical axis (the roll stays turned); a turn
    too fast for ``limits.turn`` takes longer (its window grows into the following frames)."""
    n = len(labels)
    limits = replace(limits or EventLimits(), step=None)
    for a, b in _event_windows(rng, p.roll_events, taken, lambda: int(rng.integers(12, 31))):
        turn = rng.choice([-1, 1]) * math.radians(rng.uniform(60, 120))

        def roll(length: int, sig: PathSignals = sig, a: int = a, turn: float = turn) -> tuple[PathSignals, float]:
            step = np.clip((np.arange(n) - a) / length, 0, 1)
            return replace(sig, roll=sig.roll + (0.5 - 0.5 * np.cos(np.pi * step)) * turn), 0.0

        length = fit_ramp(b - a, roll, sig, lambda r, a=a: (a - 1, a + r + 1), limits, max(b - a, n - 1 - a))
        sig.roll = roll(length)[0].roll
        taken[a:a + length] = True
        _label(labels, "roll", a, min(a + length, n))


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


def _approach(s: np.ndarray, a: int, b: int, ramp: int, goal: float) -> np.ndarray:
    """(F,) arc lengths (m) of ``s`` blended to ``goal`` over frames [a, b) with ``ramp``-frame
    ramps; after the window the path carries on from the goal (the rest shifts), its steps
    ramping up from standstill over the ramp out."""
    n = len(s)
    e = _envelope(n, a, b, ramp)
    out = s * (1 - e) + goal * e
    if b < n:
        steps = np.diff(s)[b:] * (1 - e[b + 1:])  # step into frame t, t > b
        out[b:] = goal + np.concatenate([[0.0], np.cumsum(steps)])
    return out


def add_occlusion(colon: Colon, p: PathParams, sig: PathSignals, *, s: np.ndarray, labels: list[str],
                  window: tuple[int, int], s_hi: float, limits: EventLimits | None = None) -> np.ndarray:
    """Approach a fold during frames ``window`` so that it fills the view, stay, then carry on
    from there (the rest of the path shifts); returns the new (F,) arc lengths (m). Without
    a fold within a smooth approach, nothing changes. The ramps lengthen (earlier start)
    until the approach keeps ``limits``."""
    n = len(s)
    a, b = window
    c = (a + b) // 2
    ramp = max(4, (b - a) // 2)
    found = _fold_to_approach(colon, p, s[max(a - ramp, 0)], ramp, s_hi)
    if found is None:
        return s
    goal, fold = found
    j = int(round(fold.s / colon.ring_spacing))
    crest = int(np.argmax(fold.heights))
    target = colon.taenia_phase[j] + (crest + 0.5) * 2 * np.pi / 3  # the highest crescent's middle
    base_step = float(np.abs(np.diff(s)).max()) if n > 1 else 0.0

    def approach(r: int) -> tuple[PathSignals, float]:
        out = _copy(sig)
        _look_at_wall(out, _envelope(n, a, b, r), 0.9, target, c, math.radians(15))
        extra = float(np.abs(np.diff(_approach(s, a, b, r, goal)[max(a - r - 1, 0):b + r + 1])).max())
        return out, extra if extra > 1.05 * base_step else 0.0

    ramp = fit_ramp(ramp, approach, sig, lambda r: (a - r - 1, b + r + 1), limits or EventLimits(), n // 3)
    e = _envelope(n, a, b, ramp)
    s = _approach(s, a, b, ramp, goal)
    _look_at_wall(sig, e, 0.9, target, c, math.radians(15))
    _label(labels, "occluded", a, b, e)
    return s
