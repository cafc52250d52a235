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

Memory (a global graph of ~10^5 edges): edges are rows of growable arrays, not Python
objects (~0.3 KB per edge instead of ~0.75 KB): ends, T_ij as its 3x4 top rows, the
information matrix as its 21-value upper triangle (float64, exact copies, so optimisation is
bit-for-bit what it was with whole matrices; a matrix that is not exactly rigid / symmetric is
kept whole in a side dict), pruned / uncertain flags, a kind code and the confidence; the
per-node adjacency is a linked list through the edges (two int64 links per edge, two heads per
node). :attr:`PoseGraph.edges` is a sequence of :class:`Edge` views built on access.
"""

from __future__ import annotations

from enum import Enum

from array import array
from collections.abc import Iterable, Iterator
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, replace
from functools import cached_property
from itertools import chain

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from c3f_slam.blocks import BlockRows
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


def transform_information(info: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Information matrix of the same points expressed in another frame: ``info`` was built
    from points p (:func:`information_from_points`), the result equals the one built from
    T @ p. With A = Ad(T) = [[R, 0], [[t]x R, R]] (rotation, translation order) the small
    motions relate by xi' = A xi and the result is A^-T info A^-1. Works on one (6, 6) / (4, 4)
    pair or on stacks (E, 6, 6) / (E, 4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    L = np.asarray(info, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    t = T[..., :3, 3]
    skew = np.zeros(t.shape[:-1] + (3, 3))
    skew[..., 0, 1], skew[..., 0, 2] = -t[..., 2], t[..., 1]
    skew[..., 1, 0], skew[..., 1, 2] = t[..., 2], -t[..., 0]
    skew[..., 2, 0], skew[..., 2, 1] = -t[..., 1], t[..., 0]
    A_inv = np.zeros(t.shape[:-1] + (6, 6))
    A_inv[..., :3, :3] = Rt
    A_inv[..., 3:, 3:] = Rt
    A_inv[..., 3:, :3] = -Rt @ skew
    return np.swapaxes(A_inv, -1, -2) @ L @ A_inv


def _scale_pose(T: np.ndarray, k: float) -> np.ndarray:
    T = np.array(T, dtype=np.float64)
    T[:3, 3] *= k
    return T


#: upper triangle (row-major) of a 6x6 matrix: how symmetric information matrices are stored
_TRI = np.triu_indices(6)
_N_TRI = len(_TRI[0])  # 21; the last entry is (5, 5), the correspondence count
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0]).tobytes()
class EdgeKind(str, Enum):
    """Kinds of edges (str-valued: summary.json counts them by these names)."""

    ODOMETRY = "odometry"  #: consecutive frames / fragments (certain)
    LOOP = "loop"  #: a keyframe match that closes a loop (uncertain)
    KEYFRAME = "keyframe"  #: a match to the predecessor's keyframe (uncertain)


#: the default edge kinds (codes 0, 1, 2); other names get the next codes per graph
_KINDS = ("odometry", "loop", "keyframe")
#: edge matrices are stored in blocks of this many edges (:class:`c3f_slam.blocks.BlockRows`)
_EDGE_BLOCK = 4096


class Edge:
    """View of one edge of a :class:`PoseGraph`: the constraint p_i = T_ij @ p_j between
    nodes i and j (metres). Built on access from the graph's arrays; ``T_ij`` and
    ``information`` are fresh copies. ``pruned`` and ``confidence`` can be set and land in
    the graph (call :meth:`PoseGraph.refresh_components` after setting ``pruned`` by hand;
    :meth:`PoseGraph.optimize` sets both itself)."""

    __slots__ = ("_g", "_k")

    def __init__(self, graph: "PoseGraph", k: int) -> None:
        self._g = graph
        self._k = k

    @property
    def id(self) -> int:
        return self._k

    @property
    def i(self) -> int:
        return self._g._ei[self._k]

    @property
    def j(self) -> int:
        return self._g._ej[self._k]

    @property
    def T_ij(self) -> np.ndarray:
        return self._g._transform(self._k)

    @property
    def information(self) -> np.ndarray:
        return self._g._information(self._k)

    @property
    def uncertain(self) -> bool:
        return bool(self._g._unc[self._k])

    @property
    def kind(self) -> str:
        return self._g._kind_names[int(self._g._kind[self._k])]

    @property
    def pruned(self) -> bool:
        return bool(self._g._pruned[self._k])

    @pruned.setter
    def pruned(self, value: bool) -> None:
        self._g._pruned[self._k] = bool(value)

    @property
    def confidence(self) -> float:
        return float(self._g._conf[self._k])

    @confidence.setter
    def confidence(self, value: float) -> None:
        self._g._conf[self._k] = float(value)

    @property
    def n_correspondences(self) -> float:
        return self._g._n_correspondences(self._k)

    def as_dict(self) -> dict:
        """The edge's values (what the former ``Edge`` dataclass held), as plain objects."""
        return dict(i=self.i, j=self.j, T_ij=self.T_ij, information=self.information, uncertain=self.uncertain,
                    kind=self.kind, pruned=self.pruned, confidence=self.confidence)

    def __repr__(self) -> str:
        return (f"Edge(i={self.i}, j={self.j}, kind={self.kind!r}, uncertain={self.uncertain}, "
                f"pruned={self.pruned}, confidence={self.confidence:.3g})")


