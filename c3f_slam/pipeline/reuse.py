"""Keyframe reuse on revisits (``KeyframeConfig.reuse``; a deviation from the paper, which
makes every fragment's first frame a keyframe).

A new fragment whose first frame could continue the fragment of an earlier keyframe by the
fragment rules hangs off that keyframe (the *host*) instead of adding one: no new node, no
stored features, and only the edges that add information (a merge of components, the loop
closure of a fragment that made a new keyframe). When the frame also has an odometry link
into the host's component, the two must agree on its pose; otherwise it becomes a keyframe
with uncertain edges as in the paper, so that the pose-graph optimisation can still weigh and
prune a wrong keyframe match. A stream that keeps revisiting mapped places then stops adding
keyframes and edges, so memory stays flat; new places still add them.
"""

from __future__ import annotations

import numpy as np

from c3f_slam.camera.frustum import frustum_overlap
from c3f_slam.config import FragmentConfig, KeyframeConfig
from c3f_slam.geometry import invert_pose, motion_magnitudes
from c3f_slam.pipeline.keyframe_edges import KeyframeEdge
from c3f_slam.posegraph import EdgeKind, PoseGraph


def find_host(graph: PoseGraph, edges: list[KeyframeEdge], depth: np.ndarray, K: np.ndarray,
              rules: tuple[FragmentConfig, KeyframeConfig], odometry: KeyframeEdge | None) -> int | None:
    """The earlier keyframe a new fragment should hang off, or None.

    Of the matched keyframes in ``edges`` (not the odometry link), those the frame could
    continue a fragment of by the fragment rules (at least ``min_correspondences``
    correspondences, frustum overlap of the frame (``depth``, intrinsics ``K``) with the
    keyframe >= ``min_overlap``; no occlusion test, the keyframe's depth is not kept) and
    whose match agrees with the ``odometry`` edge when that reaches the same component
    (camera centres within ``reuse_max_offset`` metres, orientations within
    ``reuse_max_angle_deg``); the one with the largest overlap (ties: more correspondences).
    """
    fragments, keyframes = rules
    T_odo = root_odo = None
    if odometry is not None:
        T_odo, root_odo = graph.pose(odometry.k) @ odometry.match.T_ij, graph.find(odometry.k)
    best, best_key = None, None
    for k, m, kind in edges:
        if kind == EdgeKind.ODOMETRY or m.n < fragments.min_correspondences:
            continue
        if T_odo is not None and graph.find(k) == root_odo:
            offset, angle = motion_magnitudes(invert_pose(T_odo) @ graph.pose(k) @ m.T_ij)
            if offset[0] > keyframes.reuse_max_offset or angle[0] > keyframes.reuse_max_angle_deg:
                continue
        ov = frustum_overlap(depth, K, m.T_ij, np.eye(4), stride=fragments.overlap_stride)
        if ov >= fragments.min_overlap and (best_key is None or (ov, m.n) > best_key):
            best, best_key = k, (ov, m.n)
    return best


def revisit_edges(graph: PoseGraph, edges: list[KeyframeEdge], host: int,
                  previous_made_keyframe: bool) -> list[KeyframeEdge]:
    """The edges a fragment attached to ``host`` keeps, as (k, T_k,new, loop): first the host's
    own match, then only those that add information the graph cannot have yet: the
    strongest match into each other component (merges; the odometry link counts as a
    match), and the odometry link into the host's component when the previous fragment
    made a new keyframe (``previous_made_keyframe``: its loop closure)."""
    m_host = next(e.match for e in edges if e.k == host and e.kind != EdgeKind.ODOMETRY)
    root = graph.find(host)
    best: dict[int, KeyframeEdge] = {}  # other component -> its strongest edge
    keep = [KeyframeEdge(host, m_host, EdgeKind.LOOP)]
    for e in edges:
        c = graph.find(e.k)
        if c == root:
            if e.kind == EdgeKind.ODOMETRY and e.k != host and previous_made_keyframe:
                keep.append(KeyframeEdge(e.k, e.match, EdgeKind.LOOP))
            continue
        b = best.get(c)
        if b is None or e.match.n > b.match.n:
            best[c] = e
    return keep + [KeyframeEdge(k, m, EdgeKind.LOOP) for k, m, _ in best.values()]
