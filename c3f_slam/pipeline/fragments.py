"""Fragments (docs/design.md, Fragments and keyframes): the new-fragment rule and the intra-fragment pose graph.

A fragment is a run of consecutive frames registered relative to its first frame, the
keyframe (node 0, identity). Poses here are keyframe-from-frame (camera-to-keyframe)
4x4 matrices in metres; edges follow :mod:`c3f_slam.posegraph` (p_i = T_ij p_j).

In the global graph a fragment hangs off one node: normally its own keyframe (``node`` = a
new global node, ``base`` None); a fragment *attached* to an earlier keyframe (a revisit,
``SlamConfig.reuse_keyframes``) hangs off that keyframe's node, ``base`` = T_node,first
(node-from-first-frame), and adds no node.
"""

from __future__ import annotations

import numpy as np

from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch
from c3f_slam.posegraph import EdgeKind, PoseGraph, PoseGraphConfig

#: reasons a frame opens a new fragment
CORRESPONDENCES, OVERLAP, SIZE, FIRST = "correspondences", "overlap", "size", "first"


def new_fragment_reason(
    n_consecutive: int,
    overlap: float | None,
    n_fragment_frames: int,
    min_correspondences: int = 100,
    min_overlap: float = 0.85,
    max_fragment_frames: int = 60,
) -> str | None:
    """Why the current frame must open a new fragment, or None to append it.

    (1) fewer than ``min_correspondences`` filtered correspondences with the previous frame;
    (2) frustum overlap with the active keyframe below ``min_overlap`` (None = not computed);
    plus a size cap (``max_fragment_frames``) that bounds the memory of the active fragment.
    """
    if n_consecutive < min_correspondences:
        return CORRESPONDENCES
    if overlap is not None and overlap < min_overlap:
        return OVERLAP
    if n_fragment_frames >= max_fragment_frames:
        return SIZE
    return None


def intra_fragment_targets(n_frames: int, all_pairs: bool = False, recent: int = 2, spaced: int = 8) -> list[int]:
    """Local indices (ascending) of the active fragment's frames that a new frame is matched
    against besides the previous one (local ``n_frames - 1``, its odometry link), for a fragment
    of ``n_frames`` frames. ``all_pairs``: every earlier frame (the cost grows with the length);
    else a bounded set of at most ``1 + recent + spaced``: the keyframe (0), the ``recent``
    frames before the previous one, and every k-th of the frames between the two (at most
    ``spaced``; k = their number / ``spaced``), from an offset that moves on with each new frame
    (``prev mod k``), so that the older frames take turns instead of the same few getting every
    edge."""
    prev = n_frames - 1
    if prev <= 0:
        return []
    if all_pairs:
        return list(range(prev))
    chosen = {0, *range(max(1, prev - recent), prev)}
    hi = prev - recent - 1  # the older frames: 1 .. hi
    if spaced > 0 and hi >= 1:
        step = -(-hi // spaced)  # ceil: at most `spaced` of them
        chosen.update(range(1 + prev % step, hi + 1, step))
    return sorted(chosen)


class Fragment:
    """The active fragment: its frames' features (dropped when closed) and local pose graph."""

    def __init__(self, fid: int, keyframe: FrameFeatures, keyframe_depth: np.ndarray, reason: str,
                 node: int | None = None, base: np.ndarray | None = None) -> None:
        """``node``: the global node it hangs off (default ``fid``); ``base``: T_node,first
        (None = identity: the fragment's first frame is that node's keyframe)."""
        self.id = fid
        self.node = fid if node is None else int(node)
        self.base = None if base is None else np.asarray(base, dtype=np.float64)
        self.keyframe = keyframe.index
        self.reason = reason
        self.frames: list[int] = [keyframe.index]
        self.features: list[FrameFeatures] | None = [keyframe]
        self.keyframe_depth: np.ndarray | None = keyframe_depth
        self.graph: PoseGraph | None = PoseGraph()  # None once closed
        self.graph.add_node(np.eye(4))
        self.rel_poses: np.ndarray | None = None  # (n, 4, 4) after close()
        self.n_edges = 0
        self.pruned = 0

    def __len__(self) -> int:
        return len(self.frames)

    def pose(self, local: int) -> np.ndarray:
        """Keyframe-from-frame pose of the fragment's ``local``-th frame."""
        if self.rel_poses is not None:
            return self.rel_poses[local]
        assert self.graph is not None
        return self.graph.pose(local)

    @property
    def last_pose(self) -> np.ndarray:
        return self.pose(len(self.frames) - 1)

    def node_pose(self, local: int) -> np.ndarray:
        """Node-from-frame pose of the ``local``-th frame (``base`` @ :meth:`pose`)."""
        P = self.pose(local)
        return P if self.base is None else self.base @ P

    def add_frame(
        self, feat: FrameFeatures, link: PairMatch, extra: list[tuple[int, PairMatch]] | None = None
    ) -> int:
        """Append ``feat`` linked to the previous frame by ``link`` (T_prev,cur); ``extra``:
        (local index, match T_local,cur) to other frames of the fragment. Returns its local index."""
        prev = len(self.frames) - 1
        assert self.graph is not None, "the fragment is closed"
        node = self.graph.add_node(self.graph.pose(prev) @ link.T_ij)
        self.graph.add_edge(prev, node, link.T_ij, points_j=link.points_j, kind=EdgeKind.ODOMETRY)
        for local, m in extra or []:
            self.graph.add_edge(local, node, m.T_ij, points_j=m.points_j, uncertain=True, kind=EdgeKind.LOOP)
        self.n_edges += 1 + len(extra or [])
        self.frames.append(feat.index)
        assert self.features is not None
        self.features.append(feat)
        return node

    def close(self, config: PoseGraphConfig) -> None:
        """Optimise the local graph (when it has more than a chain), freeze the relative poses,
        drop the per-frame features."""
        assert self.graph is not None, "the fragment is closed"
        if self.graph.has_uncertain():
            res = self.graph.optimize(config, reference_node=0)
            self.pruned = len(res.pruned)
        self.rel_poses = self.graph.poses.astype(np.float64)
        self.graph = None  # free the nodes and edges
        self.features = None
        self.keyframe_depth = None
