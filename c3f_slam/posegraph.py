"""Pose-graph optimisation with line-process edge pruning (Choi et al. 2015) on Open3D.

One class serves both levels of SPEC §4.2: the intra-fragment graph (nodes = frames of a
fragment, node 0 = its keyframe, poses relative to the keyframe) and the global graph
(nodes = keyframes, node 0 = the first keyframe).

Conventions
-----------
Our side (see ``c3f_slam.geometry``): node poses are camera-to-world ``T_wc`` (the "world"
being the graph's reference frame); an edge ``(i, j, T_ij)`` says p_i = T_ij @ p_j, i.e.
T_ij = inv(T_wi) @ T_wj. Metres and radians.

Open3D 0.19 (``pipelines/registration/GlobalOptimization.cpp``; pinned by
``tests/test_slam_posegraph.py::test_open3d_edge_convention``):

- ``PoseGraphNode.pose`` is the node's camera-to-world pose;
- ``PoseGraphEdge(s, t).transformation`` X is consistent when X = inv(pose_t) @ pose_s:
  it maps *source*-frame points into the *target* frame (X = T_ts in our naming). So our
  edge T_ij is stored as an Open3D edge with source = j, target = i;
- the residual is the linearisation of inv(X) @ inv(pose_t) @ pose_s ~ (w, v), acting on
  *source*-frame points, with the 6-vector ordered (rotation, translation). The information
  matrix is therefore sum_p G^T G with G = [-[p]x | I] over the matched points p **in the
  source frame j**; its (5, 5) entry is the number of correspondences, which Open3D uses
  for the line-process weight mu = preference_loop_closure * max_correspondence_distance^2 *
  mean(correspondences);
- uncertain edges get a line-process confidence l = (mu / (mu + e^T Lambda e))^2; those with
  l <= edge_prune_threshold are removed from the graph (two optimise/prune passes).
  Roughly: an uncertain edge is pruned when the RMS misalignment of its points after
  optimisation exceeds max_correspondence_distance * sqrt(preference_loop_closure)
  (times sqrt of mean/own correspondence count);
- ``global_optimization`` silently does nothing on a disconnected graph, so this wrapper
  optimises the connected component of the reference node and leaves other nodes as given;
- Open3D's convergence thresholds are absolute (e.g. residual < 1e-6), so the graph is
  optimised in units of ``max_correspondence_distance`` (all lengths divided by it), which
  makes the result independent of the scene scale (colon millimetres or room metres).

Scale (a global graph of thousands of keyframes)
-----------------------------------------------
Open3D's Levenberg-Marquardt builds a *dense* 6N x 6N system (measured on 2 cores: 100 nodes
0.03 s, 200 nodes 0.15 s, 400 nodes 1.5 s, 800 nodes 7.8 s), so :meth:`PoseGraph.optimize`
can also optimise a bounded set of *free* nodes with every other node fixed: the fixed
neighbours are folded into one anchor node (the world, identity) and each edge between a free
and a fixed node becomes an edge between the free node and the anchor, with the same residual
(:func:`transform_information` re-expresses its information matrix when the free node was the
edge's target). Connected components over the non-pruned edges are kept incrementally
(union-find with member lists, updated per edge; rebuilt only when an optimisation prunes an
edge), with the main component (largest, ties to the oldest node) tracked as edges are added;
:meth:`PoseGraph.components` recomputes everything from scratch for callers that need it.
Poses live in one growable (N, 4, 4) array, so :meth:`PoseGraph.pose` reads one node and
:meth:`PoseGraph.pose_array` gives a read-only view for vectorised queries.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from functools import cached_property
from itertools import chain

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from c3f_slam.geometry import invert_pose

_reg = o3d.pipelines.registration


@dataclass(frozen=True)
class PoseGraphConfig:
    """Optimisation options; lengths in metres.

    - ``max_correspondence_distance``: the misalignment (RMS over an edge's points) at which
      an uncertain edge starts being distrusted; also the internal length unit.
    - ``edge_prune_threshold``: line-process confidence below which an uncertain edge is pruned.
    - ``preference_loop_closure``: weight of loop closures against odometry (larger keeps
      more loop edges).
    """

    max_correspondence_distance: float = 0.003
    edge_prune_threshold: float = 0.25
    preference_loop_closure: float = 1.0
    max_iterations: int = 100


#: Colon: 3 mm (a few voxels of the 1 mm TSDF, the size of DepthNet's depth noise at a few
#: cm). Room (RGB-D indoor scenes, Open3D's reconstruction system uses 1.4 x 5 cm voxels): 7 cm.
POSEGRAPH_PRESETS: dict[str, PoseGraphConfig] = {
    "colon": PoseGraphConfig(max_correspondence_distance=0.003),
    "room": PoseGraphConfig(max_correspondence_distance=0.07),
}


def information_from_points(points: np.ndarray) -> np.ndarray:
    """6x6 information matrix sum_p G^T G, G = [-[p]x | I] (Choi et al. 2015, Open3D order).

    ``points`` (N, 3) are the matched 3D points, in metres, in the frame the edge's transform
    maps *from* (frame j of T_ij; Open3D's source frame). Entry (5, 5) equals N. Same values
    as Open3D 0.19's ``get_information_matrix_from_point_clouds`` for these points (which
    takes them from the target cloud instead; a test pins the equality).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    n = len(p)
    G = np.zeros((n, 3, 6))
    # -[p]x = [[0, z, -y], [-z, 0, x], [y, -x, 0]]
    G[:, 0, 1], G[:, 0, 2] = z, -y
    G[:, 1, 0], G[:, 1, 2] = -z, x
    G[:, 2, 0], G[:, 2, 1] = y, -x
    G[:, 0, 3] = G[:, 1, 4] = G[:, 2, 5] = 1.0
    return np.einsum("nki,nkj->ij", G, G)


def linearized_residual(T_ij: np.ndarray, T_wi: np.ndarray, T_wj: np.ndarray) -> np.ndarray:
    """Open3D's edge residual (w, v): linearisation of inv(T_ij) @ inv(T_wi) @ T_wj (radians, m)."""
    M = invert_pose(T_ij) @ invert_pose(T_wi) @ T_wj
    w = 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    return np.concatenate([w, M[:3, 3]])


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def transform_information(info: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Information matrix of the same points expressed in another frame: ``info`` was built
    from points p (:func:`information_from_points`), the result equals the one built from
    T @ p. With A = Ad(T) = [[R, 0], [[t]x R, R]] (rotation, translation order) the small
    motions relate by xi' = A xi and the result is A^-T info A^-1."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    A_inv = np.zeros((6, 6))
    A_inv[:3, :3] = R.T
    A_inv[3:, 3:] = R.T
    A_inv[3:, :3] = -R.T @ _skew(t)
    return A_inv.T @ np.asarray(info, dtype=np.float64) @ A_inv


def _scale_pose(T: np.ndarray, k: float) -> np.ndarray:
    T = np.array(T, dtype=np.float64)
    T[:3, 3] *= k
    return T


@dataclass(slots=True)
class Edge:
    """Constraint p_i = T_ij @ p_j between nodes i and j (metres).

    Set ``pruned`` through :meth:`PoseGraph.optimize` (or call
    :meth:`PoseGraph.refresh_components` after changing it by hand)."""

    i: int
    j: int
    T_ij: np.ndarray
    information: np.ndarray
    uncertain: bool = False
    kind: str = "odometry"
    pruned: bool = False
    confidence: float = 1.0

    @property
    def n_correspondences(self) -> float:
        return float(self.information[5, 5])


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

    def __init__(self, graph: "PoseGraph", pruned: list[int], optimized_nodes: list[int],
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
        return np.array([e.confidence for e in self._graph.edges])

    @cached_property
    def edge_rms(self) -> np.ndarray:
        return self._graph.edge_rms()

    @cached_property
    def component(self) -> list[int]:
        return self._graph.component_of(self.reference_node)


class PoseGraph:
    """Nodes with camera-to-world poses and relative-pose edges, optimised with Open3D."""

    def __init__(self) -> None:
        self._P = np.zeros((16, 4, 4))  # growable pose array; rows [0, n) are the nodes
        self._n = 0
        self.edges: list[Edge] = []
        # per node, ids of its edges (pruned ones too) to older nodes (bounded: added with the
        # node) and to newer ones (grows as later nodes match it)
        self._older: list[list[int]] = []
        self._newer: list[list[int]] = []
        # union-find over the non-pruned edges, with member lists at the roots
        self._parent: list[int] = []
        self._size: list[int] = []
        self._cmin: list[int] = []  # oldest (smallest) node of a root's component
        self._members: list[list[int] | None] = []
        self._main = -1  # root of the main component (largest, ties to the oldest)
        self._ends = np.zeros((16, 2), np.int64)  # per edge (i, j), growable
        self._pruned = np.zeros(16, bool)  # per edge, mirrors Edge.pruned

    # ------------------------------------------------------------------ building
    def add_node(self, T_wc: np.ndarray) -> int:
        """Add a node with initial camera-to-world pose ``T_wc``; returns its index."""
        T = np.asarray(T_wc, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"node pose must be a finite 4x4 matrix, got shape {T.shape}")
        n = self._n
        if n == len(self._P):
            grown = np.zeros((2 * len(self._P), 4, 4))
            grown[:n] = self._P[:n]
            self._P = grown
        self._P[n] = T
        self._n = n + 1
        self._older.append([])
        self._newer.append([])
        self._parent.append(n)
        self._size.append(1)
        self._cmin.append(n)
        self._members.append([n])
        if self._main < 0:
            self._main = n
        return n

    def add_edge(
        self,
        i: int,
        j: int,
        T_ij: np.ndarray,
        points_j: np.ndarray | None = None,
        information: np.ndarray | None = None,
        uncertain: bool = False,
        kind: str | None = None,
    ) -> int:
        """Add the constraint p_i = T_ij @ p_j; returns the edge index.

        Give either the matched 3D points of frame j (``points_j``, metres, frame-j
        coordinates) or a 6x6 ``information`` matrix in Open3D's (rotation, translation)
        order. Odometry edges are ``uncertain=False`` (never pruned); loop closures are
        ``uncertain=True``.
        """
        n = self._n
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
        k = len(self.edges)
        if k == len(self._ends):
            self._ends = np.concatenate([self._ends, np.zeros_like(self._ends)])
            self._pruned = np.concatenate([self._pruned, np.zeros_like(self._pruned)])
        self._ends[k] = (i, j)
        self._pruned[k] = False
        self.edges.append(Edge(i, j, T.copy(), info, bool(uncertain), kind or ("loop" if uncertain else "odometry")))
        self._older[max(i, j)].append(k)
        self._newer[min(i, j)].append(k)
        self._union(i, j)
        return k

    # ------------------------------------------------------------------ access
    @property
    def n_nodes(self) -> int:
        return self._n

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) copy of the current camera-to-world poses (initial or last optimised)."""
        return self._P[: self._n].copy()

    def pose(self, node: int) -> np.ndarray:
        """Camera-to-world pose of one node (a copy)."""
        if not 0 <= node < self._n:
            raise IndexError(f"node {node} not in graph of {self._n} nodes")
        return self._P[node].copy()

    def pose_array(self) -> np.ndarray:
        """Read-only (N, 4, 4) view of the poses (no copy; invalid after the next change)."""
        v = self._P[: self._n]
        v.flags.writeable = False
        return v

    def set_pose(self, node: int, T_wc: np.ndarray) -> None:
        self._P[node] = np.asarray(T_wc, dtype=np.float64)

    def transform_nodes(self, nodes: Iterable[int], G: np.ndarray) -> None:
        """Left-multiply the poses of ``nodes`` by G (move them rigidly in the world)."""
        idx = np.fromiter(nodes, dtype=np.int64)
        if len(idx):
            self._P[idx] = np.asarray(G, dtype=np.float64) @ self._P[idx]

    def edges_of(self, node: int) -> list[int]:
        """Ids of the edges at ``node`` (pruned ones too)."""
        return self._older[node] + self._newer[node]

    # ------------------------------------------------------------------ components
    def find(self, node: int) -> int:
        """Root of ``node``'s component over the non-pruned edges (amortised O(1))."""
        parent = self._parent
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    def _key(self, root: int) -> tuple[int, int]:
        return self._size[root], -self._cmin[root]

    def _union(self, a: int, b: int) -> int:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return ra
        if self._size[ra] < self._size[rb]:
            ra, rb = rb, ra
        self._parent[rb] = ra
        self._size[ra] += self._size[rb]
        self._cmin[ra] = min(self._cmin[ra], self._cmin[rb])
        self._members[ra].extend(self._members[rb])  # smaller into larger: amortised O(log n) per node
        self._members[rb] = None
        if self._main in (ra, rb) or self._key(ra) > self._key(self._main):
            self._main = ra
        return ra

    def refresh_components(self) -> None:
        """Rebuild the union-find from the edges' ``pruned`` flags (call it after changing
        them by hand; :meth:`optimize` keeps the components up to date itself)."""
        E = len(self.edges)
        self._pruned[:E] = [e.pruned for e in self.edges]
        self._rebuild_components()

    def _rebuild_components(self) -> None:
        """Union-find from scratch over the non-pruned edges (scipy, O(N + E) in C)."""
        n, E = self._n, len(self.edges)
        keep = ~self._pruned[:E]
        ends = self._ends[:E][keep]
        adj = coo_matrix((np.ones(len(ends), np.int8), (ends[:, 0], ends[:, 1])), shape=(n, n))
        _, labels = connected_components(adj, directed=False)
        order = np.argsort(labels, kind="stable")  # nodes ascending within each label
        starts = np.concatenate([[0], np.flatnonzero(np.diff(labels[order])) + 1]) if n else np.zeros(0, np.int64)
        roots = order[starts]  # the oldest node of each label
        sizes = np.diff(np.concatenate([starts, [n]]))
        root_of_label = np.empty(len(roots), np.int64)
        root_of_label[labels[roots]] = roots
        self._parent = root_of_label[labels].tolist()
        self._size = [1] * n
        self._cmin = list(range(n))
        self._members = [None] * n
        for r, a, b in zip(roots.tolist(), starts.tolist(), (starts + sizes).tolist()):
            self._size[r] = b - a
            self._members[r] = order[a:b].tolist()
        self._main = -1
        if n:
            best = np.lexsort((roots, -sizes))[0]  # largest, ties to the oldest
            self._main = int(roots[best])

    def component_size(self, node: int) -> int:
        return self._size[self.find(node)]

    def component_oldest(self, node: int) -> int:
        """Smallest node of ``node``'s component (non-pruned edges)."""
        return self._cmin[self.find(node)]

    def component_nodes(self, node: int) -> list[int]:
        """Sorted nodes of ``node``'s component over the non-pruned edges (O(its size))."""
        members = self._members[self.find(node)]
        assert members is not None
        return sorted(members)

    def connected(self, a: int, b: int) -> bool:
        return self.find(a) == self.find(b)

    @property
    def main_root(self) -> int:
        """Root of the main component (largest, ties to the oldest); -1 when empty."""
        return self._main

    def in_main(self, node: int) -> bool:
        """``node`` lies in the main component (non-pruned edges)."""
        return 0 <= node < self._n and self.find(node) == self._main

    def main_component(self) -> list[int]:
        return self.component_nodes(self._main) if self._n else []

    def reachable(self, seeds: Iterable[int], limit: int | None = None) -> list[int]:
        """Nodes reached from ``seeds`` over all edges (pruned ones too), breadth first, at
        most ``limit`` of them (None: the whole component); the seeds come first."""
        seen: dict[int, None] = {}
        for s in seeds:
            if limit is not None and len(seen) >= limit:
                return list(seen)
            seen.setdefault(int(s), None)
        frontier = list(seen)
        while frontier:
            nxt = []
            for v in frontier:
                for k in chain(self._older[v], reversed(self._newer[v])):
                    e = self.edges[k]
                    w = e.j if e.i == v else e.i
                    if w not in seen:
                        if limit is not None and len(seen) >= limit:
                            return list(seen)
                        seen[w] = None
                        nxt.append(w)
            frontier = nxt
        return list(seen)

    def components(self, include_pruned: bool = False) -> list[list[int]]:
        """Connected components (sorted node lists, largest first) over the edges, computed
        from scratch (O(graph); see :meth:`component_nodes` / :meth:`in_main` for the
        incremental queries). Pruned edges are ignored unless ``include_pruned``.
        """
        parent = list(range(self.n_nodes))

        def find(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        for e in self.edges:
            if e.pruned and not include_pruned:
                continue
            ra, rb = find(e.i), find(e.j)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
        groups: dict[int, list[int]] = {}
        for v in range(self.n_nodes):
            groups.setdefault(find(v), []).append(v)
        return sorted(groups.values(), key=lambda c: (-len(c), c[0]))

    def component_of(self, node: int, include_pruned: bool = False) -> list[int]:
        """Sorted nodes of ``node``'s component (pruned edges ignored unless ``include_pruned``)."""
        if not 0 <= node < self._n:
            raise IndexError(f"node {node} not in graph of {self.n_nodes} nodes")
        if include_pruned:
            return sorted(self.reachable([node]))
        return self.component_nodes(node)

    def edge_rms(self, poses: np.ndarray | None = None, edges: Iterable[int] | None = None) -> np.ndarray:
        """Per-edge RMS point misalignment (metres): sqrt(e^T Lambda e / N) (of ``edges``,
        default all)."""
        P = self._P if poses is None else poses
        ids = range(len(self.edges)) if edges is None else list(edges)
        out = np.zeros(len(ids))
        for n, k in enumerate(ids):
            e = self.edges[k]
            r = linearized_residual(e.T_ij, P[e.i], P[e.j])
            out[n] = np.sqrt(max(float(r @ e.information @ r), 0.0) / max(e.n_correspondences, 1.0))
        return out

    # ------------------------------------------------------------------ optimisation
    def _edges_at(self, free: list[int], free_set: set[int], max_boundary: int | None) -> tuple[list[int], bool]:
        """Sorted ids of the edges with an end in ``free_set`` (at most ``max_boundary`` per
        node to newer nodes outside it), and whether any has its other end outside."""
        ids: set[int] = set()
        outside = False
        for v in free:
            for k in self._older[v]:
                ids.add(k)
                e = self.edges[k]
                outside |= min(e.i, e.j) not in free_set
            taken = 0
            for k in reversed(self._newer[v]):
                e = self.edges[k]
                if max(e.i, e.j) in free_set:  # listed with the newer node
                    continue
                if max_boundary is not None and taken >= max_boundary:
                    break
                ids.add(k)
                taken += 1
                outside = True
        return sorted(ids), outside

    def optimize(
        self,
        config: PoseGraphConfig | None = None,
        reference_node: int = 0,
        nodes: Iterable[int] | None = None,
        max_boundary_edges: int | None = None,
        **overrides: float,
    ) -> OptimizationResult:
        """Optimise with LM and line-process edge pruning.

        ``nodes`` None: the reference node's whole component (over all edges, pruned ones
        too). Otherwise only ``nodes`` move: their neighbours outside ``nodes`` stay fixed
        (folded into an anchor node, see the module notes), and so does the reference node
        when it is among ``nodes`` but some neighbour lies outside (so the world frame does
        not drift). ``max_boundary_edges``: per optimised node, at most this many edges to
        fixed *newer* nodes, the most recent first (edges to older nodes, added with the node,
        are all used), which bounds the work when old nodes keep being matched by new ones;
        None = all. ``overrides`` replace fields of ``config`` (e.g.
        ``max_correspondence_distance=0.005``). Node poses and the ``pruned`` / ``confidence``
        fields of the edges at the optimised nodes are updated in place; those edges are all
        reconsidered on every call.
        """
        cfg = config or PoseGraphConfig()
        if overrides:
            cfg = replace(cfg, **overrides)
        if not cfg.max_correspondence_distance > 0:
            raise ValueError("max_correspondence_distance must be positive")
        if not 0 <= reference_node < self.n_nodes:
            raise ValueError(f"reference node {reference_node} not in graph of {self.n_nodes} nodes")

        if nodes is None:
            free = sorted(self.reachable([reference_node]))
        else:
            free = sorted({int(v) for v in nodes})
            if any(not 0 <= v < self._n for v in free):
                raise ValueError("optimised nodes must exist")
        free_set = set(free)
        edge_ids, outside = self._edges_at(free, free_set, max_boundary_edges)
        if outside and reference_node in free_set:
            free_set.discard(reference_node)
            free = [v for v in free if v != reference_node]
            edge_ids, outside = self._edges_at(free, free_set, max_boundary_edges)
        if not outside and reference_node not in free_set:
            raise ValueError(f"reference node {reference_node} is not connected to the optimised nodes")
        k_scale = 1.0 / cfg.max_correspondence_distance

        # local ids: the anchor (world, identity) first when some neighbour is fixed
        local = np.full(self._n, -1, np.int64)
        local[free] = np.arange(len(free)) + int(outside)
        graph = _reg.PoseGraph()
        if outside:
            graph.nodes.append(_reg.PoseGraphNode(np.eye(4)))
        for v in free:
            graph.nodes.append(_reg.PoseGraphNode(_scale_pose(self._P[v], k_scale)))

        # the edges as Open3D sees them, vectorised: source = the frame T_ij maps from (j),
        # target = i; a fixed target becomes the anchor (map frame-j points into the world);
        # with a fixed source j the edge is reversed (frame-i points into the world)
        E = len(edge_ids)
        es = [self.edges[k] for k in edge_ids]
        ei = np.fromiter((e.i for e in es), np.int64, E)
        ej = np.fromiter((e.j for e in es), np.int64, E)
        unc = [e.uncertain for e in es]
        X = np.array([e.T_ij for e in es]).reshape(E, 4, 4)
        L = np.array([e.information for e in es]).reshape(E, 6, 6)
        src, tgt = local[ej], local[ei]
        fixed_i, fixed_j = tgt < 0, src < 0
        if fixed_i.any():
            X[fixed_i] = self._P[ei[fixed_i]] @ X[fixed_i]
            tgt[fixed_i] = 0
        if fixed_j.any():
            T = X[fixed_j]
            L[fixed_j] = _transform_information_batch(L[fixed_j], T)
            X[fixed_j] = self._P[ej[fixed_j]] @ _invert_batch(T)
            src[fixed_j], tgt[fixed_j] = local[ei[fixed_j]], 0
        fixed = sorted(set(ei[fixed_i].tolist()) | set(ej[fixed_j].tolist()))
        X[:, :3, 3] *= k_scale
        sc = np.array([k_scale] * 3 + [1.0] * 3)
        L *= np.outer(sc, sc)
        for n in range(E):
            graph.edges.append(_reg.PoseGraphEdge(int(src[n]), int(tgt[n]), X[n], L[n], uncertain=unc[n],
                                                  confidence=1.0))
        option = _reg.GlobalOptimizationOption(
            max_correspondence_distance=1.0,  # internal unit = max_correspondence_distance
            edge_prune_threshold=cfg.edge_prune_threshold,
            preference_loop_closure=cfg.preference_loop_closure,
            reference_node=0 if outside else int(local[reference_node]),
        )
        criteria = _reg.GlobalOptimizationConvergenceCriteria()
        criteria.max_iteration = int(cfg.max_iterations)
        if E:
            with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
                _reg.global_optimization(graph, _reg.GlobalOptimizationLevenbergMarquardt(), criteria, option)

        # Open3D keeps the surviving edges in their original order: with none removed they
        # line up, else match them as a subsequence (source, target, transformation).
        kept = graph.edges
        n_kept = len(kept)
        newly_pruned = False
        pos = 0
        for n, e in enumerate(es):
            was = e.pruned
            if n_kept == E or (pos < n_kept and _same_edge(kept[pos], int(src[n]), int(tgt[n]), X[n])):
                e.pruned, e.confidence = False, float(kept[pos].confidence) if e.uncertain else 1.0
                pos += 1
                if was:
                    self._pruned[edge_ids[n]] = False
                    self._union(e.i, e.j)
            else:
                e.pruned, e.confidence = True, 0.0
                self._pruned[edge_ids[n]] = True
                newly_pruned |= not was
        if pos != n_kept:  # pragma: no cover - would mean Open3D reordered edges
            raise RuntimeError("could not match optimised edges to the input edges")
        for v in free:
            self._P[v] = _scale_pose(np.asarray(graph.nodes[int(local[v])].pose), 1.0 / k_scale)
        if newly_pruned:
            self._rebuild_components()

        return OptimizationResult(
            self,
            pruned=[k for k, e in zip(edge_ids, es) if e.pruned],
            optimized_nodes=free,
            fixed_nodes=fixed,
            reference_node=reference_node,
        )


def _invert_batch(T: np.ndarray) -> np.ndarray:
    """Inverses of (E, 4, 4) rigid transforms."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("eij,ej->ei", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def _transform_information_batch(L: np.ndarray, T: np.ndarray) -> np.ndarray:
    """:func:`transform_information` of (E, 6, 6) matrices by (E, 4, 4) transforms."""
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    t = T[:, :3, 3]
    skew = np.zeros((len(T), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -t[:, 2], t[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = t[:, 2], -t[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -t[:, 1], t[:, 0]
    A_inv = np.zeros((len(T), 6, 6))
    A_inv[:, :3, :3] = Rt
    A_inv[:, 3:, 3:] = Rt
    A_inv[:, 3:, :3] = -Rt @ skew
    return np.swapaxes(A_inv, 1, 2) @ L @ A_inv


def _same_edge(edge: "_reg.PoseGraphEdge", s: int, t: int, X: np.ndarray) -> bool:
    """True when the Open3D edge is the one built in ``optimize`` (source, target and the
    scaled transformation, compared exactly)."""
    return (
        edge.source_node_id == s
        and edge.target_node_id == t
        and np.array_equal(np.asarray(edge.transformation), X)
    )
