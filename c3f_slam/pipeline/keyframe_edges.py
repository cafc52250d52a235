"""Edges of a new keyframe into the global graph: how many are kept and where the keyframe
goes (docs/design.md, Fragments and keyframes).

A new keyframe has at most one odometry edge (to the previous fragment's node, certain), or
in its place a ``fallback`` edge (dense alignment, uncertain: :mod:`.fallback`), and
keyframe matches to earlier keyframes (kinds ``keyframe`` and ``loop``, uncertain). An edge
(k, T_k,new) maps points of the new frame into keyframe k (p_k = T_k,new p_new, metres).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from c3f_slam.geometry import invert_pose, transform_points
from c3f_slam.pipeline.frontend import PairMatch
from c3f_slam.posegraph import EdgeKind, PoseGraph
from c3f_slam.posegraph.components import Components


class KeyframeEdge(NamedTuple):
    """An edge from earlier keyframe ``k`` to a new frame: ``match.T_ij`` = T_k,new."""

    k: int
    match: PairMatch
    kind: EdgeKind


def cap_keyframe_edges(
    edges: list[KeyframeEdge], cap: int | None, component: Callable[[int], int] | None = None
) -> tuple[list[KeyframeEdge], int]:
    """Bound the keyframe-match edges of a new keyframe (``KeyframeConfig.max_loop_edges``);
    returns (kept edges in their input order, number discarded).

    ``odometry`` and ``fallback`` edges are always kept and not counted. Of the others, at most ``cap`` are
    kept (None or 0: all), chosen in this order: the match to the most recent keyframe
    (highest id); then, for each component (``component(k)``, e.g. the pose graph's
    union-find root) that no kept edge reaches yet, its strongest match, so that no merge of
    components is lost; then the strongest of the rest. Strength = inlier correspondences
    (``PairMatch.n``), ties to the more recent keyframe.
    """
    always = (EdgeKind.ODOMETRY, EdgeKind.FALLBACK)
    matches = [n for n, e in enumerate(edges) if e[2] not in always]
    if not cap or len(matches) <= cap:
        return list(edges), 0
    comp = component or (lambda k: k)
    covered = {comp(k) for k, _, kind in edges if kind in always}
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
    keep = set(chosen) | {n for n, e in enumerate(edges) if e[2] in always}
    return [e for n, e in enumerate(edges) if n in keep], len(matches) - len(chosen)


class ComponentView(Protocol):
    """Connected components of the keyframes, as :func:`place_new_frame` reads them: a root per
    node, the oldest node and the nodes of a node's component (e.g.
    :class:`c3f_slam.posegraph.components.Components`)."""

    def find(self, node: int) -> int: ...

    def oldest(self, node: int) -> int: ...

    def nodes(self, node: int) -> list[int]: ...


class _GraphComponents:
    """The pose graph's own components (over its non-pruned edges) as a :class:`ComponentView`."""

    def __init__(self, graph: PoseGraph) -> None:
        self.find, self.oldest, self.nodes = graph.find, graph.component_oldest, graph.component_nodes


def place_new_frame(graph: PoseGraph, edges: list[KeyframeEdge],
                    components: ComponentView | None = None) -> tuple[np.ndarray | None, int]:
    """World pose (camera-to-world) of a new frame linked by ``edges`` to earlier keyframes
    (None without edges), after moving the other components it connects rigidly into the
    frame of the oldest one (so that optimisation starts consistent). Touches only the nodes
    of the components it merges. Returns (T_w,new, number of components merged into the
    anchor). Per component the edge used is the odometry one, else the strongest.

    ``components``: which components (default the graph's). The back-end passes its
    components over sparse-match edges only when the dense fallback is on: keyframe matches
    that reach across a fallback edge then re-place the side after it as they say, so that a
    wrong fallback edge, not the matches, is what the optimisation finds misaligned."""
    if not edges:
        return None, 0
    comps = components or _GraphComponents(graph)
    by_comp: dict[int, KeyframeEdge] = {}  # component root -> best edge
    for e in edges:
        c = comps.find(e.k)
        best = by_comp.get(c)
        if best is None or (e.kind == EdgeKind.ODOMETRY) > (best.kind == EdgeKind.ODOMETRY) or e.match.n > best.match.n:
            by_comp[c] = e
    anchor = min(by_comp, key=comps.oldest)
    k, m, _ = by_comp[anchor]
    T_wn = graph.pose(k) @ m.T_ij
    for c, (k, m, _) in by_comp.items():
        if c != anchor:
            _move_component(graph, k, T_wn @ invert_pose(m.T_ij), comps)
    return T_wn, len(by_comp) - 1


