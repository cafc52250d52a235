"""The map a :class:`~c3f_slam.pipeline.slam.FragmentSlam` builds, and what can be read from it.

State: the frame log (per streamed frame its fragment, local index and, once the fragment is
closed, the node it hangs off and its node-from-frame pose), the global keyframe graph
(camera-to-world node poses, metres), the stored keyframes and their appearance index, which
node each fragment hangs off, and the active fragment. Queries: which fragments are registered
(their node in the main component), each frame's world pose, the trajectory, the keyframe
graph, the components (:meth:`FragmentMap.components`) and the counters for summary.json.
:class:`FragmentSlam` adds the per-frame tracking.

The main component is, while the stream runs, the one with the most keyframes (O(1) to keep,
:class:`~c3f_slam.posegraph.PoseGraph`); at the end (:meth:`FragmentMap.choose_main`) the one
with the most registered frames.
"""

from __future__ import annotations

from array import array
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from c3f_slam.config import SlamConfig
from c3f_slam.outputs import KeyframeGraph
from c3f_slam.pipeline.backend import FrameLog
from c3f_slam.pipeline.components import MapComponent
from c3f_slam.pipeline.fragments import Fragment
from c3f_slam.pipeline.keyframe_store import KeyframeStore
from c3f_slam.pipeline.retrieval import KeyframeRetrieval
from c3f_slam.pipeline.schedule import OptimizationSchedule
from c3f_slam.posegraph import PoseGraph


@dataclass
class FragmentCounts:
    """What the back-end did, for summary.json (see :meth:`FragmentMap.stats`)."""

    fragments: int = 0  #: fragments opened (also the next fragment id)
    attached: int = 0  #: fragments hung off an earlier keyframe (reuse)
    lone_created: int = 0  #: keyframes created without any edge
    relocalised: int = 0  #: keyframes / fragments placed without an odometry link
    intra_edges: int = 0  #: edges of closed fragments' graphs
    intra_pruned: int = 0  #: of them pruned
    candidates_matched: int = 0  #: keyframe pairs matched (sum over new keyframes)
    edges_capped: int = 0  #: accepted keyframe matches discarded by the loop-edge cap
    candidate_sources: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    reasons: dict[str, int] = field(default_factory=lambda: defaultdict(int))  #: new-fragment reasons


class FragmentMap:
    """Fragments, keyframes and the global graph, with the queries the run loop and the
    output writer use (the read side of :class:`~c3f_slam.pipeline.backend.SlamBackend`)."""

    def __init__(self, cfg: SlamConfig, keyframe_cache: str | Path | None = None) -> None:
        """``keyframe_cache``: folder for the stored keyframes' features (emptied now, removed
        by :meth:`close`); None keeps them in RAM. Same results."""
        self.log = FrameLog()
        self.counts = FragmentCounts()
        self.frag_node = array("q")  # fragment id -> the global node it hangs off
        self.node_fragment = array("q")  # global node (keyframe) id -> the fragment that made it
        self.keyframes = KeyframeStore(keyframe_cache)
        self.graph = PoseGraph()
        self.retrieval = KeyframeRetrieval(cfg.candidates)
        self.schedule = OptimizationSchedule(cfg.optimization, cfg.posegraph, self.graph)
        self.active: Fragment | None = None
        self._last_row = -1  # log row of the last placed frame
        self._main_node = -1  # once chosen (choose_main): a node of the main component

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
        """Per component of the graph with a placed frame: (its oldest node, the log rows of
        its frames in stream order), by frames (most first; ties: the oldest node first)."""
        fragment = self._log_fragments()
        rows = np.flatnonzero(fragment >= 0)
        if not len(rows):
            return []
        oldest = np.array([self.graph.component_oldest(k) for k in range(self.graph.n_nodes)], np.int64)
        row_comp = oldest[np.asarray(self.frag_node, np.int64)[fragment[rows]]]
        order = np.argsort(row_comp, kind="stable")  # by component, stream order within
        labels, starts = np.unique(row_comp[order], return_index=True)
        groups = [(int(c), rows[part]) for c, part in zip(labels.tolist(), np.split(order, starts[1:]))]
        return sorted(groups, key=lambda g: (-len(g[1]), g[0]))

    def _log_fragments(self) -> np.ndarray:
        """Fragment id per log row (-1: not placed), a copy (a view would pin the log's array)."""
        return np.frombuffer(self.log.fragment, dtype=np.int64).copy() if len(self.log) else np.zeros(0, np.int64)

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
        fragment = self._log_fragments()
        for node, rows in self._frame_groups():
            poses = np.stack([self.graph.pose(self.log.node[r]) @ self.log.node_pose(r) for r in rows.tolist()])
            members = self.graph.component_nodes(node)
            frags = frozenset(fragment[rows].tolist())
            out.append(MapComponent(rows, poses, frags, len(members)))
        return out

    def pose_of_log(self, row: int) -> np.ndarray | None:
        """World pose of the frame in log row ``row`` (None when unregistered)."""
        if self.log.fragment[row] < 0:
            return None
        node = self.log.node[row]
        if node >= 0:  # its fragment is closed
            return self.graph.pose(node) @ self.log.node_pose(row) if self._node_in_main(node) else None
        act = self.active  # a frame of the active fragment
        assert act is not None and act.id == self.log.fragment[row]
        if not self._node_in_main(act.node):
            return None
        return self.graph.pose(act.node) @ act.node_pose(self.log.local[row])

    def current_pose(self) -> np.ndarray | None:
        """World pose of the last placed frame (None when lone or none)."""
        return self.pose_of_log(self._last_row) if self._last_row >= 0 else None

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
        """Counters for summary.json."""
        c, opt = self.counts, self.schedule.counts
        kinds: dict[str, int] = defaultdict(int, self.graph.kind_counts())
        act = self.active if self.active is not None and self.active.rel_poses is None else None
        return {
            "fragments": c.fragments,
            "keyframes": len(self.keyframes),
            "attached_fragments": c.attached,
            "lone_fragments": c.fragments - len(self.main_fragments()),
            "lone_created": c.lone_created,
            "relocalised_keyframes": c.relocalised,
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
            "keyframe_candidates_per_fragment": c.candidates_matched / c.fragments if c.fragments else 0.0,
            "keyframe_matches_capped": c.edges_capped,
            "keyframe_matches_by_source": dict(c.candidate_sources),
            "new_fragment_reasons": dict(c.reasons),
            "keyframe_memory_bytes": self.keyframe_memory_bytes(),
            "keyframe_disk_bytes": self.keyframes.disk_bytes,
        }
