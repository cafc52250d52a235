"""Pose-graph optimisation in named steps: the window (free nodes and their edges), the problem
in Open3D's terms, the solve, and the write-back (poses, pruned flags, confidences).

``global_optimization`` silently does nothing on a disconnected graph, so only the connected
component of the reference node is optimised and other nodes are left as given. Open3D's
convergence thresholds are absolute (e.g. residual < 1e-6), so the graph is optimised in units
of ``max_correspondence_distance`` (all lengths divided by it), which makes the result
independent of the scene scale (colon millimetres or room metres).

Scale (a global graph of thousands of keyframes): Open3D's Levenberg-Marquardt builds a *dense*
6N x 6N system (measured on 2 cores: 100 nodes 0.03 s, 200 nodes 0.15 s, 400 nodes 1.5 s, 800
nodes 7.8 s), so a bounded set of *free* nodes can be optimised with every other node fixed: the
fixed neighbours are folded into one anchor node (the world, identity) and each edge between a
free and a fixed node becomes an edge between the free node and the anchor, with the same
residual (:func:`~c3f_slam.posegraph.information.transform_information` re-expresses its
information matrix when the free node was the edge's target).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np

from c3f_slam.geometry import invert_pose
from c3f_slam.posegraph.adjacency import Adjacency
from c3f_slam.posegraph.components import Components, component_labels, reachable
from c3f_slam.posegraph.config import PoseGraphConfig
from c3f_slam.posegraph.edges import EdgeStore
from c3f_slam.posegraph.information import transform_information
from c3f_slam.posegraph.nodes import NodePoses
from c3f_slam.posegraph.open3d_adapter import Open3DProblem, Open3DSolution, solve


class OptimizedGraph(Protocol):
    """What an :class:`OptimizationResult` reads from its graph (a ``PoseGraph``) on demand."""

    @property
    def poses(self) -> np.ndarray: ...

    def confidences(self) -> np.ndarray: ...

    def edge_rms(self) -> np.ndarray: ...

    def component_of(self, node: int) -> list[int]: ...


@dataclass
class GraphParts:
    """The parts of a pose graph that an optimisation reads and updates."""

    poses: NodePoses
    edges: EdgeStore
    adjacency: Adjacency
    components: Components


@dataclass
class Window:
    """What one optimisation works on: ``free`` (sorted nodes that move), ``edge_ids`` (sorted
    edges with an end among them) and ``outside`` (some edge's other end is fixed, so the
    problem gets an anchor node)."""

    free: list[int]
    edge_ids: list[int]
    outside: bool


@dataclass(kw_only=True)
class WindowEdges:
    """The window's edges: graph ends ``ei`` / ``ej``, ``uncertain`` flags, the Open3D edges
    (``source`` / ``target`` local node ids, ``X`` / ``L`` in internal units, fixed ends folded
    into the anchor 0) and the sorted ``fixed_nodes`` folded."""

    ei: np.ndarray
    ej: np.ndarray
    uncertain: list[bool]
    source: np.ndarray
    target: np.ndarray
    X: np.ndarray
    L: np.ndarray
    fixed_nodes: list[int]


class OptimizationResult:
    """Outcome of :meth:`PoseGraph.optimize`.

    ``pruned``: indices of edges removed by the line process (among the optimised ones).
    ``optimized_nodes``: sorted nodes whose poses were optimised; ``fixed_nodes``: sorted
    nodes held fixed through the anchor (empty unless a bounded set was optimised).
    Computed on first access from the graph (O(graph); read them before changing the graph):
    ``poses`` (N, 4, 4) camera-to-world after optimisation (untouched for nodes that were not
    optimised); ``confidence``: per-edge line-process value (1 for certain edges, 0 for
    pruned ones); ``edge_rms``: per-edge RMS point misalignment in metres under the optimised
    poses; ``component``: sorted nodes connected to the reference node by the edges kept.
    """

    def __init__(self, graph: OptimizedGraph, pruned: list[int], optimized_nodes: list[int],
                 fixed_nodes: list[int], reference_node: int) -> None:
        self._graph = graph
        self.pruned = pruned
        self.optimized_nodes = optimized_nodes
        self.fixed_nodes = fixed_nodes
        self.reference_node = reference_node

    @cached_property
    def poses(self) -> np.ndarray:
        return self._graph.poses

    @cached_property
    def confidence(self) -> np.ndarray:
        return self._graph.confidences()

    @cached_property
    def edge_rms(self) -> np.ndarray:
        return self._graph.edge_rms()

    @cached_property
    def component(self) -> list[int]:
        return self._graph.component_of(self.reference_node)


def optimize_window(parts: GraphParts, cfg: PoseGraphConfig, reference_node: int, nodes: Iterable[int] | None,
                    max_boundary_edges: int | None) -> tuple[Window, list[int]]:
    """Optimise the window of ``nodes`` (see :meth:`PoseGraph.optimize`) in place; returns the
    window and the sorted fixed nodes."""
    window = select_window(parts, reference_node, nodes, max_boundary_edges)
    k_scale = 1.0 / cfg.max_correspondence_distance
    local = np.full(parts.poses.n, -1, np.int64)  # the anchor (world, identity) first when some neighbour is fixed
    local[window.free] = np.arange(len(window.free)) + int(window.outside)
    edges = window_edges(parts, window, local, k_scale)
    initial = [np.eye(4)] if window.outside else []
    initial += [_scale_pose(parts.poses.buffer[v], k_scale) for v in window.free]
    reference = 0 if window.outside else int(local[reference_node])
    problem = Open3DProblem(node_poses=initial, source=edges.source, target=edges.target, transformation=edges.X,
                            information=edges.L, uncertain=edges.uncertain, reference_node=reference)
    solution = solve(problem, cfg)
    write_back(parts, window, edges, solution, local, k_scale)
    return window, edges.fixed_nodes


def select_window(parts: GraphParts, reference_node: int, nodes: Iterable[int] | None,
                  max_boundary_edges: int | None) -> Window:
    """The free nodes: ``nodes`` (None: the reference node's whole component over all edges),
    less the reference node when some neighbour lies outside (so the world frame does not
    drift); their edges (:func:`edges_at`). Raises ValueError for missing nodes and when the
    reference node is neither free nor a fixed neighbour."""
    n = parts.poses.n
    if not 0 <= reference_node < n:
        raise ValueError(f"reference node {reference_node} not in graph of {n} nodes")
    if nodes is None:
        free = sorted(reachable(parts.adjacency, parts.edges, [reference_node]))
    else:
        free = sorted({int(v) for v in nodes})
        if any(not 0 <= v < n for v in free):
            raise ValueError("optimised nodes must exist")
    free_set = set(free)
    edge_ids, outside = edges_at(parts, free, free_set, max_boundary_edges)
    if outside and reference_node in free_set:
        free_set.discard(reference_node)
        free = [v for v in free if v != reference_node]
        edge_ids, outside = edges_at(parts, free, free_set, max_boundary_edges)
    if not outside and reference_node not in free_set:
        raise ValueError(f"reference node {reference_node} is not connected to the optimised nodes")
    return Window(free, edge_ids, outside)


def edges_at(parts: GraphParts, free: list[int], free_set: set[int],
             max_boundary: int | None) -> tuple[list[int], bool]:
    """Sorted ids of the edges with an end in ``free_set`` (at most ``max_boundary`` per
    node to newer nodes outside it, the most recent first), and whether any has its other end
    outside."""
    ids: set[int] = set()
    outside = False
    ei, ej = parts.edges.ei, parts.edges.ej
    for v in free:
        for k in parts.adjacency.older_ids(v):
            ids.add(k)
            outside |= min(ei[k], ej[k]) not in free_set
        taken = 0
        for k in parts.adjacency.iter_newer(v):
            if max(ei[k], ej[k]) in free_set:  # listed with the newer node
                continue
            if max_boundary is not None and taken >= max_boundary:
                break
            ids.add(k)
            taken += 1
            outside = True
    return sorted(ids), outside


def window_edges(parts: GraphParts, window: Window, local: np.ndarray, k_scale: float) -> WindowEdges:
    """The window's edges as Open3D sees them, vectorised: source = the frame T_ij maps from
    (j), target = i; a fixed target becomes the anchor (map frame-j points into the world);
    with a fixed source j the edge is reversed (frame-i points into the world). Lengths are
    multiplied by ``k_scale`` (internal units)."""
    store, P, edge_ids = parts.edges, parts.poses.buffer, window.edge_ids
    E = len(edge_ids)
    ids = np.asarray(edge_ids, np.int64)
    ei = np.fromiter((store.ei[k] for k in edge_ids), np.int64, E)
    ej = np.fromiter((store.ej[k] for k in edge_ids), np.int64, E)
    unc = store.uncertain[ids].tolist()
    X = store.transforms(ids)
    L = store.informations(ids)
    src, tgt = local[ej], local[ei]
    fixed_i, fixed_j = tgt < 0, src < 0
    if fixed_i.any():
        X[fixed_i] = P[ei[fixed_i]] @ X[fixed_i]
        tgt[fixed_i] = 0
    if fixed_j.any():
        T = X[fixed_j]
        L[fixed_j] = transform_information(L[fixed_j], T)
        X[fixed_j] = P[ej[fixed_j]] @ invert_pose(T)
        src[fixed_j], tgt[fixed_j] = local[ei[fixed_j]], 0
    fixed = sorted(set(ei[fixed_i].tolist()) | set(ej[fixed_j].tolist()))
    X[:, :3, 3] *= k_scale
    sc = np.array([k_scale] * 3 + [1.0] * 3)
    L *= np.outer(sc, sc)
    return WindowEdges(ei=ei, ej=ej, uncertain=unc, source=src, target=tgt, X=X, L=L, fixed_nodes=fixed)


def write_back(parts: GraphParts, window: Window, edges: WindowEdges, solution: Open3DSolution, local: np.ndarray,
               k_scale: float) -> None:
    """Store the solution: per window edge its confidence (1 for certain edges) or pruned with
    confidence 0, components joined for edges that came back, the free nodes' poses in metres;
    the components are rebuilt when an edge was newly pruned."""
    store = parts.edges
    newly_pruned = False
    was_pruned = store.pruned[np.asarray(window.edge_ids, np.int64)].tolist()
    for n, k in enumerate(window.edge_ids):
        confidence = solution.edge_confidence[n]
        if confidence is not None:
            store.confidence[k] = confidence if edges.uncertain[n] else 1.0
            if was_pruned[n]:
                store.pruned[k] = False
                parts.components.union(int(edges.ei[n]), int(edges.ej[n]))
        else:
            store.pruned[k], store.confidence[k] = True, 0.0
            newly_pruned |= not was_pruned[n]
    for v in window.free:
        parts.poses.buffer[v] = _scale_pose(solution.node_poses[int(local[v])], 1.0 / k_scale)
    if newly_pruned:
        rebuild_components(parts)


def rebuild_components(parts: GraphParts) -> None:
    """Union-find from scratch over the non-pruned edges (scipy, O(N + E) in C)."""
    parts.components.rebuild(component_labels(parts.poses.n, *parts.edges.ends(include_pruned=False)))


def _scale_pose(T: np.ndarray, k: float) -> np.ndarray:
    """A copy of pose ``T`` with its translation multiplied by ``k``."""
    T = np.array(T, dtype=np.float64)
    T[:3, 3] *= k
    return T
