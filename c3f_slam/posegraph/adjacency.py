"""Per-node adjacency of a pose graph as linked lists through the edges.

Each edge is in the list of its newer end ("older" edges of that node, bounded: added with the
node) and in the list of its older end ("newer" edges, growing as later nodes match it). Per
node the last edge of each list, per edge the previous edge of the same list (-1 = none); all
int64 ``array``s (two links per edge, two heads per node), so walks read Python scalars fast.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator


class Adjacency:
    """Edge ids per node (see the module notes); nodes and edges are only ever appended."""

    def __init__(self) -> None:
        self._tail_older, self._tail_newer = array("q"), array("q")
        self._prev_older, self._prev_newer = array("q"), array("q")

    def add_node(self) -> None:
        """Append a node without edges."""
        self._tail_older.append(-1)
        self._tail_newer.append(-1)

    def add_edge(self, k: int, i: int, j: int) -> None:
        """Append edge ``k`` (the next edge id) between nodes ``i`` and ``j``."""
        hi, lo = max(i, j), min(i, j)
        self._prev_older.append(self._tail_older[hi])
        self._tail_older[hi] = k
        self._prev_newer.append(self._tail_newer[lo])
        self._tail_newer[lo] = k

    def older_ids(self, v: int) -> list[int]:
        """Ids of the edges of ``v`` to older nodes, in the order they were added."""
        out, prev, k = [], self._prev_older, self._tail_older[v]
        while k >= 0:
            out.append(k)
            k = prev[k]
        out.reverse()
        return out

    def newer_ids_recent_first(self, v: int) -> list[int]:
        """Ids of the edges of ``v`` to newer nodes, the most recently added first."""
        return list(self.iter_newer(v))

    def iter_newer(self, v: int) -> Iterator[int]:
        """Like :meth:`newer_ids_recent_first`, lazily (for walks that stop early)."""
        prev, k = self._prev_newer, self._tail_newer[v]
        while k >= 0:
            yield k
            k = prev[k]

    def edges_of(self, v: int) -> list[int]:
        """Ids of the edges at ``v``: to older nodes, then to newer ones, in the order added."""
        return self.older_ids(v) + self.newer_ids_recent_first(v)[::-1]

    @property
    def nbytes(self) -> int:
        """Bytes held by the links."""
        links = (self._prev_older, self._prev_newer, self._tail_older, self._tail_newer)
        return sum(a.itemsize * len(a) for a in links)
