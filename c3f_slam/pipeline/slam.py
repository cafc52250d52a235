"""The full SLAM back-end (docs/design.md, Fragments and keyframes): fragments + global keyframe graph.

Poses are camera-to-world (metres); the world is the frame of the first keyframe of the
component it belongs to. A frame is *registered* when its fragment's keyframe lies in the
main component of the global graph (the largest one, ties to the oldest); lone fragments
are kept and join when one of their keyframes matches the map later.

Per frame (:meth:`FragmentSlam.add`): match to the previous frame; the fragment rules
(:mod:`.fragments`) either extend the active fragment or open a new one. Opening one closes
the active fragment (its intra-fragment optimisation), and :class:`~.placement.FragmentPlacer`
matches the new keyframe against a bounded candidate set (:mod:`.retrieval`), then either hangs
it off an earlier keyframe (:mod:`.reuse`) or adds it as a node with capped edges
(:mod:`.keyframe_edges`); the global optimisation follows its schedule (:mod:`.schedule`).

Parts: the tracker (:class:`FragmentSlam`) holds the map (:class:`~.fragment_map.FragmentMap`,
``slam.map``: frame log, fragments, keyframes, global graph; every change to it goes through
its methods), the placement of new fragments, the re-joining of breaks (:mod:`.rejoin`) and
the recovery of broken links (:mod:`.fallback`).

Memory: per frame a fragment id, a local index and a timestamp (and, once its fragment is
closed, the node it hangs off and its 4x4 pose relative to it, in the frame log's arrays;
closed fragments keep no object); features only for the active fragment and, compactly
(capped keypoints, uint8/float16 descriptors, float32 points, no pixel keypoints), for every
keyframe (in RAM, or on disk with a 34-byte record and a small LRU in RAM:
:class:`c3f_slam.pipeline.keyframe_store.KeyframeStore`), plus one global appearance
descriptor and a bounded number of graph edges per keyframe (~0.3 KB per edge). With keyframe
reuse, a stream that only revisits mapped places keeps flat memory apart from the frame log
(~170 bytes per frame). Time per frame does not grow with the map: candidates are bounded,
components are kept incrementally (union-find), optimisation is rate-limited and windowed;
what remains proportional to the map is vectorised (appearance scores, spatial distances).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from c3f_slam.camera.frustum import frustum_overlap
from c3f_slam.config import SlamConfig
from c3f_slam.pipeline.fallback import LinkRecovery
from c3f_slam.pipeline.fragment_map import FragmentMap
from c3f_slam.pipeline.fragments import FIRST, intra_fragment_targets, new_fragment_reason
from c3f_slam.pipeline.frame_step import EXTENDED, FrameDecision, FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, Matcher, PairMatch, frame_matcher
from c3f_slam.pipeline.placement import FragmentPlacer, NewFragment
from c3f_slam.pipeline.rejoin import BreakTails
from c3f_slam.pipeline.timings import Timings


class FragmentSlam:
    """Full system: fragments with intra-fragment pose graphs and a global keyframe graph
    (``map``), built one frame at a time by :meth:`add`."""

    mode = "full"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None) -> None:
        """``K``: 3x3 intrinsics (px); ``metric``: the descriptors' distance; ``keyframe_cache``:
        folder for the stored keyframes' features (emptied now, removed by :meth:`close`); None
        keeps them in RAM. Same results."""
        if cfg.fragments.min_correspondences is None:
            raise ValueError("fragments.min_correspondences is derived from the frame size: "
                             "pass SlamConfig.for_frame_size(width, height)")
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.t = timings or Timings()
        self.map = FragmentMap(cfg, keyframe_cache)
        self.prev: FrameFeatures | None = None  # last placed frame (in the active fragment)
        self.gap = True  # the previous streamed frame was skipped / unusable
        self.match: Matcher = frame_matcher(cfg, metric, self.K)
        relaxed = (frame_matcher(cfg.with_(match_filter={"min_matches": cfg.rejoin.relaxed_min_matches}), metric,
                                 self.K)
                   if cfg.rejoin.relaxed_min_matches else None)
        self.rejoin = BreakTails(cfg.rejoin, lambda a, b: self.match(a, b), relaxed)  # self.match: tests replace it
        self.recovery = LinkRecovery(cfg, self.K, metric)  # guided matching, dense fallback
        self.placer = FragmentPlacer(cfg, self.K, self.map, lambda a, b: self.match(a, b), self.recovery, self.t)

    # ------------------------------------------------------------------ per frame
    def skip(self, index: int, stamp: float) -> None:
        """A frame that was not processed (black / saturated / featureless / repeated ...). The
        next frame is still matched to the last processed one (``rejoin.across_skipped``;
        False: the track breaks here), without the motion prior of guided matching."""
        self.map.skip(index, stamp)
        self.gap = self.gap or not self.cfg.rejoin.across_skipped
        self.recovery.gap()

    def add(self, frame: FrameInput) -> FrameDecision:
        """Process one frame; returns what was done with it (extended the active fragment, or
        opened one: on a new keyframe, lone, or attached to an earlier keyframe; re-joined)."""
        feat = frame.features
        link, n = (None, 0)
        with self.t.stage("matching"):
            if self.prev is not None and not self.gap:
                link, n = self.match(self.prev, feat)
                if link is None:
                    link, n = self.recovery.guided_link(self.prev, feat, min(frame.depth.shape[:2]))
        with self.t.stage("fallback"):
            rgbd = self.recovery.frame(frame.rgb, frame.depth)
            tracked = self.prev is not None and not self.gap
            dense = self.recovery.dense_link(rgbd) if link is None and tracked else None
            bridge = self.recovery.bridge_link(rgbd, frame.timestamp) if link is None and dense is None and tracked \
                else None
            dense = dense or bridge
        reason = self._new_fragment_reason(link, n, frame.depth)
        if reason is None:
            fid, kind = self._extend_active(feat, link), EXTENDED
        else:
            fid, kind = self._open_fragment(frame, link, reason, dense)
        self.prev, self.gap = feat, False
        self.recovery.settle(link or dense, rgbd, frame.timestamp, bridged=bridge is not None)
        rejoined = bool(self.rejoin.pending) and self._try_rejoin(feat)
        return FrameDecision(frame.index, fid, kind, reason, rejoined)

    def _try_rejoin(self, feat: FrameFeatures) -> bool:
        """Match the frame against the frames before a pending tracking break
        (:mod:`.rejoin`); an accepted match merges the two components with a rejoin edge
        (returns True)."""
        act, graph = self.map.active, self.map.graph
        assert act is not None
        with self.t.stage("matching"):
            root = graph.find(act.node)
            r = self.rejoin.step(feat, act.node_pose(len(act) - 1), lambda node: graph.find(node) == root)
        if r is None:
            return False
        with self.t.stage("posegraph"):
            self.map.join_break(r.tail_node, r.T_ij, r.points_j)
        return True

    def _new_fragment_reason(self, link: PairMatch | None, n: int, depth: np.ndarray) -> str | None:
        """Why this frame (``depth``: (H, W) metres) opens a new fragment (None: it extends the active one)."""
        act, rules = self.map.active, self.cfg.fragments
        if act is None:
            return FIRST
        overlap = None
        if link is not None and n >= rules.min_correspondences:
            T_kc = act.last_pose @ link.T_ij
            overlap = frustum_overlap(depth, self.K, T_kc, np.eye(4), depth_j=act.keyframe_depth,
                                      stride=rules.overlap_stride)
        return new_fragment_reason(n, overlap, len(act), rules.min_correspondences, rules.min_overlap,
                                   rules.max_frames)

    def _extend_active(self, feat: FrameFeatures, link: PairMatch | None) -> int:
        """Append the frame to the active fragment, with its extra intra-fragment matches."""
        act = self.map.active
        assert act is not None and link is not None and act.features is not None
        rules = self.cfg.fragments
        extra = []
        with self.t.stage("matching"):
            for local in intra_fragment_targets(len(act), rules.intra_all_pairs, rules.intra_recent,
                                                rules.intra_spaced):
                m, _ = self.match(act.features[local], feat)
                if m is not None:
                    extra.append((local, m))
        return self.map.extend(feat, link, extra)

    def _open_fragment(self, frame: FrameInput, link: PairMatch | None, reason: str,
                       dense: PairMatch | None = None) -> tuple[int, str]:
        """Close the active fragment and open one on ``frame`` (:class:`FragmentPlacer`).
        ``dense``: the fallback's T_prev,cur where sparse ``link`` is None. Returns its id and
        the decision kind (keyframe, lone or attached)."""
        prev_frag = self.map.active
        broken = prev_frag is not None and link is None and dense is None
        tail = list(prev_frag.features or []) if broken else []
        with self.t.stage("posegraph"):
            self.map.close_active()
        if tail:  # a tracking break: its last frames become targets for re-joining
            assert prev_frag is not None
            self.rejoin.record(prev_frag.node, tail, [prev_frag.node_pose(i) for i in range(len(tail))])
        fid = self.map.start_fragment(frame.index, frame.timestamp)
        return fid, self.placer.place(NewFragment(fid=fid, frame=frame, reason=reason, link=link, dense=dense,
                                                  prev_frag=prev_frag, prev=self.prev))

    # ------------------------------------------------------------------ end of the stream
    def stats(self) -> dict:
        """Counters for summary.json: the map's, the placement's, the re-joining's and the fallback's."""
        return {**self.map.stats(), **self.placer.stats(self.map.counts.fragments), **self.rejoin.stats(),
                **self.recovery.stats()}

    def finish(self) -> None:
        """Close the active fragment and optimise the map one last time (:meth:`FragmentMap.finish`)."""
        with self.t.stage("posegraph"):
            self.map.close_active()
            self.map.finish()

    def close(self) -> None:
        """Free the map's files (:meth:`FragmentMap.close`); its queries stay available."""
        self.map.close()
