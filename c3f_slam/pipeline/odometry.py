"""The frame-to-frame odometry baseline (``--set mode=odometry``): a :class:`SlamBackend`
without fragments, keyframes or optimisation. Poses camera-to-world, metres.

:class:`OdometrySlam` (the tracker) holds an :class:`OdometryMap` (``slam.map``: the frame log
and one pose per row, the read side the run loop and the writers use)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from c3f_slam.config import SlamConfig
from c3f_slam.io.run_outputs import KeyframeGraph
from c3f_slam.pipeline.backend import FrameLog
from c3f_slam.pipeline.components import MapComponent
from c3f_slam.pipeline.frame_step import EXTENDED, LOST, FrameDecision, FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, Matcher, frame_matcher
from c3f_slam.pipeline.timings import Timings


class OdometryMap:
    """Per log row a camera-to-world pose (NaN when untracked); fusion gets chunks of ``chunk``
    log rows as its fragments, those with a tracked frame registered."""

    def __init__(self, chunk: int = 30) -> None:
        self.log = FrameLog()
        self.chunk = chunk
        self.poses: list[np.ndarray] = []  # per log row (NaN when untracked)
        self._fids: set[int] = set()  # fusion chunks with a tracked frame
        self._last: np.ndarray | None = None  # pose of the last tracked frame

    def next_fragment(self) -> int:
        """The fusion chunk of the next log row."""
        return len(self.log) // self.chunk

    def append(self, index: int, stamp: float, T: np.ndarray | None) -> int:
        """Log a frame with its pose ``T`` (None: not tracked); returns its chunk (-1 when not tracked)."""
        if T is None:
            self.log.append(index, stamp)
            self.poses.append(np.full((4, 4), np.nan))
            return -1
        fid = self.next_fragment()
        self._fids.add(fid)
        self.log.append(index, stamp, fid, 0)
        self.poses.append(T)
        self._last = T
        return fid

    def main_fragments(self) -> set[int]:
        return set(self._fids)

    def in_main(self, fid: int) -> bool:
        return fid in self._fids

    def pose_of_log(self, row: int) -> np.ndarray | None:
        P = self.poses[row]
        return None if not np.isfinite(P).all() else P

    def current_pose(self) -> np.ndarray | None:
        return self._last

    def current_placement(self) -> tuple[int, np.ndarray] | None:
        """The baseline has one component (0) and one frame: the last tracked frame's pose."""
        return None if self._last is None else (0, self._last)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        poses = np.array(self.poses).reshape(-1, 4, 4)
        reg = np.isfinite(poses).all(axis=(1, 2))
        return np.asarray(self.log.index), np.asarray(self.log.stamp), poses, reg

    def components(self) -> list[MapComponent]:
        """One component: the tracked frames (the baseline never starts another)."""
        _, _, poses, reg = self.trajectory()
        rows = np.flatnonzero(reg)
        return [MapComponent(rows, poses[rows], frozenset(self._fids), 0)] if len(rows) else []

    def keyframe_graph(self) -> KeyframeGraph | None:
        return None

    def n_keyframes(self) -> int:
        return 0


class OdometrySlam:
    """Each frame matched to the last tracked one, poses chained. A frame that does not match
    is left unregistered and the next frame tries the last tracked frame again."""

    mode = "odometry"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None, chunk: int = 30) -> None:
        """``K``: 3x3 intrinsics (px; the reprojection refit); ``keyframe_cache`` is accepted for
        the back-ends' common signature and unused (the baseline stores no keyframes);
        ``chunk``: log rows per fusion fragment."""
        self.cfg = cfg
        self.t = timings or Timings()
        self.map = OdometryMap(chunk)
        self.last: FrameFeatures | None = None
        self.T_last = np.eye(4)
        self.n_lost = 0
        self.match: Matcher = frame_matcher(cfg, metric, K)

    def skip(self, index: int, stamp: float) -> None:
        self.map.append(index, stamp, None)

    def close(self) -> None:
        """Nothing to free."""

    def add(self, frame: FrameInput) -> FrameDecision:
        """Match to the last frame (its image is unused: the baseline has no dense fallback):
        extended (chained; the first frame too) or lost."""
        feat = frame.features
        if self.last is None:
            T = np.eye(4)
        else:
            with self.t.stage("matching"):
                m, _ = self.match(self.last, feat)
            if m is None:
                self.n_lost += 1
                return FrameDecision(feat.index, self.map.append(feat.index, feat.timestamp, None), LOST)
            T = self.T_last @ m.T_ij
        self.last, self.T_last = feat, T
        return FrameDecision(feat.index, self.map.append(feat.index, feat.timestamp, T), EXTENDED)

    def finish(self) -> None:
        """Nothing to close or optimise."""

    def stats(self) -> dict:
        return {"fragments": 0, "keyframes": 0, "lost_frames": self.n_lost, "loop_edges": 0, "pruned_edges": 0}
