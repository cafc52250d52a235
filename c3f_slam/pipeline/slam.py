"""The SLAM back-end state machine (SPEC §4.2): fragments + global keyframe graph, and the
frame-to-frame odometry baseline.

Poses are camera-to-world (metres); the world is the frame of the first keyframe of the
component it belongs to. A frame is *registered* when its fragment's keyframe lies in the
main component of the global graph (the largest one, ties to the oldest); lone fragments
are kept and join when one of their keyframes matches the map later.

Memory: per frame a fragment id, a local index and a timestamp (and, once its fragment is
closed, a 4x4 relative pose); features only for the active fragment and, compactly
(capped keypoints, uint8/float16 descriptors, float32 points), for every keyframe.
Matching a new keyframe against all earlier keyframes costs O(#keyframes) per keyframe.
"""

from __future__ import annotations

import time
from array import array
from collections import defaultdict
from collections.abc import Callable

import numpy as np

from c3f_slam.frustum import frustum_overlap
from c3f_slam.geometry import invert_pose
from c3f_slam.pipeline.config import SlamConfig
from c3f_slam.pipeline.fragments import FIRST, Fragment, new_fragment_reason
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch, match_frames
from c3f_slam.posegraph import PoseGraph

Matcher = Callable[[FrameFeatures, FrameFeatures], "tuple[PairMatch | None, int]"]


class Timings:
    """Seconds per stage (io, depth, keypoints incl. descriptors, matching, posegraph, fusion)."""

    STAGES = ("io", "depth", "keypoints", "matching", "posegraph", "fusion")

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def add(self, stage: str, t0: float) -> float:
        now = time.perf_counter()
        self.seconds[stage] += now - t0
        return now

    def as_dict(self, n_frames: int) -> dict:
        out = {}
        for s in self.STAGES:
            sec = self.seconds.get(s, 0.0)
            out[s] = {"seconds": sec, "ms_per_frame": 1000.0 * sec / max(n_frames, 1)}
        total = sum(self.seconds.values())
        out["total"] = {"seconds": total, "frames_per_second": n_frames / total if total > 0 else None}
        return out


class FrameLog:
    """Per processed frame: timestamp, fragment id (-1 = not placed) and local index (compact)."""

    def __init__(self) -> None:
        self.index = array("q")
        self.stamp = array("d")
        self.fragment = array("q")
        self.local = array("q")

    def append(self, index: int, stamp: float, fragment: int = -1, local: int = -1) -> None:
        self.index.append(index)
        self.stamp.append(stamp)
        self.fragment.append(fragment)
        self.local.append(local)

    def __len__(self) -> int:
        return len(self.index)


