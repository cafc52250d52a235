"""The SLAM back-end state machine (SPEC §4.2): fragments + global keyframe graph, and the
frame-to-frame odometry baseline.

Poses are camera-to-world (metres); the world is the frame of the first keyframe of the
component it belongs to. A frame is *registered* when its fragment's keyframe lies in the
main component of the global graph (the largest one, ties to the oldest); lone fragments
are kept and join when one of their keyframes matches the map later.

Memory: per frame a fragment id, a local index and a timestamp (and, once its fragment is
closed, the node it hangs off and its 4x4 pose relative to it, in the frame log's arrays;
closed fragments keep no object); features only for the active fragment and, compactly
(capped keypoints, uint8/float16 descriptors, float32 points, no pixel keypoints), for every
keyframe (in RAM, or on disk with a 34-byte record and a small LRU in RAM when a cache
folder is given: :class:`c3f_slam.pipeline.keyframe_store.KeyframeStore`), plus one global
appearance descriptor and a bounded number of graph edges per keyframe (its odometry edge
and at most ``max_loop_edges_per_keyframe`` keyframe matches, :func:`cap_keyframe_edges`),
kept in the pose graph's arrays (~0.3 KB per edge). With ``reuse_keyframes`` a fragment that
revisits a mapped place hangs off that place's keyframe (:meth:`FragmentSlam._host`) and
adds no node, stored features or edges, so on a stream that only revisits mapped places the
memory stays flat apart from the frame log (~170 bytes per frame).

Time per frame does not grow with the map (see :class:`SlamConfig` for the switches back to
the paper's literal rules): a new keyframe is matched against a bounded candidate set
(:mod:`c3f_slam.pipeline.retrieval`) instead of all earlier keyframes; components and the
main component are kept incrementally by the pose graph (union-find), poses are read per
node; the global optimisation is rate-limited on big maps and bounded to a window of
``max_optimize_nodes`` keyframes around the new ones. What remains proportional to the map
is vectorised (the appearance scores and the spatial distances over all keyframes: a few
floats per keyframe), or proportional to a merge (moving the components a keyframe joins).
"""

from __future__ import annotations

import math
import time
from array import array
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

from c3f_slam.frustum import frustum_overlap
from c3f_slam.geometry import invert_pose, motion_magnitudes, transform_points
from c3f_slam.pipeline.config import SlamConfig
from c3f_slam.pipeline.fragments import FIRST, OVERLAP, Fragment, new_fragment_reason
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch, match_frames
from c3f_slam.pipeline.keyframe_store import KeyframeStore
from c3f_slam.pipeline.retrieval import Candidates, KeyframeRetrieval, global_descriptor
from c3f_slam.posegraph import PoseGraph

Matcher = Callable[[FrameFeatures, FrameFeatures], "tuple[PairMatch | None, int]"]
KeyframeEdge = tuple[int, PairMatch, str]  # (earlier keyframe k, match T_k,new, kind)


