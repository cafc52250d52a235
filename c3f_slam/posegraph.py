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
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import open3d as o3d

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


def _scale_information(info: np.ndarray, k: float) -> np.ndarray:
    """Information matrix of the same points with every length multiplied by k."""
    S = np.diag([k, k, k, 1.0, 1.0, 1.0])
    return S @ info @ S


def _scale_pose(T: np.ndarray, k: float) -> np.ndarray:
    T = np.array(T, dtype=np.float64)
    T[:3, 3] *= k
    return T


@dataclass
class Edge:
    """Constraint p_i = T_ij @ p_j between nodes i and j (metres)."""

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


@dataclass
class OptimizationResult:
    """Outcome of :meth:`PoseGraph.optimize`.

    ``poses``: (N, 4, 4) camera-to-world after optimisation (untouched for nodes outside the
    reference node's component). ``pruned``: indices of edges removed by the line process.
    ``confidence``: per-edge line-process value (1 for certain edges, 0 for pruned ones).
    ``edge_rms``: per-edge RMS point misalignment in metres under the optimised poses.
    ``component``: sorted nodes connected to the reference node by the edges kept.
    """

    poses: np.ndarray
    pruned: list[int]
    confidence: np.ndarray
    edge_rms: np.ndarray
    component: list[int]
    optimized_nodes: list[int] = field(default_factory=list)


class PoseGraph:
    """Nodes with camera-to-world poses and relative-pose edges, optimised with Open3D."""

    def __init__(self) -> None:
        self._poses: list[np.ndarray] = []
        self.edges: list[Edge] = []

    # ------------------------------------------------------------------ building
    def add_node(self, T_wc: np.ndarray) -> int:
        """Add a node with initial camera-to-world pose ``T_wc``; returns its index."""
        T = np.asarray(T_wc, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"node pose must be a finite 4x4 matrix, got shape {T.shape}")
        self._poses.append(T.copy())
        return len(self._poses) - 1

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
        n = len(self._poses)
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
        self.edges.append(Edge(i, j, T.copy(), info, bool(uncertain), kind or ("loop" if uncertain else "odometry")))
        return len(self.edges) - 1

    # ------------------------------------------------------------------ access
    @property
    def n_nodes(self) -> int:
        return len(self._poses)

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) current camera-to-world poses (initial or last optimised)."""
        return np.array(self._poses).reshape(-1, 4, 4)

    def set_pose(self, node: int, T_wc: np.ndarray) -> None:
        self._poses[node] = np.asarray(T_wc, dtype=np.float64).copy()

    def components(self, include_pruned: bool = False) -> list[list[int]]:
        """Connected components (sorted node lists, largest first) over the edges.

        Pruned edges are ignored unless ``include_pruned``.
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
        for comp in self.components(include_pruned):
            if node in comp:
                return comp
        raise IndexError(f"node {node} not in graph of {self.n_nodes} nodes")

    def edge_rms(self, poses: np.ndarray | None = None) -> np.ndarray:
        """Per-edge RMS point misalignment (metres): sqrt(e^T Lambda e / N)."""
        P = self.poses if poses is None else poses
        out = np.zeros(len(self.edges))
        for k, e in enumerate(self.edges):
            r = linearized_residual(e.T_ij, P[e.i], P[e.j])
            out[k] = np.sqrt(max(float(r @ e.information @ r), 0.0) / max(e.n_correspondences, 1.0))
        return out

    # ------------------------------------------------------------------ optimisation
    def optimize(
        self,
        config: PoseGraphConfig | None = None,
        reference_node: int = 0,
        **overrides: float,
    ) -> OptimizationResult:
        """Optimise the reference node's component with LM and line-process edge pruning.

        ``overrides`` replace fields of ``config`` (e.g. ``max_correspondence_distance=0.005``).
        The reference node keeps its pose. Node poses and the edges' ``pruned`` /
        ``confidence`` fields are updated in place; all edges are reconsidered on every call.
        """
        cfg = config or PoseGraphConfig()
        if overrides:
            cfg = replace(cfg, **overrides)
        if not cfg.max_correspondence_distance > 0:
            raise ValueError("max_correspondence_distance must be positive")
        if not 0 <= reference_node < self.n_nodes:
            raise ValueError(f"reference node {reference_node} not in graph of {self.n_nodes} nodes")

        nodes = self.component_of(reference_node, include_pruned=True)
        local = {v: k for k, v in enumerate(nodes)}
        edge_ids = [k for k, e in enumerate(self.edges) if e.i in local]
        k_scale = 1.0 / cfg.max_correspondence_distance

        graph = _reg.PoseGraph()
        for v in nodes:
            graph.nodes.append(_reg.PoseGraphNode(_scale_pose(self._poses[v], k_scale)))
        for k in edge_ids:
            e = self.edges[k]
            graph.edges.append(
                _reg.PoseGraphEdge(
                    local[e.j],  # source: the frame T_ij maps from
                    local[e.i],  # target
                    _scale_pose(e.T_ij, k_scale),
                    _scale_information(e.information, k_scale),
                    uncertain=e.uncertain,
                    confidence=1.0,
                )
            )
        option = _reg.GlobalOptimizationOption(
            max_correspondence_distance=1.0,  # internal unit = max_correspondence_distance
            edge_prune_threshold=cfg.edge_prune_threshold,
            preference_loop_closure=cfg.preference_loop_closure,
            reference_node=local[reference_node],
        )
        criteria = _reg.GlobalOptimizationConvergenceCriteria()
        criteria.max_iteration = int(cfg.max_iterations)
        if len(edge_ids) > 0:
            with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
                _reg.global_optimization(graph, _reg.GlobalOptimizationLevenbergMarquardt(), criteria, option)

        # Open3D keeps the surviving edges in their original order: match as a subsequence.
        kept = list(graph.edges)
        pos = 0
        for k in edge_ids:
            e = self.edges[k]
            if pos < len(kept) and _same_edge(kept[pos], local[e.j], local[e.i], e, k_scale):
                e.pruned, e.confidence = False, float(kept[pos].confidence) if e.uncertain else 1.0
                pos += 1
            else:
                e.pruned, e.confidence = True, 0.0
        if pos != len(kept):  # pragma: no cover - would mean Open3D reordered edges
            raise RuntimeError("could not match optimised edges to the input edges")
        for v in nodes:
            self._poses[v] = _scale_pose(np.asarray(graph.nodes[local[v]].pose), 1.0 / k_scale)

        return OptimizationResult(
            poses=self.poses,
            pruned=[k for k in edge_ids if self.edges[k].pruned],
            confidence=np.array([e.confidence for e in self.edges]),
            edge_rms=self.edge_rms(),
            component=self.component_of(reference_node),
            optimized_nodes=nodes,
        )


def _same_edge(edge: "_reg.PoseGraphEdge", s: int, t: int, ours: Edge, k: float) -> bool:
    """True when the Open3D edge is our edge ``ours`` (as built in ``optimize``)."""
    return (
        edge.source_node_id == s
        and edge.target_node_id == t
        and np.array_equal(np.asarray(edge.transformation), _scale_pose(ours.T_ij, k))
        and np.array_equal(np.asarray(edge.information), _scale_information(ours.information, k))
    )
