"""Re-joining the map across a tracking break (multi-map recovery).

When consecutive frames cannot be matched (a close-up turning to the wall, a fold filling
the view, skipped frames), the frames after the break start a new component of the global
graph. The best targets to join it back are not the keyframes (often tens of frames before
the break) but the last frames tracked before it: the camera usually comes back to about
where it was. :class:`BreakTails` keeps, per recent break, a few of those frames (their
features and node-from-frame poses, camera-to-node, metres) and, for a bounded number of
frames after the break, matches the current frame against them; an accepted match becomes a
``rejoin`` edge between the tail's node and the current fragment's node, which merges the two
components (uncertain: the pose graph may prune it like a loop closure).

For the first ``relaxed_frames`` frames after a break a pair the normal filter rejects is
matched again with a lower correspondence floor (``relaxed_min_matches``: close-ups at the wall
keep only 50-90 keypoints at 128 px, and a turn of a few degrees there leaves 8-9 consistent
matches), accepted only if the motion it gives is one the camera can make in the frames
between the two (``relaxed_max_step`` metres, ``relaxed_max_turn_deg`` degrees per frame).

Cost: at most one pair match per processed frame while a break is pending (two during the
relaxed frames), none otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from c3f_slam.config import RejoinConfig
from c3f_slam.geometry import invert_pose, motion_magnitudes, transform_points
from c3f_slam.pipeline.frontend import FrameFeatures, Matcher, PairMatch


@dataclass
class BreakTail:
    """Frames tracked just before one break: ``frames`` (compact features) and ``poses``
    (node-from-frame, camera-to-node) in the frame of global node ``node``."""

    node: int
    frames: list[FrameFeatures]
    poses: list[np.ndarray]
    age: int = 0  #: frames processed since the break
    tried: int = 0  #: matches attempted


@dataclass(frozen=True)
class Rejoin:
    """An accepted match across a break: T_tailnode,curnode maps points of the current
    frame's node into the tail's node (metres); ``points_j`` are the match's points in the
    current node's frame."""

    tail_node: int
    T_ij: np.ndarray
    points_j: np.ndarray
    n: int


class BreakTails:
    """Pending breaks and the matching of new frames against their tails (see the module notes)."""

    def __init__(self, cfg: RejoinConfig, match: Matcher, relaxed: Matcher | None = None) -> None:
        """``match``: the run's pair matching; ``relaxed``: the same with ``relaxed_min_matches``
        (None: no relaxed attempts)."""
        self.cfg = cfg
        self.match = match
        self.relaxed = relaxed if cfg.relaxed_min_matches else None
        self.pending: list[BreakTail] = []
        self.breaks = 0  #: breaks recorded
        self.joined = 0  #: breaks bridged
        self.joined_relaxed = 0  #: of them by a relaxed match
        self.attempts = 0  #: pair matches tried

    def record(self, node: int, frames: list[FrameFeatures], poses: list[np.ndarray]) -> None:
        """A break right after ``frames`` (in stream order, with their node-from-frame ``poses``)."""
        self.breaks += 1
        if not self.cfg.enabled or not frames:
            return
        step, n = self.cfg.tail_step, self.cfg.tail_frames
        picked = list(range(len(frames) - 1, -1, -step))[:n]  # newest first
        tail = BreakTail(node, [frames[i].subset(self.cfg.keypoints) for i in picked],
                         [np.asarray(poses[i], dtype=np.float64) for i in picked])
        self.pending.append(tail)
        if len(self.pending) > self.cfg.max_pending:
            self.pending.pop(0)

    def step(self, feat: FrameFeatures, T_node_frame: np.ndarray,
             joined: Callable[[int], bool]) -> Rejoin | None:
        """Try the current frame (``feat``, pose ``T_node_frame`` in its fragment's node) against
        one tail frame of one pending break (in turn over the breaks that ``joined(tail_node)``
        does not report as already in the current frame's component; expired ones are dropped).
        Returns the accepted match, if any."""
        for tail in self.pending:
            tail.age += 1
        self.pending = [t for t in self.pending if t.age <= self.cfg.window and not joined(t.node)]
        if not self.pending:
            return None
        tail = self.pending[self.attempts % len(self.pending)]  # round robin over the breaks
        i = _tail_index(tail.tried, len(tail.frames))
        tail.tried += 1
        self.attempts += 1
        m, _ = self.match(tail.frames[i], feat)
        if m is None:
            m = self._relaxed_match(tail, i, feat)
            if m is None:
                return None
            self.joined_relaxed += 1
        self.pending.remove(tail)
        self.joined += 1
        return _edge(tail.node, tail.poses[i], m, T_node_frame)

    def _relaxed_match(self, tail: BreakTail, i: int, feat: FrameFeatures) -> PairMatch | None:
        """The relaxed match of tail frame ``i`` and ``feat`` during the first frames after the
        break, if its motion is plausible for the frames between them (at most ``age + i *
        tail_step``: the tail frames are every ``tail_step``-th before the break, newest first)."""
        if self.relaxed is None or tail.age > self.cfg.relaxed_frames:
            return None
        m, _ = self.relaxed(tail.frames[i], feat)
        if m is None:
            return None
        gap = tail.age + i * self.cfg.tail_step
        step, turn = (float(v[0]) for v in motion_magnitudes(m.T_ij))
        if step > gap * self.cfg.relaxed_max_step or turn > gap * self.cfg.relaxed_max_turn_deg:
            return None
        return m

    def stats(self) -> dict:
        return {"tracking_breaks": self.breaks, "breaks_rejoined": self.joined,
                "breaks_rejoined_relaxed": self.joined_relaxed, "rejoin_attempts": self.attempts}


def _tail_index(tried: int, n: int) -> int:
    """Which tail frame the ``tried``-th attempt uses: every other attempt the last frame
    tracked before the break (the likeliest to match), in between the others in turn."""
    if n == 1 or tried % 2 == 0:
        return 0
    return 1 + (tried // 2) % (n - 1)


def _edge(tail_node: int, T_tn_tf: np.ndarray, m: PairMatch, T_cn_cf: np.ndarray) -> Rejoin:
    """Node-to-node edge from a match of tail frame (pose ``T_tn_tf`` in the tail's node) and
    current frame (pose ``T_cn_cf`` in its node): T_tn,cn = T_tn,tf T_tf,cf T_cf,cn."""
    T = T_tn_tf @ m.T_ij @ invert_pose(T_cn_cf)
    return Rejoin(tail_node, T, transform_points(T_cn_cf, m.points_j), m.n)
