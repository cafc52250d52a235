"""The map a :class:`~c3f_slam.pipeline.slam.FragmentSlam` builds and holds (``slam.map``).

State: the frame log (per streamed frame its fragment, local index and, once the fragment is
closed, the node it hangs off and its node-from-frame pose), the global keyframe graph
(camera-to-world node poses, metres) with its optimisation schedule, the stored keyframes and
their appearance index, which node each fragment hangs off, and the active fragment. Every
change goes through a method here (a frame appended or skipped, a fragment started or closed,
a keyframe stored and linked, a fragment attached to an earlier keyframe, a break joined);
the tracker (:class:`FragmentSlam`) decides which, the map keeps its state consistent.

Queries: which fragments are registered (their node in the main component), each frame's
world pose, the trajectory, the keyframe graph, the components (:meth:`FragmentMap.components`)
and the counters for summary.json. The main component is, while the stream runs, the one
with the most keyframes (O(1) to keep, :class:`~c3f_slam.posegraph.PoseGraph`); at the end
(:meth:`FragmentMap.choose_main`) the one with the most registered frames.
"""

from __future__ import annotations

from array import array
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from c3f_slam.config import SlamConfig
from c3f_slam.geometry import invert_pose
from c3f_slam.io.run_outputs import KeyframeGraph
from c3f_slam.pipeline.backend import FrameLog
from c3f_slam.pipeline.components import MapComponent
from c3f_slam.pipeline.fragments import Fragment
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch
from c3f_slam.pipeline.keyframe_edges import KeyframeEdge, link_across_break, link_new_keyframe, link_revisit
from c3f_slam.pipeline.keyframe_store import KeyframeStore
from c3f_slam.pipeline.retrieval import KeyframeRetrieval
from c3f_slam.pipeline.schedule import OptimizationSchedule
from c3f_slam.pipeline.smoothing import smooth_poses
from c3f_slam.posegraph import PoseGraph
from c3f_slam.posegraph.components import Components


@dataclass
class MapCounts:
    """What was added to the map, for summary.json (see :meth:`FragmentMap.stats`)."""

    fragments: int = 0  #: fragments opened (also the next fragment id)
    attached: int = 0  #: fragments hung off an earlier keyframe (reuse)
    intra_edges: int = 0  #: edges of closed fragments' graphs
    intra_pruned: int = 0  #: of them pruned


