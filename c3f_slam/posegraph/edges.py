"""Edge storage of a pose graph: rows of growable arrays, not Python objects.

Memory (a global graph of ~10^5 edges): ~0.3 KB per edge instead of ~0.75 KB as objects. Per
edge: its ends, T_ij as its 3x4 top rows, the information matrix as its 21-value upper triangle
(float64, exact copies, so optimisation is bit-for-bit what it was with whole matrices; a
matrix that is not exactly rigid / symmetric is kept whole in a side dict), pruned / uncertain
flags, a kind code (:class:`EdgeKind`) and the line-process confidence. The per-node adjacency
lives in :mod:`c3f_slam.posegraph.adjacency`. :class:`EdgeList` is a sequence of :class:`Edge`
views built on access.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator
from collections.abc import Sequence as SequenceABC
from enum import Enum

import numpy as np

from c3f_slam.posegraph.blocks import BlockRows
from c3f_slam.posegraph.information import edge_rms


class EdgeKind(str, Enum):
    """What an edge links (str-valued: ``kind="loop"`` and ``EdgeKind.LOOP`` are the same)."""

    ODOMETRY = "odometry"
    LOOP = "loop"
    KEYFRAME = "keyframe"
    REJOIN = "rejoin"  #: a frame after a tracking break matched to a frame before it (:mod:`c3f_slam.pipeline.rejoin`)
    FALLBACK = "fallback"  #: consecutive frames aligned densely (:mod:`c3f_slam.pipeline.fallback`)


#: kind names (plain strings) by kind code: the code of an edge kind is its index in EdgeKind
_KIND_NAMES = tuple(kind.value for kind in EdgeKind)
#: upper triangle (row-major) of a 6x6 matrix: how symmetric information matrices are stored
_TRI = np.triu_indices(6)
_N_TRI = len(_TRI[0])  # 21; the last entry is (5, 5), the correspondence count
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0]).tobytes()
#: edge matrices are stored in blocks of this many edges (:class:`c3f_slam.posegraph.blocks.BlockRows`)
_EDGE_BLOCK = 4096


def kind_code(kind: EdgeKind | str) -> int:
    """Storage code of an edge kind (an :class:`EdgeKind` or its string)."""
    try:
        return _KIND_NAMES.index(EdgeKind(kind).value)
    except ValueError:
        raise ValueError(f"unknown edge kind {kind!r} (choose {', '.join(_KIND_NAMES)})") from None


class EdgeStore:
    """The edges' values in growable arrays (rows [0, m) are the edges): ends as int64
    ``array``s (fast scalar reads in the graph walks), T_ij as its top 3x4 rows and the
    symmetric information matrix as its 21-value upper triangle (float64, exact copies:
    matrices that are not exactly rigid / symmetric are kept whole in a side dict) in blocks
    of :data:`_EDGE_BLOCK` edges (:class:`~c3f_slam.posegraph.blocks.BlockRows`), flags, kind codes and
    confidences as (doubling) NumPy arrays. The flag / code / confidence arrays are replaced
    when they grow: read them through the store, do not keep them across :meth:`add`."""

    def __init__(self, capacity: int = 16) -> None:
        self.m = 0
        self.ei, self.ej = array("q"), array("q")
        self._T = BlockRows((3, 4), np.float64, _EDGE_BLOCK, capacity)
        self._info = BlockRows((_N_TRI,), np.float64, _EDGE_BLOCK, capacity)
        self._T_full: dict[int, np.ndarray] = {}
        self._info_full: dict[int, np.ndarray] = {}
        self.pruned = np.zeros(capacity, bool)
        self.uncertain = np.zeros(capacity, bool)
        self.kind = np.zeros(capacity, np.uint8)
        self.confidence = np.ones(capacity)

    # ------------------------------------------------------------------ writing
    def add(self, i: int, j: int, T: np.ndarray, info: np.ndarray, uncertain: bool, code: int) -> int:
        """Append the edge (i, j) with T_ij ``T`` (4x4), information ``info`` (6x6) and kind
        ``code`` (:func:`kind_code`), not pruned, confidence 1; returns its index."""
        k = self.m
        if k == len(self.pruned):
            self._grow()
        self._T.ensure(k)
        self._info.ensure(k)
        self._store_matrices(k, T, info)
        self.pruned[k] = False
        self.uncertain[k] = bool(uncertain)
        self.kind[k] = code
        self.confidence[k] = 1.0
        self.ei.append(i)
        self.ej.append(j)
        self.m = k + 1
        return k

    def _grow(self) -> None:
        """Double the capacity of the per-edge flag / code / confidence arrays."""
        for name in ("pruned", "uncertain", "kind", "confidence"):
            a = getattr(self, name)
            grown = np.zeros((2 * len(a),) + a.shape[1:], a.dtype)
            grown[: self.m] = a[: self.m]
            setattr(self, name, grown)

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

    # ------------------------------------------------------------------ one edge
    def transform(self, k: int) -> np.ndarray:
        """T_ij of edge ``k`` (a new 4x4 array)."""
        full = self._T_full.get(k)
        if full is not None:
            return full.copy()
        T = np.zeros((4, 4))
        T[:3] = self._T.row(k)
        T[3, 3] = 1.0
        return T

    def information(self, k: int) -> np.ndarray:
        """Information matrix of edge ``k`` (a new 6x6 array)."""
        full = self._info_full.get(k)
        if full is not None:
            return full.copy()
        L = np.empty((6, 6))
        tri = self._info.row(k)
        L[_TRI] = tri
        L[_TRI[1], _TRI[0]] = tri
        return L

    def n_correspondences(self, k: int) -> float:
        """Matched points of edge ``k`` (entry (5, 5) of its information matrix)."""
        full = self._info_full.get(k)
        return float(full[5, 5] if full is not None else self._info.row(k)[_N_TRI - 1])

    def other_end(self, k: int, v: int) -> int:
        """The end of edge ``k`` that is not ``v``."""
        i = self.ei[k]
        return self.ej[k] if i == v else i

    # ------------------------------------------------------------------ many edges
    def transforms(self, ids: np.ndarray) -> np.ndarray:
        """(E, 4, 4) T_ij of edges ``ids`` (new array)."""
        X = np.zeros((len(ids), 4, 4))
        X[:, :3] = self._T.take(ids)
        X[:, 3, 3] = 1.0
        if self._T_full:
            for n, k in enumerate(ids.tolist()):
                if k in self._T_full:
                    X[n] = self._T_full[k]
        return X

    def informations(self, ids: np.ndarray) -> np.ndarray:
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

    def ends(self, include_pruned: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(i, j) of the edges as int64 arrays (copies); pruned edges left out unless
        ``include_pruned``."""
        m = self.m
        ei = np.frombuffer(self.ei, np.int64, m).copy() if m else np.zeros(0, np.int64)
        ej = np.frombuffer(self.ej, np.int64, m).copy() if m else np.zeros(0, np.int64)
        if include_pruned:
            return ei, ej
        keep = ~self.pruned[:m]
        return ei[keep], ej[keep]

    def rms(self, poses: np.ndarray, ids: range | list[int]) -> np.ndarray:
        """RMS point misalignment (metres) of edges ``ids`` under camera-to-world ``poses``."""
        out = np.zeros(len(ids))
        for n, k in enumerate(ids):
            out[n] = edge_rms(self.transform(k), self.information(k), self.n_correspondences(k),
                              poses[self.ei[k]], poses[self.ej[k]])
        return out

    # ------------------------------------------------------------------ summaries
    def n_pruned(self) -> int:
        return int(np.count_nonzero(self.pruned[: self.m]))

    def kind_counts(self) -> dict[str, int]:
        """Edges per kind name, kinds present only."""
        counts = np.bincount(self.kind[: self.m], minlength=len(_KIND_NAMES))
        return {name: int(c) for name, c in zip(_KIND_NAMES, counts) if c}

    def pruned_kind_counts(self) -> dict[str, int]:
        """Pruned edges per kind name, kinds present only."""
        counts = np.bincount(self.kind[: self.m][self.pruned[: self.m]], minlength=len(_KIND_NAMES))
        return {name: int(c) for name, c in zip(_KIND_NAMES, counts) if c}

    def has_uncertain(self) -> bool:
        return bool(self.uncertain[: self.m].any())

    def confidences(self) -> np.ndarray:
        """(E,) line-process confidence per edge (a copy)."""
        return self.confidence[: self.m].copy()

    @property
    def n_matrix_blocks(self) -> int:
        """Storage blocks of the edge transforms (one per :data:`_EDGE_BLOCK` edges)."""
        return len(self._T.blocks)

    @property
    def nbytes(self) -> int:
        """Bytes held (arrays at capacity, side dicts' matrices)."""
        arrays = (self._T, self._info, self.pruned, self.uncertain, self.kind, self.confidence)  # all have nbytes
        return (sum(a.nbytes for a in arrays) + sum(a.itemsize * len(a) for a in (self.ei, self.ej))
                + 128 * len(self._T_full) + 288 * len(self._info_full))