class EdgeList(SequenceABC):
    """The edges of a :class:`PoseGraph` as a read-only sequence of :class:`Edge` views
    (``len``, indexing, slicing, iteration); the data stay in the graph's arrays."""

    __slots__ = ("_g",)

    def __init__(self, graph: "PoseGraph") -> None:
        self._g = graph

    def __len__(self) -> int:
        return self._g._m

    def __getitem__(self, k: int | slice) -> "Edge | list[Edge]":  # type: ignore[override]
        m = self._g._m
        if isinstance(k, slice):
            return [Edge(self._g, n) for n in range(*k.indices(m))]
        k = int(k)
        if k < 0:
            k += m
        if not 0 <= k < m:
            raise IndexError(f"edge {k} not in graph of {m} edges")
        return Edge(self._g, k)

    def __iter__(self) -> Iterator[Edge]:
        g = self._g
        return (Edge(g, k) for k in range(g._m))


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
        return self._graph._conf[: self._graph._m].copy()

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
        self._init_edge_storage()
        # union-find over the non-pruned edges, with member lists at the roots
        self._parent: list[int] = []
        self._size: list[int] = []
        self._cmin: list[int] = []  # oldest (smallest) node of a root's component
        self._members: list[list[int] | None] = []
        self._main = -1  # root of the main component (largest, ties to the oldest)

    # ------------------------------------------------------------------ edge storage
    def _init_edge_storage(self, capacity: int = 16) -> None:
        """Edges live in growable arrays (rows [0, m) are the edges), not in Python objects:
        ends and adjacency links as int64 ``array``s (fast scalar reads in the graph walks),
        T_ij as its top 3x4 rows and the symmetric information matrix as its 21-value upper
        triangle (float64, exact copies: matrices that are not exactly rigid / symmetric are
        kept whole in a side dict) in blocks of :data:`_EDGE_BLOCK` edges (:class:`~c3f_slam.blocks.BlockRows`),
        flags, kind codes and confidences as (doubling) NumPy arrays."""
        self._m = 0
        self._ei, self._ej = array("q"), array("q")
        # adjacency as linked lists through the edges: each edge is in the list of its newer
        # end ("older" edges of that node, bounded: added with the node) and of its older end
        # ("newer" edges, growing as later nodes match it); per node the last edge of each
        # list, per edge the previous edge of the same list (-1 = none)
        self._tail_older, self._tail_newer = array("q"), array("q")
        self._prev_older, self._prev_newer = array("q"), array("q")
        self._T = BlockRows((3, 4), np.float64, _EDGE_BLOCK, capacity)
        self._info = BlockRows((_N_TRI,), np.float64, _EDGE_BLOCK, capacity)
        self._T_full: dict[int, np.ndarray] = {}
        self._info_full: dict[int, np.ndarray] = {}
        self._pruned = np.zeros(capacity, bool)
        self._unc = np.zeros(capacity, bool)
        self._kind = np.zeros(capacity, np.uint8)
        self._conf = np.ones(capacity)
        self._kind_names: list[str] = list(_KINDS)

    def _grow_edges(self) -> None:
        """Double the capacity of the per-edge flag / code / confidence arrays."""
        for name in ("_pruned", "_unc", "_kind", "_conf"):
            a = getattr(self, name)
            grown = np.zeros((2 * len(a),) + a.shape[1:], a.dtype)
            grown[: self._m] = a[: self._m]
            setattr(self, name, grown)

    def _kind_code(self, kind: str) -> int:
        try:
            return self._kind_names.index(kind)
        except ValueError:
            if len(self._kind_names) >= 255:
                raise ValueError("too many edge kinds (at most 255)") from None
            self._kind_names.append(kind)
            return len(self._kind_names) - 1

    def _transform(self, k: int) -> np.ndarray:
        """T_ij of edge ``k`` (a new 4x4 array)."""
        full = self._T_full.get(k)
        if full is not None:
            return full.copy()
        T = np.zeros((4, 4))
        T[:3] = self._T.row(k)
        T[3, 3] = 1.0
        return T

    def _information(self, k: int) -> np.ndarray:
        """Information matrix of edge ``k`` (a new 6x6 array)."""
        full = self._info_full.get(k)
        if full is not None:
            return full.copy()
        L = np.empty((6, 6))
        tri = self._info.row(k)
        L[_TRI] = tri
        L[_TRI[1], _TRI[0]] = tri
        return L

    def _n_correspondences(self, k: int) -> float:
        full = self._info_full.get(k)
        return float(full[5, 5] if full is not None else self._info.row(k)[_N_TRI - 1])

    def _transforms(self, ids: np.ndarray) -> np.ndarray:
        """(E, 4, 4) T_ij of edges ``ids`` (new array)."""
        X = np.zeros((len(ids), 4, 4))
        X[:, :3] = self._T.take(ids)
        X[:, 3, 3] = 1.0
        if self._T_full:
            for n, k in enumerate(ids.tolist()):
                if k in self._T_full:
                    X[n] = self._T_full[k]
        return X

    def _informations(self, ids: np.ndarray) -> np.ndarray:
        """(E, 6, 6) information matrices of edges ``ids`` (new array)."""
        tri = self._info.take(ids)
        L = np.empty((len(ids), 6, 6))
        L[:, _TRI[0], _TRI[1]] = tri
        L[:, _TRI[1], _TRI[0]] = tri
        if self._info_full:
            for n, k in enumerate(ids.tolist()):
                if k in self._info_full:
                    L[n] = self._info_full[k]
        return L

    def _ends(self) -> tuple[np.ndarray, np.ndarray]:
        """(i, j) of all edges as int64 arrays (copies)."""
        m = self._m
        return (np.frombuffer(self._ei, np.int64, m).copy() if m else np.zeros(0, np.int64),
                np.frombuffer(self._ej, np.int64, m).copy() if m else np.zeros(0, np.int64))

    def _older_ids(self, v: int) -> list[int]:
        """Ids of the edges of ``v`` to older nodes, in the order they were added."""
        out, prev, k = [], self._prev_older, self._tail_older[v]
        while k >= 0:
            out.append(k)
            k = prev[k]
        out.reverse()
        return out

    def _newer_ids_recent_first(self, v: int) -> list[int]:
        """Ids of the edges of ``v`` to newer nodes, the most recently added first."""
        out, prev, k = [], self._prev_newer, self._tail_newer[v]
        while k >= 0:
            out.append(k)
            k = prev[k]
        return out

    def _iter_newer(self, v: int) -> Iterator[int]:
        """Like :meth:`_newer_ids_recent_first`, lazily (for walks that stop early)."""
        prev, k = self._prev_newer, self._tail_newer[v]
        while k >= 0:
            yield k
            k = prev[k]

    def _other_end(self, k: int, v: int) -> int:
        i = self._ei[k]
        return self._ej[k] if i == v else i

    @property
    def edges(self) -> EdgeList:
        """The edges as a sequence of :class:`Edge` views (see :class:`EdgeList`)."""
        return EdgeList(self)

    @property
    def n_edges(self) -> int:
        return self._m

    def n_pruned(self) -> int:
        """Number of pruned edges."""
        return int(np.count_nonzero(self._pruned[: self._m]))

    def kind_counts(self) -> dict[str, int]:
        """Edges per kind (``odometry``, ``loop``, ``keyframe``, ...), kinds present only."""
        counts = np.bincount(self._kind[: self._m], minlength=len(self._kind_names))
        return {name: int(c) for name, c in zip(self._kind_names, counts) if c}

    def has_uncertain(self) -> bool:
        return bool(self._unc[: self._m].any())

    def edge_nbytes(self) -> int:
        """Bytes held by the edge storage (arrays at capacity, side dicts' matrices)."""
        arrays = (self._T, self._info, self._pruned, self._unc, self._kind, self._conf)  # all have nbytes
        links = (self._ei, self._ej, self._prev_older, self._prev_newer, self._tail_older, self._tail_newer)
        return (sum(a.nbytes for a in arrays) + sum(a.itemsize * len(a) for a in links)
                + 128 * len(self._T_full) + 288 * len(self._info_full))

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
        self._tail_older.append(-1)
        self._tail_newer.append(-1)
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
        code = self._kind_code(kind or ("loop" if uncertain else "odometry"))
        k = self._m
        if k == len(self._pruned):
            self._grow_edges()
        self._T.ensure(k)
        self._info.ensure(k)
        self._store_matrices(k, T, info)
        self._pruned[k] = False
        self._unc[k] = bool(uncertain)
        self._kind[k] = code
        self._conf[k] = 1.0
        self._ei.append(i)
        self._ej.append(j)
        hi, lo = max(i, j), min(i, j)
        self._prev_older.append(self._tail_older[hi])
        self._tail_older[hi] = k
        self._prev_newer.append(self._tail_newer[lo])
        self._tail_newer[lo] = k
        self._m = k + 1
        self._union(i, j)
        return k

    def _store_matrices(self, k: int, T: np.ndarray, info: np.ndarray) -> None:
        """T_ij as its 3x4 top rows and the information as its upper triangle, or whole in
        the side dicts when the last row is not exactly (0, 0, 0, 1) / the matrix not exactly
        symmetric (so that every value read back is bit-for-bit the one given)."""
        if T[3].tobytes() == _LAST_ROW:
            self._T.set(k, T[:3])
        else:
            self._T_full[k] = T.copy()
        info = np.ascontiguousarray(info, dtype=np.float64)
        if info.tobytes() == np.ascontiguousarray(info.T).tobytes():
            self._info.set(k, info[_TRI])
        else:
            self._info_full[k] = info.copy()

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
        return self._older_ids(node) + self._newer_ids_recent_first(node)[::-1]

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
        self._rebuild_components()

    def _rebuild_components(self) -> None:
        """Union-find from scratch over the non-pruned edges (scipy, O(N + E) in C)."""
        n = self._n
        labels = self._component_labels(~self._pruned[: self._m])
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
                for k in chain(self._older_ids(v), self._newer_ids_recent_first(v)):
                    w = self._other_end(k, v)
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
        keep = np.ones(self._m, bool) if include_pruned else ~self._pruned[: self._m]
        groups: dict[int, list[int]] = {}
        for v, label in enumerate(self._component_labels(keep).tolist()):
            groups.setdefault(label, []).append(v)
        return sorted(groups.values(), key=lambda c: (-len(c), c[0]))

    def _component_labels(self, keep: np.ndarray) -> np.ndarray:
        """Per node, the label of its connected component over the edges where ``keep``
        (bool per edge) is True (scipy, O(N + E) in C)."""
        n = self._n
        ei, ej = self._ends()
        adj = coo_matrix((np.ones(int(keep.sum()), np.int8), (ei[keep], ej[keep])), shape=(n, n))
        return connected_components(adj, directed=False)[1]

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
        ids = range(self._m) if edges is None else list(edges)
        out = np.zeros(len(ids))
        for n, k in enumerate(ids):
            r = linearized_residual(self._transform(k), P[self._ei[k]], P[self._ej[k]])
            info = self._information(k)
            out[n] = np.sqrt(max(float(r @ info @ r), 0.0) / max(self._n_correspondences(k), 1.0))
        return out

    # ------------------------------------------------------------------ optimisation
    def _edges_at(self, free: list[int], free_set: set[int], max_boundary: int | None) -> tuple[list[int], bool]:
        """Sorted ids of the edges with an end in ``free_set`` (at most ``max_boundary`` per
        node to newer nodes outside it), and whether any has its other end outside."""
        ids: set[int] = set()
        outside = False
        ei, ej = self._ei, self._ej
        for v in free:
            for k in self._older_ids(v):
                ids.add(k)
                outside |= min(ei[k], ej[k]) not in free_set
            taken = 0
            for k in self._iter_newer(v):
                if max(ei[k], ej[k]) in free_set:  # listed with the newer node
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
        ids = np.asarray(edge_ids, np.int64)
        ei = np.fromiter((self._ei[k] for k in edge_ids), np.int64, E)
        ej = np.fromiter((self._ej[k] for k in edge_ids), np.int64, E)
        unc = self._unc[ids].tolist()
        X = self._transforms(ids)
        L = self._informations(ids)
        src, tgt = local[ej], local[ei]
        fixed_i, fixed_j = tgt < 0, src < 0
        if fixed_i.any():
            X[fixed_i] = self._P[ei[fixed_i]] @ X[fixed_i]
            tgt[fixed_i] = 0
        if fixed_j.any():
            T = X[fixed_j]
            L[fixed_j] = transform_information(L[fixed_j], T)
            X[fixed_j] = self._P[ej[fixed_j]] @ invert_pose(T)
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
        was_pruned = self._pruned[ids].tolist()
        for n, k in enumerate(edge_ids):
            was = was_pruned[n]
            if n_kept == E or (pos < n_kept and _same_edge(kept[pos], int(src[n]), int(tgt[n]), X[n])):
                self._conf[k] = float(kept[pos].confidence) if unc[n] else 1.0
                pos += 1
                if was:
                    self._pruned[k] = False
                    self._union(int(ei[n]), int(ej[n]))
            else:
                self._pruned[k], self._conf[k] = True, 0.0
                newly_pruned |= not was
        if pos != n_kept:  # pragma: no cover - would mean Open3D reordered edges
            raise RuntimeError("could not match optimised edges to the input edges")
        for v in free:
            self._P[v] = _scale_pose(np.asarray(graph.nodes[int(local[v])].pose), 1.0 / k_scale)
        if newly_pruned:
            self._rebuild_components()

        return OptimizationResult(
            self,
            pruned=[k for k in edge_ids if self._pruned[k]],
            optimized_nodes=free,
            fixed_nodes=fixed,
            reference_node=reference_node,
        )


def _same_edge(edge: "_reg.PoseGraphEdge", s: int, t: int, X: np.ndarray) -> bool:
    """True when the Open3D edge is the one built in ``optimize`` (source, target and the
    scaled transformation, compared exactly)."""
    return (
        edge.source_node_id == s
        and edge.target_node_id == t
        and np.array_equal(np.asarray(edge.transformation), X)
    )
