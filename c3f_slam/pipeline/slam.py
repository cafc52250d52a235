"""The full SLAM back-end (SPEC §4.2): fragments + global keyframe graph.

Poses are camera-to-world (metres); the world is the frame of the first keyframe of the
component it belongs to. A frame is *registered* when its fragment's keyframe lies in the
main component of the global graph (the largest one, ties to the oldest); lone fragments
are kept and join when one of their keyframes matches the map later.

Per frame (:meth:`FragmentSlam.add`): match to the previous frame; the fragment rules
(:mod:`.fragments`) either extend the active fragment or open a new one. Opening one closes
the active fragment (its intra-fragment optimisation), matches the new keyframe against a
bounded candidate set (:mod:`.retrieval`), then either hangs it off an earlier keyframe
(:mod:`.reuse`) or adds it as a node with capped edges (:mod:`.keyframe_edges`); the global
optimisation follows its schedule (:mod:`.schedule`).

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

from c3f_slam.frustum import frustum_overlap
from c3f_slam.geometry import invert_pose, transform_points
from c3f_slam.pipeline.config import SlamConfig
from c3f_slam.pipeline.fallback import LinkRecovery
from c3f_slam.pipeline.fragment_map import FragmentMap
from c3f_slam.pipeline.fragments import FIRST, OVERLAP, Fragment, new_fragment_reason
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, Matcher, PairMatch, frame_matcher
from c3f_slam.pipeline.keyframe_edges import (
    KeyframeEdge,
    cap_keyframe_edges,
    link_across_break,
    link_new_keyframe,
    place_new_frame,
)
from c3f_slam.pipeline.refine import EdgeRefiner
from c3f_slam.pipeline.rejoin import BreakTails
from c3f_slam.pipeline.retrieval import Candidates, global_descriptor
from c3f_slam.pipeline.reuse import find_host, revisit_edges
from c3f_slam.pipeline.timings import Timings
from c3f_slam.posegraph import EdgeKind
from c3f_slam.posegraph.components import Components


class FragmentSlam(FragmentMap):
    """Full system: fragments with intra-fragment pose graphs and a global keyframe graph."""

    mode = "full"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None) -> None:
        """``K``: 3x3 intrinsics (px); ``keyframe_cache``: folder for the stored keyframes'
        features (emptied now, removed by :meth:`close`); None keeps them in RAM. Same results."""
        super().__init__(cfg, keyframe_cache)
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.t = timings or Timings()
        self._active_row = -1  # log row of the active fragment's first frame
        self.prev: FrameFeatures | None = None  # last placed frame (in the active fragment)
        self.gap = True  # the previous streamed frame was skipped / unusable
        self.match: Matcher = frame_matcher(cfg, metric)
        relaxed = (frame_matcher(cfg.with_(match_filter={"min_matches": cfg.rejoin.relaxed_min_matches}), metric)
                   if cfg.rejoin.relaxed_min_matches else None)
        self.rejoin = BreakTails(cfg.rejoin, lambda a, b: self.match(a, b), relaxed)  # self.match: tests replace it
        self.recovery = LinkRecovery(cfg, self.K, metric)  # guided matching, dense fallback
        #: with the dense fallback: components over the edges of sparse matches only (pruning is
        #: not reflected), so that matches across a fallback edge re-place the side after it
        self.sparse = Components() if cfg.fallback.dense else None
        self.refiner = EdgeRefiner(cfg.refine, self.K) if cfg.refine.enabled else None  # dense keyframe edges
        if cfg.fragments.min_correspondences is None:
            raise ValueError("fragments.min_correspondences is derived from the frame size: "
                             "pass SlamConfig.for_frame_size(width, height)")

    # ------------------------------------------------------------------ per frame
    def skip(self, index: int, stamp: float) -> None:
        """A frame that was not processed (black / saturated / featureless)."""
        self.log.append(index, stamp)
        self.gap = True
        self.recovery.gap()

    def add(self, frame: FrameInput) -> tuple[int, bool]:
        """Process one frame; returns (fragment id, opened a new fragment)."""
        feat = frame.features
        link, n = (None, 0)
        with self.t.stage("matching"):
            if self.prev is not None and not self.gap:
                link, n = self.match(self.prev, feat)
                if link is None:
                    link, n = self.recovery.guided_link(self.prev, feat, min(frame.depth.shape[:2]))
        with self.t.stage("fallback"):
            rgbd = self.recovery.frame(frame.rgb, frame.depth)
            dense = self.recovery.dense_link(rgbd) if link is None and self.prev is not None and not self.gap else None
        reason = self._new_fragment_reason(link, n, frame.depth)
        if reason is None:
            fid, opened = self._extend_active(feat, link), False
        else:
            fid, opened = self._open_fragment(frame, link, reason, dense), True
        self._last_row = len(self.log) - 1
        self.prev, self.gap = feat, False
        self.recovery.settle(link or dense, rgbd)
        if self.rejoin.pending:
            self._try_rejoin(feat)
        return fid, opened

    def _try_rejoin(self, feat: FrameFeatures) -> None:
        """Match the frame against the frames before a pending tracking break
        (:mod:`.rejoin`); an accepted match merges the two components with a rejoin edge."""
        act = self.active
        assert act is not None
        with self.t.stage("matching"):
            root = self.graph.find(act.node)
            r = self.rejoin.step(feat, act.node_pose(len(act) - 1), lambda node: self.graph.find(node) == root)
        if r is None:
            return
        with self.t.stage("posegraph"):
            link_across_break(self.graph, r.tail_node, act.node, r.T_ij, r.points_j, self.sparse)
            self.schedule.after_keyframe(act.node, True, len(self.keyframes))

    def _new_fragment_reason(self, link: PairMatch | None, n: int, depth: np.ndarray) -> str | None:
        """Why this frame opens a new fragment (None: it extends the active one)."""
        act, rules = self.active, self.cfg.fragments
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
        act = self.active
        assert act is not None and link is not None and act.features is not None
        extra = []
        all_pairs = self.cfg.fragments.intra_all_pairs
        if all_pairs or len(act) > 1:
            with self.t.stage("matching"):
                for local in range(len(act) - 1) if all_pairs else [0]:
                    if local == len(act) - 1:
                        continue
                    m, _ = self.match(act.features[local], feat)
                    if m is not None:
                        extra.append((local, m))
        local = act.add_frame(feat, link, extra)
        self.log.append(feat.index, feat.timestamp, act.id, local)
        return act.id

    # ------------------------------------------------------------------ new fragments
    def _close_active(self) -> None:
        """Close the active fragment (intra-fragment optimisation) and move its frames' poses
        into the frame log; the fragment's features and graph are freed."""
        frag = self.active
        if frag is None or frag.rel_poses is not None:
            return
        with self.t.stage("posegraph"):
            frag.close(self.cfg.posegraph)
        self.counts.intra_edges += frag.n_edges
        self.counts.intra_pruned += frag.pruned
        assert frag.rel_poses is not None
        poses = frag.rel_poses if frag.base is None else frag.base @ frag.rel_poses
        self.log.settle(self._active_row, frag.node, poses)

    def _open_fragment(self, frame: FrameInput, link: PairMatch | None, reason: str,
                       dense: PairMatch | None = None) -> int:
        """Close the active fragment and open one on ``frame``: on an earlier keyframe (reuse)
        or as a new keyframe. ``dense``: the fallback's T_prev,cur where sparse ``link`` is
        None. Returns its id."""
        self.counts.reasons[reason] += 1
        prev_frag = self.active
        broken = prev_frag is not None and link is None and dense is None
        tail = list(prev_frag.features or []) if broken else []
        self._close_active()
        if tail:  # a tracking break: its last frames become targets for re-joining
            assert prev_frag is not None
            self.rejoin.record(prev_frag.node, tail, [prev_frag.node_pose(i) for i in range(len(tail))])
        fid = self.counts.fragments
        self.counts.fragments += 1
        self._active_row = len(self.log)
        self.log.append(frame.index, frame.timestamp, fid, 0)
        kf = frame.features.subset(self.cfg.keyframes.keypoints)
        with self.t.stage("matching"):
            g = global_descriptor(kf.descriptors)
            edges = self._keyframe_edges(kf, g, link, prev_frag, dense)
            sparse = [e for e in edges if e.kind != EdgeKind.FALLBACK]  # a revisit is found by sparse matches only
            host = self._reuse_host(sparse, frame.depth, reason, prev_frag) if self.cfg.keyframes.reuse else None
        if host is not None:
            return self._attach(fid, frame, reason, sparse, host, prev_frag)
        return self._add_keyframe(fid, frame, kf, g, reason, edges, link or dense, prev_frag)

    def _keyframe_edges(self, kf: FrameFeatures, g: np.ndarray, link: PairMatch | None,
                        prev_frag: Fragment | None, dense: PairMatch | None = None) -> list[KeyframeEdge]:
        """Edges of a new keyframe: odometry to the previous fragment's node (or the dense
        fallback's edge in its place), then its accepted matches to the candidate keyframes."""
        edges: list[KeyframeEdge] = []
        step, kind = (link, EdgeKind.ODOMETRY) if link is not None else (dense, EdgeKind.FALLBACK)
        if step is not None and prev_frag is not None:
            T = prev_frag.node_pose(len(prev_frag) - 1) @ step.T_ij  # previous node <- new keyframe
            edges.append(KeyframeEdge(prev_frag.node, PairMatch(T, step.points_j, step.n), kind))
        same_as_link = link is not None and prev_frag is not None and self.prev is not None \
            and prev_frag.base is None and prev_frag.keyframe == self.prev.index
        cands = self._candidates(g, link or dense, prev_frag)
        for k in cands.ids:
            if same_as_link and prev_frag is not None and k == prev_frag.node:  # the link is this pair
                continue
            self.counts.candidates_matched += 1
            m, _ = self.match(self.keyframes[k], kf)
            if m is not None:
                kind = EdgeKind.KEYFRAME if prev_frag is not None and k == prev_frag.node else EdgeKind.LOOP
                edges.append(KeyframeEdge(k, m, kind))
                self.counts.candidate_sources[cands.sources.get(k, "all")] += 1
        return edges

    def _candidates(self, g: np.ndarray, link: PairMatch | None, prev_frag: Fragment | None) -> Candidates:
        """Keyframes to match a new keyframe against (:mod:`c3f_slam.pipeline.retrieval`):
        spatial ones around its pose estimate through the odometry link, in the component of
        its predecessor."""
        T_est, accept = None, None
        if link is not None and prev_frag is not None:
            T_est = self.graph.pose(prev_frag.node) @ prev_frag.node_pose(len(prev_frag) - 1) @ link.T_ij
            root = self.graph.find(prev_frag.node)
            accept = lambda k: self.graph.find(k) == root
        return self.retrieval.candidates(g, self.graph.pose_array(), T_est, accept)

    def _reuse_host(self, edges: list[KeyframeEdge], depth: np.ndarray, reason: str,
                    prev_frag: Fragment | None) -> int | None:
        """The keyframe to hang the new fragment off (:func:`find_host`); after an overlap
        break, not the keyframe the frame just failed the test against (that test also
        checks occlusions)."""
        skip = prev_frag.node if reason == OVERLAP and prev_frag is not None and prev_frag.base is None else -1
        odometry = edges[0] if edges and edges[0].kind == EdgeKind.ODOMETRY else None
        return find_host(self.graph, [e for e in edges if e.k != skip], depth, self.K,
                         (self.cfg.fragments, self.cfg.keyframes), odometry)

    def _add_keyframe(self, fid: int, frame: FrameInput, kf: FrameFeatures, g: np.ndarray, reason: str,
                      edges: list[KeyframeEdge], link: PairMatch | None, prev_frag: Fragment | None) -> int:
        """Open fragment ``fid`` on a new keyframe (node) with its capped ``edges``."""
        with self.t.stage("matching"):
            edges, dropped = cap_keyframe_edges(edges, self.cfg.keyframes.max_loop_edges, self.graph.find)
            self.counts.edges_capped += dropped
            self.keyframes.append(kf)
            self.retrieval.add(g)
        with self.t.stage("posegraph"):  # node bookkeeping; the refinement times itself
            node = self.graph.add_node(np.eye(4))
            assert node == len(self.keyframes) - 1
            self.node_fragment.append(fid)
            self.frag_node.append(node)
            self.active = Fragment(fid, frame.features, frame.depth, reason, node=node)
            if self.sparse is not None:
                self.sparse.add_node()
        edges, information = self._refine(node, edges, frame)
        with self.t.stage("posegraph"):
            merged = link_new_keyframe(self.graph, node, edges, self.recovery.information, self.sparse, information)
            if not edges:
                self.counts.lone_created += 1
            elif link is None and prev_frag is not None:
                self.counts.relocalised += 1
            loops = any(e.kind == EdgeKind.LOOP for e in edges)
            self.schedule.after_keyframe(node, loops or merged > 0, len(self.keyframes))
        return fid

    def _refine(self, node: int, edges: list[KeyframeEdge],
                frame: FrameInput) -> tuple[list[KeyframeEdge], dict[int, np.ndarray]]:
        """The new keyframe ``node``'s edges with the accepted dense refinements (:mod:`.refine`)
        in place, and their information matrices by edge index; the frame's clouds are kept."""
        if self.refiner is None:
            return edges, {}
        with self.t.stage("refine"):
            self.refiner.observe(frame.rgb, frame.depth)
            refined = self.refiner.refine_edges(edges)
            self.refiner.keep(node)
        edges = [KeyframeEdge(e.k, PairMatch(refined[n].T, e.match.points_j, e.match.n), e.kind)
                 if n in refined else e for n, e in enumerate(edges)]
        return edges, {n: r.information for n, r in refined.items()}

    def _attach(self, fid: int, frame: FrameInput, reason: str,
                edges: list[KeyframeEdge], host: int, prev_frag: Fragment | None) -> int:
        """Open fragment ``fid`` on keyframe ``host`` (a revisit): no new node, no stored
        features, only the edges of :func:`revisit_edges` (as host-k edges)."""
        with self.t.stage("posegraph"):
            return self._attach_to(fid, frame, reason, edges, host, prev_frag)

    def _attach_to(self, fid: int, frame: FrameInput, reason: str,
                   edges: list[KeyframeEdge], host: int, prev_frag: Fragment | None) -> int:
        keep = revisit_edges(self.graph, edges, host, prev_frag is not None and prev_frag.base is None)
        m_host = keep[0].match
        _, merged = place_new_frame(self.graph, keep, self.sparse)
        for k, m, _ in keep[1:]:
            if self.sparse is not None:
                self.sparse.union(host, k)
            T_hk = m_host.T_ij @ invert_pose(m.T_ij)
            pts_k = transform_points(m.T_ij, m.points_j)  # the match's points in frame k
            self.graph.add_edge(host, k, T_hk, points_j=pts_k, uncertain=True, kind=EdgeKind.LOOP)
        self.counts.attached += 1
        if not any(e.kind == EdgeKind.ODOMETRY for e in edges) and prev_frag is not None:
            self.counts.relocalised += 1
        self.frag_node.append(host)
        self.active = Fragment(fid, frame.features, frame.depth, reason, node=host, base=m_host.T_ij)
        self.schedule.after_keyframe(host, len(keep) > 1 or merged > 0, len(self.keyframes))
        return fid

    def stats(self) -> dict:
        """Counters for summary.json (:meth:`FragmentMap.stats`, the re-joining's and the fallback's)."""
        refine = self.refiner.stats() if self.refiner is not None else {"refine_attempts": 0, "refine_accepted": 0}
        return {**super().stats(), **self.rejoin.stats(), **self.recovery.stats(), **refine}

    def finish(self) -> None:
        """Close the active fragment, make the component with the most frames the main one
        (:meth:`choose_main`) and optimise it one last time, and each other component that
        will be written (:mod:`.components`: ``components.min_frames``, the largest
        ``components.max_written``) on its own."""
        self._close_active()
        with self.t.stage("posegraph"):
            main = self.choose_main()
            if main >= 0:
                self.schedule.finish(len(self.keyframes), main)
            rule = self.cfg.components
            others = [node for node, rows in self._frame_groups()[1:] if rule.writes(len(rows), 1) is None]
            for node in others[:rule.max_written]:
                self.schedule.finish(len(self.keyframes), node)
            self.choose_main()  # pruning may have split the main component
