"""The frame-to-frame odometry baseline (``--baseline odometry``): a :class:`SlamBackend`
without fragments, keyframes or optimisation. Poses camera-to-world, metres."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from c3f_slam.outputs import KeyframeGraph
from c3f_slam.pipeline.backend import FrameLog
from c3f_slam.pipeline.components import MapComponent
from c3f_slam.pipeline.config import SlamConfig
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, Matcher, frame_matcher
from c3f_slam.pipeline.timings import Timings


class OdometrySlam:
    """Each frame matched to the last tracked one, poses chained. A frame that does not match
    is left unregistered and the next frame tries the last tracked frame again. Fusion gets
    chunks of ``chunk`` log rows as its fragments."""

    mode = "odometry"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None, chunk: int = 30) -> None:
        """``K`` and ``keyframe_cache`` are accepted for the back-ends' common signature and
        unused (the baseline stores no keyframes)."""
        self.cfg = cfg
        self.t = timings or Timings()
        self.log = FrameLog()
        self.chunk = chunk
        self.last: FrameFeatures | None = None
        self.T_last = np.eye(4)
        self.poses: list[np.ndarray] = []  # per log row (NaN when untracked)
        self._fids: set[int] = set()  # fusion chunks with a tracked frame
        self.n_lost = 0
        self.match: Matcher = frame_matcher(cfg, metric)

    def skip(self, index: int, stamp: float) -> None:
        self.log.append(index, stamp)
        self.poses.append(np.full((4, 4), np.nan))

    def close(self) -> None:
        """Nothing to free."""

    def add(self, frame: FrameInput) -> tuple[int, bool]:
        """Match to the last frame (its image is unused: the baseline has no dense fallback)."""
        feat = frame.features
        fid = len(self.log) // self.chunk  # fusion chunks
        if self.last is None:
            T = np.eye(4)
        else:
            with self.t.stage("matching"):
                m, _ = self.match(self.last, feat)
            if m is None:
                self.n_lost += 1
                self.log.append(feat.index, feat.timestamp)
                self.poses.append(np.full((4, 4), np.nan))
                return -1, False
            T = self.T_last @ m.T_ij
        self.last, self.T_last = feat, T
        self._fids.add(fid)
        self.log.append(feat.index, feat.timestamp, fid, 0)
        self.poses.append(T)
        return fid, False

    def main_fragments(self) -> set[int]:
        return set(self._fids)

    def in_main(self, fid: int) -> bool:
        return fid in self._fids

    def pose_of_log(self, row: int) -> np.ndarray | None:
        P = self.poses[row]
        return None if not np.isfinite(P).all() else P

    def current_pose(self) -> np.ndarray | None:
        return self.T_last if self.last is not None else None

    def finish(self) -> None:
        """Nothing to close or optimise."""

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        poses = np.array(self.poses).reshape(-1, 4, 4)
        reg = np.isfinite(poses).all(axis=(1, 2))
        return np.asarray(self.log.index), np.asarray(self.log.stamp), poses, reg

    def components(self) -> list[MapComponent]:
        """One component: the tracked frames (the baseline never starts another)."""
        _, _, poses, reg = self.trajectory()
        rows = np.flatnonzero(reg)
        return [MapComponent(rows, poses[rows], frozenset(self._fids), 0)] if len(rows) else []

    def stats(self) -> dict:
        return {"fragments": 0, "keyframes": 0, "lost_frames": self.n_lost, "loop_edges": 0, "pruned_edges": 0}

    def keyframe_graph(self) -> KeyframeGraph | None:
        return None

    def n_keyframes(self) -> int:
        return 0
