"""The pose graph: nodes with camera-to-world poses and relative-pose edges (a facade over the
parts of :mod:`c3f_slam.posegraph`)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from c3f_slam.posegraph.adjacency import Adjacency
from c3f_slam.posegraph.components import Components, component_labels, components_from_labels, reachable
from c3f_slam.posegraph.config import PoseGraphConfig, resolve_config
from c3f_slam.posegraph.edges import EdgeKind, EdgeList, EdgeStore, kind_code
from c3f_slam.posegraph.information import information_from_points
from c3f_slam.posegraph.nodes import NodePoses
from c3f_slam.posegraph.optimize import GraphParts, OptimizationResult, optimize_window, rebuild_components


class PoseGraph:
    """Nodes with camera-to-world poses and relative-pose edges, optimised with Open3D.

    An edge ``(i, j, T_ij)`` says p_i = T_ij @ p_j, i.e. T_ij = inv(T_wi) @ T_wj (metres,
    radians). Components are over the non-pruned edges unless said otherwise.
    """

    def __init__(self) -> None:
        self._poses = NodePoses()
        self._edges = EdgeStore()
        self._adjacency = Adjacency()
        self._components = Components()
        self._parts = GraphParts(self._poses, self._edges, self._adjacency, self._components)

    # ------------------------------------------------------------------ building
    def add_node(self, T_wc: np.ndarray) -> int:
        """Add a node with initial camera-to-world pose ``T_wc``; returns its index."""
        n = self._poses.add(T_wc)
        self._adjacency.add_node()
        self._components.add_node()
        return n

    def add_edge(
        self,
        i: int,
        j: int,
        T_ij: np.ndarray,
        points_j: np.ndarray | None = None,
        information: np.ndarray | None = None,
        uncertain: bool = False,
        kind: EdgeKind | str | None = None,
    ) -> int:
        """Add the constraint p_i = T_ij @ p_j; returns the edge index.

        Give either the matched 3D points of frame j (``points_j``, metres, frame-j
        coordinates) or a 6x6 ``information`` matrix in Open3D's (rotation, translation)
        order. Odometry edges are ``uncertain=False`` (never pruned); loop closures are
        ``uncertain=True``. ``kind``: an :class:`EdgeKind` or its string (default loop when
        uncertain, else odometry).
        """
        n = self._poses.n
        if not (0 <= i < n and 0 <= j < n) or i == j:
            raise ValueError(f"edge ({i}, {j}) needs two different existing nodes (have {n})")
        if (points_j is None) == (information is None):
            raise ValueError("give exactly one of points_j and information")
        info = information_from_points(points_j) if points_j is not None else np.asarray(information, float)
        if info.shape != (6, 6) or not np.all(np.isfinite(info)):
            raise ValueError("information must be a finite 6x6 matrix")
        T = np.asarray(T_ij, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError("T_ij must be a finite 4x4 matrix")
        code = kind_code(kind or (EdgeKind.LOOP if uncertain else EdgeKind.ODOMETRY))
        k = self._edges.add(i, j, T, info, uncertain, code)
        self._adjacency.add_edge(k, i, j)
        self._components.union(i, j)
        return k

    # ------------------------------------------------------------------ nodes
    @property
    def n_nodes(self) -> int:
        return self._poses.n

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) copy of the current camera-to-world poses (initial or last optimised)."""
        return self._poses.copy()

    def pose(self, node: int) -> np.ndarray:
        """Camera-to-world pose of one node (a copy)."""
        return self._poses.get(node)

    def pose_array(self) -> np.ndarray:
        """Read-only (N, 4, 4) view of the poses (no copy; invalid after the next change)."""
        return self._poses.view()

    def set_pose(self, node: int, T_wc: np.ndarray) -> None:
        self._poses.set(node, T_wc)

    def transform_nodes(self, nodes: Iterable[int], G: np.ndarray) -> None:
        """Left-multiply the poses of ``nodes`` by G (move them rigidly in the world)."""
        self._poses.transform(nodes, G)

    # ------------------------------------------------------------------ edges
    @property
    def edges(self) -> EdgeList:
        """The edges as a sequence of :class:`~c3f_slam.posegraph.edges.Edge` views (see
        :class:`~c3f_slam.posegraph.edges.EdgeList`)."""
        return EdgeList(self._edges)

    @property
    def n_edges(self) -> int:
        return self._edges.m

    def edges_of(self, node: int) -> list[int]:
        """Ids of the edges at ``node`` (pruned ones too)."""
        return self._adjacency.edges_of(node)

    def n_pruned(self) -> int:
        """Number of pruned edges."""
        return self._edges.n_pruned()

    def kind_counts(self) -> dict[str, int]:
        """Edges per kind (``odometry``, ``loop``, ``keyframe``, ...), kinds present only."""
        return self._edges.kind_counts()

    def pruned_kind_counts(self) -> dict[str, int]:
        """Pruned edges per kind, kinds present only."""
        return self._edges.pruned_kind_counts()

    def has_uncertain(self) -> bool:
        return self._edges.has_uncertain()

    def confidences(self) -> np.ndarray:
        """(E,) line-process confidence per edge (a copy; 1 until an optimisation sets it)."""
        return self._edges.confidences()

    def edge_nbytes(self) -> int:
        """Bytes held by the edge storage (arrays at capacity, side dicts' matrices, adjacency links)."""
        return self._edges.nbytes + self._adjacency.nbytes

    def edge_rms(self, poses: np.ndarray | None = None, edges: Iterable[int] | None = None) -> np.ndarray:
        """Per-edge RMS point misalignment (metres): sqrt(e^T Lambda e / N) (of ``edges``,
        default all) under ``poses`` (default the current ones)."""
        P = self._poses.buffer if poses is None else poses
        return self._edges.rms(P, range(self._edges.m) if edges is None else list(edges))

    # ------------------------------------------------------------------ components
    def find(self, node: int) -> int:
        """Root of ``node``'s component over the non-pruned edges (amortised O(1))."""
        return self._components.find(node)

    def refresh_components(self) -> None:
        """Rebuild the union-find from the edges' ``pruned`` flags (call it after changing
        them by hand; :meth:`optimize` keeps the components up to date itself)."""
        rebuild_components(self._parts)

    def component_size(self, node: int) -> int:
        return self._components.size(node)

    def component_oldest(self, node: int) -> int:
        """Smallest node of ``node``'s component (non-pruned edges)."""
        return self._components.oldest(node)

    def component_nodes(self, node: int) -> list[int]:
        """Sorted nodes of ``node``'s component over the non-pruned edges (O(its size))."""
        return self._components.nodes(node)

    def connected(self, a: int, b: int) -> bool:
        return self._components.find(a) == self._components.find(b)

    @property
    def main_root(self) -> int:
        """Root of the main component (largest, ties to the oldest); -1 when empty."""
        return self._components.main_root

    def in_main(self, node: int) -> bool:
        """``node`` lies in the main component (non-pruned edges)."""
        return self._components.in_main(node)

    def main_component(self) -> list[int]:
        return self._components.main_nodes()

    def reachable(self, seeds: Iterable[int], limit: int | None = None) -> list[int]:
        """Nodes reached from ``seeds`` over all edges (pruned ones too), breadth first, at
        most ``limit`` of them (None: the whole component); the seeds come first."""
        return reachable(self._adjacency, self._edges, seeds, limit)

    def components(self, include_pruned: bool = False) -> list[list[int]]:
        """Connected components (sorted node lists, largest first) over the edges, computed
        from scratch (O(graph); see :meth:`component_nodes` / :meth:`in_main` for the
        incremental queries). Pruned edges are ignored unless ``include_pruned``.
        """
        return components_from_labels(component_labels(self._poses.n, *self._edges.ends(include_pruned)))

    def component_of(self, node: int, include_pruned: bool = False) -> list[int]:
        """Sorted nodes of ``node``'s component (pruned edges ignored unless ``include_pruned``)."""
        if not 0 <= node < self._poses.n:
            raise IndexError(f"node {node} not in graph of {self.n_nodes} nodes")
        if include_pruned:
            return sorted(self.reachable([node]))
        return self.component_nodes(node)

    # ------------------------------------------------------------------ optimisation
    def optimize(
        self,
        config: PoseGraphConfig | None = None,
        reference_node: int = 0,
        nodes: Iterable[int] | None = None,
        max_boundary_edges: int | None = None,
        **overrides: float,
    ) -> OptimizationResult:
        """Optimise with LM and line-process edge pruning (:mod:`c3f_slam.posegraph.optimize`).

        ``nodes`` None: the reference node's whole component (over all edges, pruned ones
        too). Otherwise only ``nodes`` move: their neighbours outside ``nodes`` stay fixed
        (folded into an anchor node, see the notes of :mod:`c3f_slam.posegraph.optimize`), and
        so does the reference node when it is among ``nodes`` but some neighbour lies outside
        (so the world frame does not drift). ``max_boundary_edges``: per optimised node, at
        most this many edges to fixed *newer* nodes, the most recent first (edges to older
        nodes, added with the node, are all used), which bounds the work when old nodes keep
        being matched by new ones; None = all. ``overrides`` replace fields of ``config``
        (e.g. ``max_correspondence_distance=0.005``). Node poses and the ``pruned`` /
        ``confidence`` fields of the edges at the optimised nodes are updated in place; those
        edges are all reconsidered on every call.
        """
        cfg = resolve_config(config, overrides)
        window, fixed = optimize_window(self._parts, cfg, reference_node, nodes, max_boundary_edges)
        return OptimizationResult(
            self,
            pruned=[k for k in window.edge_ids if self._edges.pruned[k]],
            optimized_nodes=window.free,
            fixed_nodes=fixed,
            reference_node=reference_node,
        )