def cap_keyframe_edges(
    edges: list[KeyframeEdge], cap: int | None, component: Callable[[int], int] | None = None
) -> tuple[list[KeyframeEdge], int]:
    """Bound the keyframe-match edges of a new keyframe (see ``max_loop_edges_per_keyframe``
    of :class:`SlamConfig`); returns (kept edges in their input order, number discarded).

    ``odometry`` edges are always kept and not counted. Of the others (kinds ``keyframe`` and
    ``loop``, uncertain), at most ``cap`` are kept (None or 0: all), chosen in this order:
    the match to the most recent keyframe (highest id); then, for each component
    (``component(k)``, e.g. the pose graph's union-find root) that no kept edge reaches yet,
    its strongest match, so that no merge of components is lost; then the strongest of the
    rest. Strength = inlier correspondences (``PairMatch.n``), ties to the more recent keyframe.
    """
    matches = [n for n, e in enumerate(edges) if e[2] != "odometry"]
    if not cap or len(matches) <= cap:
        return list(edges), 0
    comp = component or (lambda k: k)
    covered = {comp(k) for k, _, kind in edges if kind == "odometry"}
    by_strength = sorted(matches, key=lambda n: (edges[n][1].n, edges[n][0]), reverse=True)
    most_recent = max(matches, key=lambda n: edges[n][0])
    chosen = [most_recent]
    covered.add(comp(edges[most_recent][0]))
    for n in by_strength:
        c = comp(edges[n][0])
        if len(chosen) < cap and c not in covered:
            chosen.append(n)
            covered.add(c)
    for n in by_strength:
        if len(chosen) >= cap:
            break
        if n not in chosen:
            chosen.append(n)
    keep = set(chosen) | {n for n, e in enumerate(edges) if e[2] == "odometry"}
    return [e for n, e in enumerate(edges) if n in keep], len(matches) - len(chosen)


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
    """Per processed frame: timestamp, fragment id (-1 = not placed), local index and, once
    its fragment is closed (:meth:`settle`), the global node the frame hangs off (-1 before)
    and its node-from-frame pose (4x4 float64, row-major). Compact arrays, no objects."""

    _UNSET = array("d", bytes(8 * 16))

    def __init__(self) -> None:
        self.index = array("q")
        self.stamp = array("d")
        self.fragment = array("q")
        self.local = array("q")
        self.node = array("q")
        self.rel = array("d")

    def append(self, index: int, stamp: float, fragment: int = -1, local: int = -1) -> None:
        self.index.append(index)
        self.stamp.append(stamp)
        self.fragment.append(fragment)
        self.local.append(local)
        self.node.append(-1)
        self.rel.extend(self._UNSET)

    def settle(self, row0: int, node: int, poses: np.ndarray) -> None:
        """Rows ``row0 ..`` (a closed fragment's frames, in order) hang off ``node`` with
        node-from-frame ``poses`` (n, 4, 4)."""
        n = len(poses)
        self.node[row0:row0 + n] = array("q", [node]) * n
        self.rel[16 * row0:16 * (row0 + n)] = array("d", np.ascontiguousarray(poses, np.float64).tobytes())

    def node_pose(self, row: int) -> np.ndarray:
        """Node-from-frame pose of a settled row."""
        return np.array(self.rel[16 * row:16 * row + 16], dtype=np.float64).reshape(4, 4)

    def __len__(self) -> int:
        return len(self.index)