def _move_component(graph: PoseGraph, node: int, T_w_node: np.ndarray, components: ComponentView | None = None) -> None:
    """Move the component of ``node`` rigidly so that ``node``'s pose becomes ``T_w_node``."""
    nodes = (components or _GraphComponents(graph)).nodes(node)
    graph.transform_nodes(nodes, T_w_node @ invert_pose(graph.pose(node)))


def join_components(graph: PoseGraph, i: int, j: int, T_ij: np.ndarray) -> bool:
    """Before adding the edge (i, j, T_ij) between two components: move the newer component
    (its oldest node is younger) rigidly so that pose(i) @ T_ij = pose(j). Returns whether the
    two were different components."""
    if graph.find(i) == graph.find(j):
        return False
    if graph.component_oldest(i) <= graph.component_oldest(j):
        _move_component(graph, j, graph.pose(i) @ T_ij)
    else:
        _move_component(graph, i, graph.pose(j) @ invert_pose(T_ij))
    return True


def link_new_keyframe(graph: PoseGraph, node: int, edges: list[KeyframeEdge],
                      dense_information: Callable[[PairMatch], np.ndarray],
                      *,
                      sparse: Components | None = None, information: dict[int, np.ndarray] | None = None) -> int:
    """Place the new keyframe ``node`` (:func:`place_new_frame`) and add its ``edges``: odometry
    certain, the others uncertain; a ``fallback`` edge with ``dense_information(match)`` (its
    trust-weighted information) instead of its points'; edge number n with ``information[n]``
    where given (a dense refinement: :mod:`.refine`). ``sparse``: the components over
    sparse-match edges (the node already added), kept up to date. Returns the number of
    components merged."""
    T_wn, merged = place_new_frame(graph, edges, sparse)
    if T_wn is not None:
        graph.set_pose(node, T_wn)
    for n, (k, m, kind) in enumerate(edges):
        if kind == EdgeKind.FALLBACK:  # prunable where keyframe matches disagree
            graph.add_edge(k, node, m.T_ij, information=dense_information(m), uncertain=True, kind=kind)
            continue
        weight = {"information": information[n]} if information and n in information else {"points_j": m.points_j}
        graph.add_edge(k, node, m.T_ij, **weight, uncertain=kind != EdgeKind.ODOMETRY, kind=kind)
        if sparse is not None:
            sparse.union(k, node)
    return merged


def link_revisit(graph: PoseGraph, keep: list[KeyframeEdge], sparse: Components | None = None) -> int:
    """Place a frame that hangs off host keyframe ``keep[0].k`` (a revisit: no node of its own,
    :mod:`.reuse`) and add the other edges of ``keep`` as uncertain host-k ``loop`` edges:
    T_host,k = T_host,new T_k,new^-1, with the match's points moved into frame k. ``sparse``:
    the components over sparse-match edges, kept up to date. Returns the number of components
    merged."""
    host, m_host = keep[0].k, keep[0].match
    _, merged = place_new_frame(graph, keep, sparse)
    for k, m, _ in keep[1:]:
        if sparse is not None:
            sparse.union(host, k)
        T_hk = m_host.T_ij @ invert_pose(m.T_ij)
        pts_k = transform_points(m.T_ij, m.points_j)  # the match's points in frame k
        graph.add_edge(host, k, T_hk, points_j=pts_k, uncertain=True, kind=EdgeKind.LOOP)
    return merged


def link_across_break(graph: PoseGraph, i: int, j: int, T_ij: np.ndarray, points_j: np.ndarray,
                      *,
                      sparse: Components | None = None) -> None:
    """Merge the components of ``i`` and ``j`` (:func:`join_components`) and add the uncertain
    ``rejoin`` edge p_i = T_ij p_j with the matched points of frame j."""
    join_components(graph, i, j, T_ij)
    if sparse is not None:
        sparse.union(i, j)
    graph.add_edge(i, j, T_ij, points_j=points_j, uncertain=True, kind=EdgeKind.REJOIN)