class FragmentMap:
    """Fragments, keyframes and the global graph: the changes the tracker makes and the queries
    the run loop and the output writers use (the back-end's read side,
    :class:`~c3f_slam.pipeline.backend.SlamMap`)."""

    def __init__(self, cfg: SlamConfig, keyframe_cache: str | Path | None = None) -> None:
        """``keyframe_cache``: folder for the stored keyframes' features (emptied now, removed
        by :meth:`close`); None keeps them in RAM. Same results."""
        self.cfg = cfg
        self.log = FrameLog()
        self.counts = MapCounts()
        self.frag_node = array("q")  # fragment id -> the global node it hangs off
        self.node_fragment = array("q")  # global node (keyframe) id -> the fragment that made it
        self.keyframes = KeyframeStore(keyframe_cache)
        self.graph = PoseGraph()
        self.retrieval = KeyframeRetrieval(cfg.candidates)
        self.schedule = OptimizationSchedule(cfg.optimization, cfg.posegraph, self.graph)
        #: with the dense fallback: components over the edges of sparse matches only (pruning is
        #: not reflected), so that matches across a fallback edge re-place the side after it
        self.sparse = Components() if cfg.fallback.dense else None
        self.active: Fragment | None = None
        self._active_row = -1  # log row of the active fragment's first frame
        self._active_rows: list[int] = []  # log rows of its frames (skipped frames may lie between)
        self._last_row = -1  # log row of the last placed frame
        self._main_node = -1  # once chosen (choose_main): a node of the main component

    # ------------------------------------------------------------------ frames and fragments
    def skip(self, index: int, stamp: float) -> None:
        """A streamed frame that is not placed (log row without a fragment)."""
        self.log.append(index, stamp)

    def extend(self, feat: FrameFeatures, link: PairMatch, extra: list[tuple[int, PairMatch]]) -> int:
        """Append ``feat`` to the active fragment (``link``: T_prev,cur; ``extra``: matches to
        its other frames by local index); returns the fragment id."""
        act = self.active
        assert act is not None
        local = act.add_frame(feat, link, extra)
        self.log.append(feat.index, feat.timestamp, act.id, local)
        self._last_row = len(self.log) - 1
        self._active_rows.append(self._last_row)
        return act.id

    def close_active(self) -> None:
        """Close the active fragment (intra-fragment optimisation) and move its frames' poses
        into the frame log; the fragment's features and graph are freed."""
        frag = self.active
        if frag is None or frag.rel_poses is not None:
            return
        frag.close(self.cfg.posegraph)
        self.counts.intra_edges += frag.n_edges
        self.counts.intra_pruned += frag.pruned
        assert frag.rel_poses is not None
        poses = frag.rel_poses if frag.base is None else frag.base @ frag.rel_poses
        self.log.settle(self._active_row, frag.node, poses, self._active_rows)
        self._active_rows = []

    def start_fragment(self, index: int, stamp: float) -> int:
        """Log the first frame of a new fragment (after :meth:`close_active`); returns its id.
        :meth:`add_keyframe` or :meth:`attach` places it."""
        fid = self.counts.fragments
        self.counts.fragments += 1
        self._active_row = self._last_row = len(self.log)
        self._active_rows = [self._active_row]
        self.log.append(index, stamp, fid, 0)
        return fid

    # ------------------------------------------------------------------ the global graph
    def store_keyframe(self, kf: FrameFeatures, g: np.ndarray) -> None:
        """Keep a new keyframe's compact features ``kf`` and global descriptor ``g``."""
        self.keyframes.append(kf)
        self.retrieval.add(g)

    def add_keyframe(self, fid: int, frame: FrameInput, reason: str) -> int:
        """Fragment ``fid`` on the keyframe just stored: a new node (identity pose until
        :meth:`link_keyframe`), the active fragment from now on. Returns the node."""
        node = self.graph.add_node(np.eye(4))
        assert node == len(self.keyframes) - 1
        self.node_fragment.append(fid)
        self.frag_node.append(node)
        self.active = Fragment(fid, frame.features, frame.depth, reason, node=node)
        if self.sparse is not None:
            self.sparse.add_node()
        return node

    def link_keyframe(self, node: int, edges: list[KeyframeEdge], dense_information: Callable[[PairMatch], np.ndarray],
                      information: dict[int, np.ndarray]) -> int:
        """Place keyframe ``node`` and add its ``edges`` (:func:`link_new_keyframe`); returns the
        number of components merged."""
        return link_new_keyframe(self.graph, node, edges, dense_information, sparse=self.sparse,
                                 information=information)

    def attach(self, fid: int, frame: FrameInput, reason: str, keep: list[KeyframeEdge],
               odometry: KeyframeEdge | None = None) -> int:
        """Fragment ``fid`` hung off the keyframe of ``keep[0]`` (the host, a revisit): no new
        node, the host's match as its base (moved ``keyframes.reuse_odometry_weight`` of the way
        to where the ``odometry`` edge puts the frame, when it reaches the host's component) and
        the other edges of ``keep`` (host-k loop edges; :func:`~c3f_slam.pipeline.reuse.revisit_edges`).
        Returns the number of components merged."""
        host, m_host = keep[0].k, keep[0].match
        merged = link_revisit(self.graph, keep, self.sparse)
        self.counts.attached += 1
        self.frag_node.append(host)
        base = m_host.T_ij
        w = self.cfg.keyframes.reuse_odometry_weight
        if w > 0 and odometry is not None and self.graph.connected(odometry.k, host):
            by_odometry = invert_pose(self.graph.pose(host)) @ self.graph.pose(odometry.k) @ odometry.match.T_ij
            base = blend_poses(base, by_odometry, w)
        self.active = Fragment(fid, frame.features, frame.depth, reason, node=host, base=base)
        return merged

    def join_break(self, tail_node: int, T_ij: np.ndarray, points_j: np.ndarray) -> None:
        """A rejoin edge from ``tail_node`` to the active fragment's node (:func:`link_across_break`),
        which merges their components, then the schedule's turn."""
        act = self.active
        assert act is not None
        link_across_break(self.graph, tail_node, act.node, T_ij, points_j, sparse=self.sparse)
        self.after_keyframe(act.node, True)

    def after_keyframe(self, node: int, trigger: bool) -> None:
        """Keyframe ``node`` was added or a fragment hung off it; ``trigger``: a loop edge or a
        merge (the optimisation schedule's rules)."""
        self.schedule.after_keyframe(node, trigger, len(self.keyframes))

    def finish(self) -> None:
        """Make the component with the most frames the main one (:meth:`choose_main`) and
        optimise it one last time, and each other component that will be written
        (:mod:`.components`: ``components.min_frames``, the largest ``components.max_written``)
        on its own. Call it after :meth:`close_active`."""
        main = self.choose_main()
        if main >= 0:
            self.schedule.finish(len(self.keyframes), main)
        rule = self.cfg.components
        others = [node for node, rows in self._frame_groups()[1:] if rule.writes(len(rows), 1) is None]
        for node in others[:rule.max_written]:
            self.schedule.finish(len(self.keyframes), node)
        self.choose_main()  # pruning may have split the main component
        self.smooth_paths()

    def smooth_paths(self) -> None:
        """Refit every component's frame poses, in stream order, under the constant-velocity
        motion prior (``smoothing.motion_prior_s``, :func:`~c3f_slam.pipeline.smoothing.smooth_poses`):
        the frames stay hung off their nodes, with new node-from-frame poses. Nothing at tau 0.
        Call it after the last optimisation (every fragment closed); O(frames)."""
        rule = self.cfg.smoothing
        if rule.prior_s <= 0:
            return
        stamps = np.frombuffer(self.log.stamp, np.float64)
        for _, rows in self._frame_groups():
            nodes = [self.log.node[r] for r in rows.tolist()]
            world = np.stack([self.graph.pose(k) @ self.log.node_pose(r) for k, r in zip(nodes, rows.tolist())])
            smooth = smooth_poses(stamps[rows], world, rule.prior_s, max_gap_s=rule.max_gap_s, robust_k=rule.robust_k,
                                  robust_iterations=rule.robust_iterations)
            node_inv = np.stack([invert_pose(self.graph.pose(k)) for k in nodes])
            self.log.set_node_poses(rows, node_inv @ smooth)

    def close(self) -> None:
        """Free the keyframe store's file and cache folder (if any); the trajectory, graph and
        stats stay available, matching new keyframes does not."""
        self.keyframes.close()

    # ------------------------------------------------------------------ queries
    def _node_in_main(self, node: int) -> bool:
        """``node`` lies in the main component (the graph's, until :meth:`choose_main`); O(1)."""
        if self._main_node < 0:
            return self.graph.in_main(node)
        return 0 <= node < self.graph.n_nodes and self.graph.connected(node, self._main_node)

    def main_fragments(self) -> set[int]:
        """Fragments whose node is in the main component (a new set, O(fragments))."""
        in_main = self._node_in_main
        return {f for f, node in enumerate(self.frag_node) if in_main(node)}

    def in_main(self, fid: int) -> bool:
        """Fragment ``fid`` is registered (its node is in the main component); O(1)."""
        return self._node_in_main(self.frag_node[fid])

    def _frame_groups(self) -> list[tuple[int, np.ndarray]]:
        """:func:`frame_groups` of this map."""
        return frame_groups(self.log.fragments(), self.frag_node, self.graph)

    def choose_main(self) -> int:
        """Make the component with the most registered frames the main one (ties: the one
        with the oldest keyframe); returns its oldest node (-1 without frames)."""
        groups = self._frame_groups()
        self._main_node = groups[0][0] if groups else -1
        return self._main_node

    def components(self) -> list[MapComponent]:
        """Every component with its frames and their current poses (camera-to-world, in
        the component's world frame), by frames (after :meth:`finish`, which chose it, the
        main one first). Call it after :meth:`finish` (every fragment closed); O(frames)."""
        out = []
        fragment = self.log.fragments()
        for node, rows in self._frame_groups():
            poses = np.stack([self.graph.pose(self.log.node[r]) @ self.log.node_pose(r) for r in rows.tolist()])
            members = self.graph.component_nodes(node)
            frags = frozenset(fragment[rows].tolist())
            out.append(MapComponent(rows, poses, frags, len(members)))
        return out

    def _placed(self, row: int) -> tuple[int, np.ndarray] | None:
        """The global node log row ``row`` hangs off and the row's pose in the frame of that
        node's component (None when not placed)."""
        if self.log.fragment[row] < 0:
            return None
        node = self.log.node[row]
        if node >= 0:  # its fragment is closed
            return node, self.graph.pose(node) @ self.log.node_pose(row)
        act = self.active  # a frame of the active fragment
        assert act is not None and act.id == self.log.fragment[row]
        return act.node, self.graph.pose(act.node) @ act.node_pose(self.log.local[row])

    def pose_of_log(self, row: int) -> np.ndarray | None:
        """World pose of the frame in log row ``row`` (None when unregistered)."""
        placed = self._placed(row)
        if placed is None or not self._node_in_main(placed[0]):
            return None
        return placed[1]

    def current_pose(self) -> np.ndarray | None:
        """World pose of the last placed frame (None when lone or none)."""
        return self.pose_of_log(self._last_row) if self._last_row >= 0 else None

    def current_placement(self) -> tuple[int, np.ndarray] | None:
        """The last placed frame's component, named by its oldest keyframe (the same across
        merges into it), and the frame's pose in that component's frame, main or not (None
        before the first)."""
        placed = self._placed(self._last_row) if self._last_row >= 0 else None
        if placed is None:
            return None
        return self.graph.component_oldest(placed[0]), placed[1]

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

    def n_keyframes(self) -> int:
        return len(self.keyframes)

    def keyframe_graph(self) -> KeyframeGraph | None:
        """The global graph for keyframe_graph.json (None while it has no node)."""
        pg = self.graph
        if not pg.n_nodes:
            return None
        return KeyframeGraph.from_posegraph(
            pg, self.keyframes.frame_indices.tolist(), self.keyframes.timestamps.tolist(),
            lone={k for k in range(pg.n_nodes) if not self._node_in_main(k)}, fragments=self.node_fragment.tolist())

    def stats(self) -> dict:
        """The map's counters for summary.json."""
        c, opt = self.counts, self.schedule.counts
        kinds: dict[str, int] = defaultdict(int, self.graph.kind_counts())
        act = self.active if self.active is not None and self.active.rel_poses is None else None
        return {
            "fragments": c.fragments,
            "keyframes": len(self.keyframes),
            "attached_fragments": c.attached,
            "lone_fragments": c.fragments - len(self.main_fragments()),
            "global_edges": self.graph.n_edges,
            "odometry_edges": kinds["odometry"],
            "keyframe_edges": kinds["keyframe"],
            "loop_edges": kinds["loop"],
            "rejoin_edges": kinds["rejoin"],
            "fallback_edges": kinds["fallback"],
            "fallback_edges_pruned": self.graph.pruned_kind_counts().get("fallback", 0),
            "pruned_edges": self.graph.n_pruned(),
            "pruned_edges_intra": c.intra_pruned,
            "intra_edges": c.intra_edges + (act.n_edges if act is not None else 0),
            "global_optimizations": opt.optimizations,
            "windowed_optimizations": opt.windowed,
            "max_optimized_nodes": opt.max_nodes,
            "keyframe_memory_bytes": self.keyframe_memory_bytes(),
            "keyframe_disk_bytes": self.keyframes.disk_bytes,
        }


