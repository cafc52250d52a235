"""Where a new fragment goes in the global graph (:class:`FragmentPlacer`).

A new fragment's first frame is matched against a bounded candidate set of keyframes
(:mod:`.retrieval`); then it either hangs off an earlier keyframe, a revisit (:mod:`.reuse`:
no new node, :meth:`FragmentMap.attach`), or becomes a new keyframe with capped edges
(:mod:`.keyframe_edges`), refined densely where that is on (:mod:`.refine`). Edges map points
of the new frame into the earlier keyframe (p_k = T_k,new p_new, metres).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from c3f_slam.config import SlamConfig
from c3f_slam.pipeline.fallback import LinkRecovery
from c3f_slam.pipeline.fragment_map import FragmentMap
from c3f_slam.pipeline.fragments import OVERLAP, Fragment
from c3f_slam.pipeline.frame_step import ATTACHED, KEYFRAME, LONE, FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, Matcher, PairMatch
from c3f_slam.pipeline.keyframe_edges import KeyframeEdge, cap_keyframe_edges
from c3f_slam.pipeline.refine import EdgeRefiner
from c3f_slam.pipeline.retrieval import Candidates, global_descriptor
from c3f_slam.pipeline.reuse import find_host, revisit_edges
from c3f_slam.pipeline.timings import Timings
from c3f_slam.posegraph import EdgeKind


@dataclass
class PlacementCounts:
    """What the placement of new fragments did, for summary.json (see :meth:`FragmentPlacer.stats`)."""

    lone_created: int = 0  #: keyframes created without any edge
    relocalised: int = 0  #: keyframes / fragments placed without an odometry link
    candidates_matched: int = 0  #: keyframe pairs matched (sum over new keyframes)
    edges_capped: int = 0  #: accepted keyframe matches discarded by the loop-edge cap
    candidate_sources: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    reasons: dict[str, int] = field(default_factory=lambda: defaultdict(int))  #: new-fragment reasons


@dataclass(frozen=True, kw_only=True)
class NewFragment:
    """The frame that opens fragment ``fid`` and what it comes after: ``link`` its sparse
    match to the previous frame (T_prev,cur) or None, ``dense`` the dense fallback's in its
    place, ``prev_frag`` the fragment before (closed now) and ``prev`` its last frame."""

    fid: int
    frame: FrameInput
    reason: str
    link: PairMatch | None
    dense: PairMatch | None
    prev_frag: Fragment | None
    prev: FrameFeatures | None


class FragmentPlacer:
    """Places new fragments into ``map``: its keyframe matching (through ``match``, the
    tracker's pair matching), reuse and edge refinement (see the module notes)."""

    def __init__(self, cfg: SlamConfig, K: np.ndarray, slam_map: FragmentMap, match: Matcher,
                 recovery: LinkRecovery, timings: Timings) -> None:
        """``K``: 3x3 intrinsics (px); ``recovery``: the tracker's, for the information matrix of
        dense fallback edges."""
        self.cfg, self.K, self.map, self.match, self.t = cfg, K, slam_map, match, timings
        self.recovery = recovery
        self.refiner = EdgeRefiner(cfg.refine, K) if cfg.refine.enabled else None  # dense keyframe edges
        self.counts = PlacementCounts()

    def place(self, new: NewFragment) -> str:
        """Place fragment ``new.fid`` (its first frame already logged): on an earlier keyframe
        (reuse) or on a new keyframe. Returns the decision kind: attached, keyframe or lone
        (a new keyframe without edges)."""
        self.counts.reasons[new.reason] += 1
        kf = new.frame.features.subset(self.cfg.keyframes.keypoints)
        with self.t.stage("matching"):
            g = global_descriptor(kf.descriptors)
            edges = self._keyframe_edges(new, kf, g)
            sparse = [e for e in edges if e.kind != EdgeKind.FALLBACK]  # a revisit is found by sparse matches only
            host = self._reuse_host(new, sparse) if self.cfg.keyframes.reuse else None
        if host is None:
            return self._add_keyframe(new, kf, g, edges)
        with self.t.stage("posegraph"):
            self._attach(new, sparse, host)
        return ATTACHED

    def _keyframe_edges(self, new: NewFragment, kf: FrameFeatures, g: np.ndarray) -> list[KeyframeEdge]:
        """Edges of a new keyframe: odometry to the previous fragment's node (or the dense
        fallback's edge in its place), then its accepted matches to the candidate keyframes."""
        edges: list[KeyframeEdge] = []
        link, prev_frag = new.link, new.prev_frag
        step, kind = (link, EdgeKind.ODOMETRY) if link is not None else (new.dense, EdgeKind.FALLBACK)
        if step is not None and prev_frag is not None:
            T = prev_frag.node_pose(len(prev_frag) - 1) @ step.T_ij  # previous node <- new keyframe
            edges.append(KeyframeEdge(prev_frag.node, PairMatch(T, step.points_j, step.n), kind))
        same_as_link = link is not None and prev_frag is not None and new.prev is not None \
            and prev_frag.base is None and prev_frag.keyframe == new.prev.index
        cands = self._candidates(g, link or new.dense, prev_frag)
        for k in cands.ids:
            if same_as_link and prev_frag is not None and k == prev_frag.node:  # the link is this pair
                continue
            self.counts.candidates_matched += 1
            m, _ = self.match(self.map.keyframes[k], kf)
            if m is not None:
                kind = EdgeKind.KEYFRAME if prev_frag is not None and k == prev_frag.node else EdgeKind.LOOP
                edges.append(KeyframeEdge(k, m, kind))
                self.counts.candidate_sources[cands.sources.get(k, "all")] += 1
        return edges

    def _candidates(self, g: np.ndarray, link: PairMatch | None, prev_frag: Fragment | None) -> Candidates:
        """Keyframes to match a new keyframe against (:mod:`c3f_slam.pipeline.retrieval`):
        spatial ones around its pose estimate through the odometry link, in the component of
        its predecessor."""
        graph = self.map.graph
        T_est, accept = None, None
        if link is not None and prev_frag is not None:
            T_est = graph.pose(prev_frag.node) @ prev_frag.node_pose(len(prev_frag) - 1) @ link.T_ij
            root = graph.find(prev_frag.node)
            accept = lambda k: graph.find(k) == root
        return self.map.retrieval.candidates(g, graph.pose_array(), T_est, accept)

    def _reuse_host(self, new: NewFragment, edges: list[KeyframeEdge]) -> int | None:
        """The keyframe to hang the new fragment off (:func:`find_host`); after an overlap
        break, not the keyframe the frame just failed the test against (that test also
        checks occlusions)."""
        prev_frag = new.prev_frag
        skip = prev_frag.node if new.reason == OVERLAP and prev_frag is not None and prev_frag.base is None else -1
        odometry = edges[0] if edges and edges[0].kind == EdgeKind.ODOMETRY else None
        return find_host(self.map.graph, [e for e in edges if e.k != skip], new.frame.depth, self.K,
                         (self.cfg.fragments, self.cfg.keyframes), odometry)

    def _add_keyframe(self, new: NewFragment, kf: FrameFeatures, g: np.ndarray, edges: list[KeyframeEdge]) -> str:
        """Open fragment ``new.fid`` on a new keyframe (node) with its capped ``edges``; returns
        the decision kind (lone without edges)."""
        with self.t.stage("matching"):
            edges, dropped = cap_keyframe_edges(edges, self.cfg.keyframes.max_loop_edges, self.map.graph.find)
            self.counts.edges_capped += dropped
            self.map.store_keyframe(kf, g)
        with self.t.stage("posegraph"):  # node bookkeeping; the refinement times itself
            node = self.map.add_keyframe(new.fid, new.frame, new.reason)
        edges, information = self._refine(node, edges, new.frame)
        with self.t.stage("posegraph"):
            merged = self.map.link_keyframe(node, edges, self.recovery.information, information)
            if not edges:
                self.counts.lone_created += 1
            elif (new.link or new.dense) is None and new.prev_frag is not None:
                self.counts.relocalised += 1
            loops = any(e.kind == EdgeKind.LOOP for e in edges)
            self.map.after_keyframe(node, loops or merged > 0)
        return KEYFRAME if edges else LONE

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

    def _attach(self, new: NewFragment, edges: list[KeyframeEdge], host: int) -> None:
        """Open fragment ``new.fid`` on keyframe ``host`` (a revisit): no new node, no stored
        features, only the edges of :func:`revisit_edges` (as host-k edges)."""
        prev_frag = new.prev_frag
        keep = revisit_edges(self.map.graph, edges, host, prev_frag is not None and prev_frag.base is None)
        odometry = next((e for e in edges if e.kind == EdgeKind.ODOMETRY), None)
        merged = self.map.attach(new.fid, new.frame, new.reason, keep, odometry)
        if not any(e.kind == EdgeKind.ODOMETRY for e in edges) and prev_frag is not None:
            self.counts.relocalised += 1
        self.map.after_keyframe(host, len(keep) > 1 or merged > 0)

    def stats(self, fragments: int) -> dict:
        """Counters for summary.json (``fragments``: fragments opened), the refinement's too."""
        c = self.counts
        refine = self.refiner.stats() if self.refiner is not None else {"refine_attempts": 0, "refine_accepted": 0}
        return {
            "lone_created": c.lone_created,
            "relocalised_keyframes": c.relocalised,
            "keyframe_candidates_per_fragment": c.candidates_matched / fragments if fragments else 0.0,
            "keyframe_matches_capped": c.edges_capped,
            "keyframe_matches_by_source": dict(c.candidate_sources),
            "new_fragment_reasons": dict(c.reasons),
            **refine,
        }