class Edge:
    """View of one stored edge: the constraint p_i = T_ij @ p_j between nodes i and j
    (metres). Built on access from the store's arrays; ``T_ij`` and ``information`` are
    fresh copies. ``pruned`` and ``confidence`` can be set and land in the graph (call
    :meth:`~c3f_slam.posegraph.PoseGraph.refresh_components` after setting ``pruned`` by hand;
    :meth:`~c3f_slam.posegraph.PoseGraph.optimize` sets both itself)."""

    __slots__ = ("_k", "_s")

    def __init__(self, store: EdgeStore, k: int) -> None:
        self._s = store
        self._k = k

    @property
    def id(self) -> int:
        return self._k

    @property
    def i(self) -> int:
        return self._s.ei[self._k]

    @property
    def j(self) -> int:
        return self._s.ej[self._k]

    @property
    def T_ij(self) -> np.ndarray:
        return self._s.transform(self._k)

    @property
    def information(self) -> np.ndarray:
        return self._s.information(self._k)

    @property
    def uncertain(self) -> bool:
        return bool(self._s.uncertain[self._k])

    @property
    def kind(self) -> str:
        """The kind's name (a plain string, an :class:`EdgeKind` value)."""
        return _KIND_NAMES[int(self._s.kind[self._k])]

    @property
    def pruned(self) -> bool:
        return bool(self._s.pruned[self._k])

    @pruned.setter
    def pruned(self, value: bool) -> None:
        self._s.pruned[self._k] = bool(value)

    @property
    def confidence(self) -> float:
        return float(self._s.confidence[self._k])

    @confidence.setter
    def confidence(self, value: float) -> None:
        self._s.confidence[self._k] = float(value)

    @property
    def n_correspondences(self) -> float:
        return self._s.n_correspondences(self._k)

    def as_dict(self) -> dict:
        """The edge's values (what the former ``Edge`` dataclass held), as plain objects."""
        return {"i": self.i, "j": self.j, "T_ij": self.T_ij, "information": self.information,
                "uncertain": self.uncertain, "kind": self.kind, "pruned": self.pruned, "confidence": self.confidence}

    def __repr__(self) -> str:
        return (f"Edge(i={self.i}, j={self.j}, kind={self.kind!r}, uncertain={self.uncertain}, "
                f"pruned={self.pruned}, confidence={self.confidence:.3g})")


class EdgeList(SequenceABC):
    """The stored edges as a read-only sequence of :class:`Edge` views (``len``, indexing,
    slicing, iteration); the data stay in the store's arrays."""

    __slots__ = ("_s",)

    def __init__(self, store: EdgeStore) -> None:
        self._s = store

    def __len__(self) -> int:
        return self._s.m

    def __getitem__(self, k: int | slice) -> Edge | list[Edge]:  # type: ignore[override]
        m = self._s.m
        if isinstance(k, slice):
            return [Edge(self._s, n) for n in range(*k.indices(m))]
        k = int(k)
        if k < 0:
            k += m
        if not 0 <= k < m:
            raise IndexError(f"edge {k} not in graph of {m} edges")
        return Edge(self._s, k)

    def __iter__(self) -> Iterator[Edge]:
        s = self._s
        return (Edge(s, k) for k in range(s.m))