def blend_poses(A: np.ndarray, B: np.ndarray, w: float) -> np.ndarray:
    """The pose ``w`` of the way from ``A`` to ``B`` (4x4; 0: A, 1: B): A exp(w log(A^-1 B)),
    the rotation along the geodesic, the translation straight."""
    D = invert_pose(A) @ B
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(w * Rotation.from_matrix(D[:3, :3]).as_rotvec()).as_matrix()
    out[:3, 3] = w * D[:3, 3]
    return A @ out


def frame_groups(fragment: np.ndarray, frag_node: array, graph: PoseGraph) -> list[tuple[int, np.ndarray]]:
    """Per component of ``graph`` with a placed frame: (its oldest node, the log rows of its
    frames in stream order), by frames (most first; ties: the oldest node first).
    ``fragment``: fragment id per log row (-1: not placed); ``frag_node``: node per fragment."""
    rows = np.flatnonzero(fragment >= 0)
    if not len(rows):
        return []
    oldest = np.array([graph.component_oldest(k) for k in range(graph.n_nodes)], np.int64)
    row_comp = oldest[np.asarray(frag_node, np.int64)[fragment[rows]]]
    order = np.argsort(row_comp, kind="stable")  # by component, stream order within
    labels, starts = np.unique(row_comp[order], return_index=True)
    groups = [(int(c), rows[part]) for c, part in zip(labels.tolist(), np.split(order, starts[1:]))]
    return sorted(groups, key=lambda g: (-len(g[1]), g[0]))