class FragmentSlam:
    """Full system: fragments with intra-fragment pose graphs and a global keyframe graph."""

    mode = "full"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None) -> None:
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.metric = metric
        self.t = timings or Timings()
        self.log = FrameLog()
        self.fragments: list[Fragment] = []  # fragment id == global node id
        self.keyframes: list[FrameFeatures] = []
        self.graph = PoseGraph()
        self.active: Fragment | None = None
        self.prev: FrameFeatures | None = None  # last placed frame (in the active fragment)
        self.gap = True  # the previous streamed frame was skipped / unusable
        self.n_relocalised = 0
        self.n_lone_created = 0
        self.n_optimizations = 0
        self.reasons: dict[str, int] = defaultdict(int)
        self._main: set[int] = set()
        self._poses = np.zeros((0, 4, 4))
        self.match: Matcher = lambda a, b: match_frames(a, b, cfg.match_filter, metric, cfg.ratio)

    # ------------------------------------------------------------------ per frame
    def skip(self, index: int, stamp: float) -> None:
        """A frame that was not processed (black / saturated / featureless)."""
        self.log.append(index, stamp)
        self.gap = True

    def add(self, feat: FrameFeatures, depth: np.ndarray) -> tuple[int, bool]:
        """Process one frame; returns (fragment id, opened a new fragment)."""
        t0 = time.perf_counter()
        link, n = (None, 0)
        if self.prev is not None and not self.gap:
            link, n = self.match(self.prev, feat)
        t0 = self.t.add("matching", t0)
        act = self.active
        reason = FIRST if act is None else None
        T_kc = None
        if act is not None:
            overlap = None
            if link is not None:
                T_kc = act.last_pose @ link.T_ij
                if n >= self.cfg.min_consecutive_correspondences:
                    overlap = frustum_overlap(depth, self.K, T_kc, np.eye(4), depth_j=act.keyframe_depth,
                                              stride=self.cfg.overlap_stride)
            reason = new_fragment_reason(
                n, overlap, len(act), self.cfg.min_consecutive_correspondences, self.cfg.min_overlap,
                self.cfg.max_fragment_frames,
            )
        if reason is None:
            assert act is not None and link is not None and act.features is not None
            extra = []
            if self.cfg.intra_all_pairs or len(act) > 1:
                targets = range(len(act) - 1) if self.cfg.intra_all_pairs else [0]
                t1 = time.perf_counter()
                for local in targets:
                    if local == len(act) - 1:
                        continue
                    m, _ = self.match(act.features[local], feat)
                    if m is not None:
                        extra.append((local, m))
                self.t.add("matching", t1)
            local = act.add_frame(feat, link, extra)
            self.log.append(feat.index, feat.timestamp, act.id, local)
            fid, opened = act.id, False
        else:
            fid, opened = self._open_fragment(feat, depth, link, reason), True
        self.prev, self.gap = feat, False
        return fid, opened

    # ------------------------------------------------------------------ fragments
    def _open_fragment(self, feat: FrameFeatures, depth: np.ndarray, link: PairMatch | None, reason: str) -> int:
        self.reasons[reason] += 1
        prev_frag = self.active
        if prev_frag is not None:
            t0 = time.perf_counter()
            prev_frag.close(self.cfg.posegraph)
            self.t.add("posegraph", t0)
        fid = len(self.fragments)
        frag = Fragment(fid, feat, depth, reason)
        self.fragments.append(frag)
        self.active = frag
        self.log.append(feat.index, feat.timestamp, fid, 0)
        kf = feat.subset(self.cfg.keyframe_keypoints)

        # edges of the new keyframe: odometry to the previous fragment, matches to all keyframes
        t0 = time.perf_counter()
        edges: list[tuple[int, PairMatch, str]] = []
        if link is not None and prev_frag is not None:
            T = prev_frag.last_pose @ link.T_ij  # previous keyframe <- new keyframe
            edges.append((prev_frag.id, PairMatch(T, link.points_j, link.n), "odometry"))
        same_as_link = link is not None and prev_frag is not None and self.prev is not None \
            and prev_frag.keyframe == self.prev.index
        for k, other in enumerate(self.keyframes):
            if same_as_link and prev_frag is not None and k == prev_frag.id:  # the link is this pair
                continue
            m, _ = self.match(other, kf)
            if m is not None:
                kind = "keyframe" if prev_frag is not None and k == prev_frag.id else "loop"
                edges.append((k, m, kind))
        self.keyframes.append(kf)
        t0 = self.t.add("matching", t0)

        node = self.graph.add_node(np.eye(4))
        assert node == fid
        comps = {v: c for c in self.graph.components() for v in c}
        merged = self._place(node, edges, comps)
        loops = False
        for k, m, kind in edges:
            uncertain = kind != "odometry"
            loops |= kind == "loop"
            self.graph.add_edge(k, node, m.T_ij, points_j=m.points_j, uncertain=uncertain, kind=kind)
        if not edges:
            self.n_lone_created += 1
        elif link is None and prev_frag is not None:
            self.n_relocalised += 1
        if self.cfg.optimize_every_keyframe and (loops or merged):
            self.optimize_global(node)
        self.t.add("posegraph", t0)
        self._refresh()
        return fid

    def _place(self, node: int, edges: list[tuple[int, PairMatch, str]], comps: dict[int, list[int]]) -> int:
        """Initial pose of a new keyframe, and rigid moves that bring the other components it
        connects into the frame of the oldest one (so that optimisation starts consistent).
        Returns the number of components merged into the anchor."""
        if not edges:
            return 0
        by_comp: dict[int, tuple[int, PairMatch, str]] = {}
        for k, m, kind in edges:
            c = min(comps[k])
            best = by_comp.get(c)
            if best is None or (kind == "odometry") > (best[2] == "odometry") or m.n > best[1].n:
                by_comp[c] = (k, m, kind)
        anchor = min(by_comp)
        k, m, _ = by_comp[anchor]
        T_wn = self.graph.poses[k] @ m.T_ij
        self.graph.set_pose(node, T_wn)
        for c, (k, m, _) in by_comp.items():
            if c == anchor:
                continue
            G = T_wn @ invert_pose(m.T_ij) @ invert_pose(self.graph.poses[k])
            for v in comps[k]:
                self.graph.set_pose(v, G @ self.graph.poses[v])
        return len(by_comp) - 1

    def optimize_global(self, node: int | None = None) -> list[int]:
        """Optimise the component of ``node`` (default: the main one) anchored at its oldest node."""
        if self.graph.n_nodes == 0 or not self.graph.edges:
            return []
        comps = self.graph.components(include_pruned=True)
        comp = next(c for c in comps if node in c) if node is not None else comps[0]
        if len(comp) < 2:
            return []
        res = self.graph.optimize(self.cfg.posegraph, reference_node=min(comp))
        self.n_optimizations += 1
        self._refresh()
        return res.pruned

    def _refresh(self) -> None:
        comps = self.graph.components()
        best = max(comps, key=lambda c: (len(c), -c[0])) if comps else []
        self._main = set(best)
        self._poses = self.graph.poses

    # ------------------------------------------------------------------ queries
    def main_fragments(self) -> set[int]:
        return set(self._main)

    def is_lone(self, fid: int) -> bool:
        return fid not in self._main

    def pose_of_log(self, row: int) -> np.ndarray | None:
        """World pose of the frame in log row ``row`` (None when unregistered)."""
        fid = self.log.fragment[row]
        if fid < 0 or fid not in self._main:
            return None
        return self._poses[fid] @ self.fragments[fid].pose(self.log.local[row])

    def current_pose(self) -> np.ndarray | None:
        """World pose of the last placed frame (None when lone or none)."""
        for row in range(len(self.log) - 1, -1, -1):
            if self.log.fragment[row] >= 0:
                return self.pose_of_log(row)
        return None

    def finish(self) -> None:
        """Close the active fragment and optimise the main component one last time."""
        t0 = time.perf_counter()
        if self.active is not None and self.active.rel_poses is None:
            self.active.close(self.cfg.posegraph)
        if self.graph.edges:
            main = max(self.graph.components(include_pruned=True), key=lambda c: (len(c), -c[0]))
            self.optimize_global(main[0])
        self._refresh()
        self.t.add("posegraph", t0)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(frame indices, timestamps, poses (N, 4, 4) NaN when unregistered, registered mask)."""
        n = len(self.log)
        poses = np.full((n, 4, 4), np.nan)
        reg = np.zeros(n, bool)
        for r in range(n):
            P = self.pose_of_log(r)
            if P is not None:
                poses[r], reg[r] = P, True
        return np.asarray(self.log.index), np.asarray(self.log.stamp), poses, reg

    def stats(self) -> dict:
        pruned = sum(e.pruned for e in self.graph.edges)
        kinds: dict[str, int] = defaultdict(int)
        for e in self.graph.edges:
            kinds[e.kind] += 1
        return {
            "fragments": len(self.fragments),
            "keyframes": len(self.keyframes),
            "lone_fragments": len([f for f in range(len(self.fragments)) if f not in self._main]),
            "lone_created": self.n_lone_created,
            "relocalised_keyframes": self.n_relocalised,
            "global_edges": len(self.graph.edges),
            "odometry_edges": kinds["odometry"],
            "keyframe_edges": kinds["keyframe"],
            "loop_edges": kinds["loop"],
            "pruned_edges": pruned,
            "pruned_edges_intra": sum(f.pruned for f in self.fragments),
            "intra_edges": sum(f.n_edges for f in self.fragments),
            "global_optimizations": self.n_optimizations,
            "new_fragment_reasons": dict(self.reasons),
            "keyframe_memory_bytes": sum(k.nbytes for k in self.keyframes),
        }


class OdometrySlam:
    """Baseline: frame-to-frame odometry (each frame matched to the last tracked one, poses
    chained, no keyframe matching, no optimisation). A frame that does not match is left
    unregistered and the next frame tries the last tracked frame again."""

    mode = "odometry"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 chunk: int = 30) -> None:
        self.cfg = cfg
        self.t = timings or Timings()
        self.log = FrameLog()
        self.chunk = chunk
        self.last: FrameFeatures | None = None
        self.T_last = np.eye(4)
        self.poses: list[np.ndarray] = []  # per log row (NaN when untracked)
        self.n_lost = 0
        self.match: Matcher = lambda a, b: match_frames(a, b, cfg.match_filter, metric, cfg.ratio)

    def skip(self, index: int, stamp: float) -> None:
        self.log.append(index, stamp)
        self.poses.append(np.full((4, 4), np.nan))

    def add(self, feat: FrameFeatures, depth: np.ndarray) -> tuple[int, bool]:
        fid = len(self.log) // self.chunk  # fusion chunks
        if self.last is None:
            T = np.eye(4)
        else:
            t0 = time.perf_counter()
            m, _ = self.match(self.last, feat)
            self.t.add("matching", t0)
            if m is None:
                self.n_lost += 1
                self.log.append(feat.index, feat.timestamp)
                self.poses.append(np.full((4, 4), np.nan))
                return -1, False
            T = self.T_last @ m.T_ij
        self.last, self.T_last = feat, T
        self.log.append(feat.index, feat.timestamp, fid, 0)
        self.poses.append(T)
        return fid, False

    def main_fragments(self) -> set[int]:
        return set(f for f in self.log.fragment if f >= 0)

    def pose_of_log(self, row: int) -> np.ndarray | None:
        P = self.poses[row]
        return None if not np.isfinite(P).all() else P

    def current_pose(self) -> np.ndarray | None:
        return self.T_last if self.last is not None else None

    def finish(self) -> None:
        pass

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        poses = np.array(self.poses).reshape(-1, 4, 4)
        reg = np.isfinite(poses).all(axis=(1, 2))
        return np.asarray(self.log.index), np.asarray(self.log.stamp), poses, reg

    def stats(self) -> dict:
        return {"fragments": 0, "keyframes": 0, "lost_frames": self.n_lost, "loop_edges": 0, "pruned_edges": 0}