class FragmentSlam:
    """Full system: fragments with intra-fragment pose graphs and a global keyframe graph."""

    mode = "full"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None) -> None:
        """``keyframe_cache``: folder for the stored keyframes' features (emptied now, removed
        by :meth:`close`); None keeps them in RAM (:class:`KeyframeStore`). Same results."""
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.metric = metric
        self.t = timings or Timings()
        self.log = FrameLog()
        self.n_fragments = 0
        self.frag_node = array("q")  # fragment id -> the global node it hangs off
        self.node_fragment = array("q")  # global node (keyframe) id -> the fragment that made it
        self.keyframes = KeyframeStore(keyframe_cache)
        self.graph = PoseGraph()
        self.retrieval = KeyframeRetrieval(cfg.candidates)
        self.active: Fragment | None = None
        self._active_row = -1  # log row of the active fragment's first frame
        self.prev: FrameFeatures | None = None  # last placed frame (in the active fragment)
        self.gap = True  # the previous streamed frame was skipped / unusable
        self.n_relocalised = 0
        self.n_lone_created = 0
        self.n_attached = 0  # fragments attached to an earlier keyframe (reuse_keyframes)
        self.n_intra_edges = 0
        self.n_intra_pruned = 0
        self.n_optimizations = 0
        self.n_windowed_optimizations = 0
        self.max_optimized_nodes = 0
        self.n_candidates_matched = 0  # keyframe pairs matched (sum over keyframes)
        self.n_edges_capped = 0  # accepted keyframe matches discarded by max_loop_edges_per_keyframe
        self.candidate_sources: dict[str, int] = defaultdict(int)
        self.reasons: dict[str, int] = defaultdict(int)
        self._last_row = -1  # log row of the last placed frame
        self._kf_at_last_opt = 0  # keyframes when the global graph was last optimised
        self._pending = False  # a loop / merge is waiting for the next due optimisation
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
        self._last_row = len(self.log) - 1
        self.prev, self.gap = feat, False
        return fid, opened

    # ------------------------------------------------------------------ fragments
    def _candidates(self, g: np.ndarray, link: PairMatch | None, prev_frag: Fragment | None) -> Candidates:
        """Keyframes to match a new keyframe against (see :mod:`c3f_slam.pipeline.retrieval`):
        spatial ones around its pose estimate through the odometry link, in the component of
        its predecessor."""
        T_est, accept = None, None
        if link is not None and prev_frag is not None:
            T_est = self.graph.pose(prev_frag.node) @ prev_frag.node_pose(len(prev_frag) - 1) @ link.T_ij
            root = self.graph.find(prev_frag.node)
            accept = lambda k: self.graph.find(k) == root  # noqa: E731
        return self.retrieval.candidates(g, self.graph.pose_array(), T_est, accept)

    def _close_active(self) -> None:
        """Close the active fragment (intra-fragment optimisation) and move its frames' poses
        into the frame log; the fragment's features and graph are freed."""
        frag = self.active
        if frag is None or frag.rel_poses is not None:
            return
        t0 = time.perf_counter()
        frag.close(self.cfg.posegraph)
        self.t.add("posegraph", t0)
        self.n_intra_edges += frag.n_edges
        self.n_intra_pruned += frag.pruned
        assert frag.rel_poses is not None
        poses = frag.rel_poses if frag.base is None else frag.base @ frag.rel_poses
        self.log.settle(self._active_row, frag.node, poses)

    def _open_fragment(self, feat: FrameFeatures, depth: np.ndarray, link: PairMatch | None, reason: str) -> int:
        self.reasons[reason] += 1
        prev_frag = self.active
        self._close_active()
        fid = self.n_fragments
        self.n_fragments += 1
        self._active_row = len(self.log)
        self.log.append(feat.index, feat.timestamp, fid, 0)
        kf = feat.subset(self.cfg.keyframe_keypoints)

        # edges of the new keyframe: odometry to the previous fragment's node, matches to the candidates
        t0 = time.perf_counter()
        edges: list[KeyframeEdge] = []
        if link is not None and prev_frag is not None:
            T = prev_frag.node_pose(len(prev_frag) - 1) @ link.T_ij  # previous node <- new keyframe
            edges.append((prev_frag.node, PairMatch(T, link.points_j, link.n), "odometry"))
        same_as_link = link is not None and prev_frag is not None and self.prev is not None \
            and prev_frag.base is None and prev_frag.keyframe == self.prev.index
        g = global_descriptor(kf.descriptors)
        cands = self._candidates(g, link, prev_frag)
        for k in cands.ids:
            if same_as_link and prev_frag is not None and k == prev_frag.node:  # the link is this pair
                continue
            self.n_candidates_matched += 1
            m, _ = self.match(self.keyframes[k], kf)
            if m is not None:
                kind = "keyframe" if prev_frag is not None and k == prev_frag.node else "loop"
                edges.append((k, m, kind))
                self.candidate_sources[cands.sources.get(k, "all")] += 1
        host = None
        if self.cfg.reuse_keyframes:
            # after an overlap break, not the keyframe the frame just failed the test against
            # (that test also checks occlusions)
            skip = prev_frag.node if reason == OVERLAP and prev_frag is not None and prev_frag.base is None else -1
            odometry = edges[0] if edges and edges[0][2] == "odometry" else None
            host = self._host([e for e in edges if e[0] != skip], depth, odometry)
        if host is not None:
            self.t.add("matching", t0)
            return self._attach(fid, feat, depth, reason, edges, host, prev_frag)
        edges, dropped = cap_keyframe_edges(edges, self.cfg.max_loop_edges_per_keyframe, self.graph.find)
        self.n_edges_capped += dropped
        self.keyframes.append(kf)
        self.retrieval.add(g)
        t0 = self.t.add("matching", t0)

        node = self.graph.add_node(np.eye(4))
        assert node == len(self.keyframes) - 1
        self.node_fragment.append(fid)
        self.frag_node.append(node)
        self.active = Fragment(fid, feat, depth, reason, node=node)
        T_wn, merged = self._place(edges)
        if T_wn is not None:
            self.graph.set_pose(node, T_wn)
        loops = False
        for k, m, kind in edges:
            uncertain = kind != "odometry"
            loops |= kind == "loop"
            self.graph.add_edge(k, node, m.T_ij, points_j=m.points_j, uncertain=uncertain, kind=kind)
        if not edges:
            self.n_lone_created += 1
        elif link is None and prev_frag is not None:
            self.n_relocalised += 1
        self._maybe_optimize(node, loops or merged > 0)
        self.t.add("posegraph", t0)
        return fid

    def _maybe_optimize(self, node: int, trigger: bool) -> None:
        if self.cfg.optimize_every_keyframe:
            self._pending |= trigger
            if self._pending and self.optimization_due(node):
                self.optimize_global(node)

    def _host(self, edges: list[KeyframeEdge], depth: np.ndarray, odometry: KeyframeEdge | None) -> int | None:
        """The earlier keyframe a new fragment should hang off instead of adding a keyframe
        (``SlamConfig.reuse_keyframes``), or None. Of the matched keyframes (not the odometry
        link), those the frame could continue a fragment of by the fragment rules (at least
        ``min_consecutive_correspondences`` correspondences, frustum overlap of the frame
        with the keyframe >= ``min_overlap``; no occlusion test, the keyframe's depth is not
        kept) and whose match agrees with the ``odometry`` edge when that reaches the same
        component (camera centres within ``reuse_max_offset`` metres, orientations within
        ``reuse_max_angle_deg``: a wrong keyframe match, or a loop closure that corrects
        more drift than that, makes a keyframe with pose-graph edges instead, where the
        optimisation can weigh and prune it); the one with the largest overlap (ties: more
        correspondences)."""
        g, cfg = self.graph, self.cfg
        T_odo = None
        if odometry is not None:
            k_odo, m_odo, _ = odometry
            T_odo, root_odo = g.pose(k_odo) @ m_odo.T_ij, g.find(k_odo)
        best, best_key = None, None
        for k, m, kind in edges:
            if kind == "odometry" or m.n < cfg.min_consecutive_correspondences:
                continue
            if T_odo is not None and g.find(k) == root_odo:
                offset, angle = motion_magnitudes(invert_pose(T_odo) @ g.pose(k) @ m.T_ij)
                if offset[0] > cfg.reuse_max_offset or angle[0] > cfg.reuse_max_angle_deg:
                    continue
            ov = frustum_overlap(depth, self.K, m.T_ij, np.eye(4), stride=cfg.overlap_stride)
            if ov >= cfg.min_overlap and (best_key is None or (ov, m.n) > best_key):
                best, best_key = k, (ov, m.n)
        return best

    def _attach(self, fid: int, feat: FrameFeatures, depth: np.ndarray, reason: str,
                edges: list[KeyframeEdge], host: int, prev_frag: Fragment | None) -> int:
        """Open fragment ``fid`` on keyframe ``host`` (a revisit): no new node, no stored
        features. Of the new frame's ``edges`` (k, T_k,new) only those that add information
        the graph cannot have yet become host-k edges: the strongest match into each other
        component (merges; the odometry link counts as a match), and the odometry link when
        the previous fragment made a new keyframe (its loop closure). So a stream that only
        revisits mapped places adds no nodes and no edges."""
        t0 = time.perf_counter()
        g = self.graph
        m_host = next(m for k, m, kind in edges if k == host and kind != "odometry")
        root = g.find(host)
        best: dict[int, KeyframeEdge] = {}  # other component -> its strongest edge
        keep: list[KeyframeEdge] = [(host, m_host, "loop")]
        for k, m, kind in edges:
            c = g.find(k)
            if c == root:
                if kind == "odometry" and k != host and prev_frag is not None and prev_frag.base is None:
                    keep.append((k, m, "loop"))
                continue
            b = best.get(c)
            if b is None or m.n > b[1].n:
                best[c] = (k, m, kind)
        keep += [(k, m, "loop") for k, m, _ in best.values()]
        _, merged = self._place(keep)
        loops = False
        for k, m, _ in keep[1:]:
            T_hk = m_host.T_ij @ invert_pose(m.T_ij)
            pts_k = transform_points(m.T_ij, m.points_j)  # the match's points in frame k
            g.add_edge(host, k, T_hk, points_j=pts_k, uncertain=True, kind="loop")
            loops = True
        self.n_attached += 1
        if not any(kind == "odometry" for _, _, kind in edges) and prev_frag is not None:
            self.n_relocalised += 1
        self.frag_node.append(host)
        self.active = Fragment(fid, feat, depth, reason, node=host, base=m_host.T_ij)
        self._maybe_optimize(host, loops or merged > 0)
        self.t.add("posegraph", t0)
        return fid

    def _place(self, edges: list[KeyframeEdge]) -> tuple[np.ndarray | None, int]:
        """World pose of a new frame linked by ``edges`` (k, T_k,new) to earlier keyframes
        (None without edges), and rigid moves that bring the other components it connects
        into the frame of the oldest one (so that optimisation starts consistent). Touches
        only the nodes of the components it merges. Returns (T_w,new, number of components
        merged into the anchor)."""
        if not edges:
            return None, 0
        g = self.graph
        by_comp: dict[int, KeyframeEdge] = {}  # component root -> best edge
        for k, m, kind in edges:
            c = g.find(k)
            best = by_comp.get(c)
            if best is None or (kind == "odometry") > (best[2] == "odometry") or m.n > best[1].n:
                by_comp[c] = (k, m, kind)
        anchor = min(by_comp, key=g.component_oldest)
        k, m, _ = by_comp[anchor]
        T_wn = g.pose(k) @ m.T_ij
        for c, (k, m, _) in by_comp.items():
            if c == anchor:
                continue
            G = T_wn @ invert_pose(m.T_ij) @ invert_pose(g.pose(k))
            g.transform_nodes(g.component_nodes(k), G)
        return T_wn, len(by_comp) - 1

    # ------------------------------------------------------------------ global optimisation
    def optimization_due(self, node: int) -> bool:
        """Whether a pending loop / merge may be optimised now that keyframe ``node`` was
        added (the rate limit of :class:`SlamConfig`): always on small maps or with
        ``optimize_growth=None``; else once the keyframes added since the last optimisation
        are at least ``optimize_growth`` x the nodes an optimisation would take now (the
        size of ``node``'s component, at most ``max_optimize_nodes``). Each optimisation of s
        nodes (cost ~ s^3, dense solver) thus follows >= optimize_growth * s keyframes: a
        geometric schedule while whole components are optimised, constant amortised cost."""
        n = len(self.keyframes)
        growth = self.cfg.optimize_growth
        if growth is None or n < self.cfg.optimize_small_map:
            return True
        size = self.graph.component_size(node)
        if self.cfg.max_optimize_nodes is not None:
            size = min(size, self.cfg.max_optimize_nodes)
        return n - self._kf_at_last_opt >= max(1, math.ceil(growth * size))

    def optimize_global(self, node: int | None = None) -> list[int]:
        """Optimise the component of ``node`` (default: the main one): whole, anchored at its
        oldest node, when it has at most ``max_optimize_nodes`` keyframes; else a window of
        that many, breadth first from ``node`` and the keyframes added since the last
        optimisation, with the rest held fixed. Returns the pruned edges."""
        g = self.graph
        if g.n_nodes == 0 or not g.edges:
            return []
        if node is None:
            node = g.component_oldest(g.main_root)
        cap = self.cfg.max_optimize_nodes
        seeds = [node]
        if cap is not None:
            recent = range(len(self.keyframes) - 1, self._kf_at_last_opt - 1, -1)
            seeds += [k for k in recent if k != node and g.connected(k, node)][: max(cap // 4, 1)]
        window = g.reachable(seeds, None if cap is None else cap + 1)
        whole = cap is None or len(window) <= cap  # reachable() found the whole component
        return self._optimize(window if whole else window[:cap], whole, g.component_oldest(node))

    def _optimize(self, nodes: list[int], whole: bool, oldest: int) -> list[int]:
        """Optimise ``nodes``: a whole component (anchored at its oldest node), or a window
        of one with its other neighbours fixed (``oldest`` fixed too)."""
        if len(nodes) < 2:
            return []
        if whole:
            res = self.graph.optimize(self.cfg.posegraph, reference_node=min(nodes))
        else:
            res = self.graph.optimize(self.cfg.posegraph, reference_node=oldest, nodes=nodes,
                                      max_boundary_edges=self.cfg.window_boundary_edges)
            self.n_windowed_optimizations += 1
        self.n_optimizations += 1
        self._kf_at_last_opt = len(self.keyframes)
        self.max_optimized_nodes = max(self.max_optimized_nodes, len(res.optimized_nodes))
        self._pending = False
        return res.pruned

    # ------------------------------------------------------------------ queries
    def main_fragments(self) -> set[int]:
        """Fragments whose node is in the main component (a new set, O(fragments))."""
        in_main = self.graph.in_main
        return {f for f, node in enumerate(self.frag_node) if in_main(node)}

    def in_main(self, fid: int) -> bool:
        """Fragment ``fid`` is registered (its node is in the main component); O(1)."""
        return self.graph.in_main(self.frag_node[fid])

    def is_lone(self, fid: int) -> bool:
        return not self.in_main(fid)

    def pose_of_log(self, row: int) -> np.ndarray | None:
        """World pose of the frame in log row ``row`` (None when unregistered)."""
        if self.log.fragment[row] < 0:
            return None
        node = self.log.node[row]
        if node >= 0:  # its fragment is closed
            return self.graph.pose(node) @ self.log.node_pose(row) if self.graph.in_main(node) else None
        act = self.active  # a frame of the active fragment
        assert act is not None and act.id == self.log.fragment[row]
        if not self.graph.in_main(act.node):
            return None
        return self.graph.pose(act.node) @ act.node_pose(self.log.local[row])

    def current_pose(self) -> np.ndarray | None:
        """World pose of the last placed frame (None when lone or none)."""
        return self.pose_of_log(self._last_row) if self._last_row >= 0 else None

    def finish(self) -> None:
        """Close the active fragment and optimise the main component one last time: whole
        up to ``final_optimize_nodes`` keyframes, else one sweep of overlapping
        ``max_optimize_nodes`` windows in keyframe order."""
        self._close_active()
        t0 = time.perf_counter()
        g = self.graph
        if g.edges:
            oldest = g.component_oldest(g.main_root)
            cap = self.cfg.final_optimize_nodes
            comp = g.reachable([oldest], None if cap is None else cap + 1)
            if cap is None or len(comp) <= cap:
                self._optimize(comp, True, oldest)
            else:
                members = g.main_component()
                w = min(self.cfg.max_optimize_nodes or cap, cap)
                step = max(w // 2, 1)
                for start in range(0, max(len(members) - w, 0) + step, step):
                    self._optimize(members[start:start + w], False, oldest)
        self.t.add("posegraph", t0)

    def close(self) -> None:
        """Free the keyframe store's file and cache folder (if any); the trajectory, graph and
        stats stay available, matching new keyframes does not."""
        self.keyframes.close()

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

    def keyframe_memory_bytes(self) -> int:
        """Bytes of keyframe data held in RAM: the store's (features, or their records and
        LRU when on disk) and the appearance index (global descriptors)."""
        return self.keyframes.nbytes + self.retrieval.index.nbytes

    def stats(self) -> dict:
        pruned = self.graph.n_pruned()
        kinds: dict[str, int] = defaultdict(int, self.graph.kind_counts())
        n_kf = len(self.keyframes)
        act = self.active if self.active is not None and self.active.rel_poses is None else None
        return {
            "fragments": self.n_fragments,
            "keyframes": n_kf,
            "attached_fragments": self.n_attached,
            "lone_fragments": self.n_fragments - len(self.main_fragments()),
            "lone_created": self.n_lone_created,
            "relocalised_keyframes": self.n_relocalised,
            "global_edges": self.graph.n_edges,
            "odometry_edges": kinds["odometry"],
            "keyframe_edges": kinds["keyframe"],
            "loop_edges": kinds["loop"],
            "pruned_edges": pruned,
            "pruned_edges_intra": self.n_intra_pruned,
            "intra_edges": self.n_intra_edges + (act.n_edges if act is not None else 0),
            "global_optimizations": self.n_optimizations,
            "windowed_optimizations": self.n_windowed_optimizations,
            "max_optimized_nodes": self.max_optimized_nodes,
            "keyframe_candidates_per_fragment": self.n_candidates_matched / self.n_fragments if self.n_fragments else 0.0,
            "keyframe_matches_capped": self.n_edges_capped,
            "keyframe_matches_by_source": dict(self.candidate_sources),
            "new_fragment_reasons": dict(self.reasons),
            "keyframe_memory_bytes": self.keyframe_memory_bytes(),
            "keyframe_disk_bytes": self.keyframes.disk_bytes,
        }


class OdometrySlam:
    """Baseline: frame-to-frame odometry (each frame matched to the last tracked one, poses
    chained, no keyframe matching, no optimisation). A frame that does not match is left
    unregistered and the next frame tries the last tracked frame again."""

    mode = "odometry"

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None, chunk: int = 30) -> None:
        """``keyframe_cache`` is accepted for the back-ends' common signature and unused (the
        baseline stores no keyframes)."""
        self.cfg = cfg
        self.t = timings or Timings()
        self.log = FrameLog()
        self.chunk = chunk
        self.last: FrameFeatures | None = None
        self.T_last = np.eye(4)
        self.poses: list[np.ndarray] = []  # per log row (NaN when untracked)
        self._fids: set[int] = set()  # fusion chunks with a tracked frame
        self.n_lost = 0
        self.match: Matcher = lambda a, b: match_frames(a, b, cfg.match_filter, metric, cfg.ratio)

    def skip(self, index: int, stamp: float) -> None:
        self.log.append(index, stamp)
        self.poses.append(np.full((4, 4), np.nan))

    def close(self) -> None:
        """Nothing to free (the common interface of the back-ends)."""

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
        pass

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        poses = np.array(self.poses).reshape(-1, 4, 4)
        reg = np.isfinite(poses).all(axis=(1, 2))
        return np.asarray(self.log.index), np.asarray(self.log.stamp), poses, reg

    def stats(self) -> dict:
        return {"fragments": 0, "keyframes": 0, "lost_frames": self.n_lost, "loop_edges": 0, "pruned_edges": 0}
