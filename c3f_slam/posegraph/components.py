"""Connected components of a pose graph.

Over the non-pruned edges the components are kept incrementally (:class:`Components`:
union-find with member lists, updated per edge; rebuilt only when an optimisation prunes an
edge), with the main component (largest, ties to the oldest node) tracked as edges are added.
:func:`components_from_labels` / :func:`component_labels` recompute everything from scratch,
and :func:`reachable` walks all edges (pruned ones too).
"""

from __future__ import annotations

from collections.abc import Iterable
from itertools import chain

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from c3f_slam.posegraph.adjacency import Adjacency
from c3f_slam.posegraph.edges import EdgeStore


def component_labels(n_nodes: int, ei: np.ndarray, ej: np.ndarray) -> np.ndarray:
    """Per node, the label of its connected component over the edges (ei[k], ej[k])
    (scipy, O(N + E) in C)."""
    adj = coo_matrix((np.ones(len(ei), np.int8), (ei, ej)), shape=(n_nodes, n_nodes))
    return connected_components(adj, directed=False)[1]


def components_from_labels(labels: np.ndarray) -> list[list[int]]:
    """The nodes grouped by component label: sorted node lists, largest first (ties: the
    one with the oldest node first)."""
    groups: dict[int, list[int]] = {}
    for v, label in enumerate(labels.tolist()):
        groups.setdefault(label, []).append(v)
    return sorted(groups.values(), key=lambda c: (-len(c), c[0]))


def reachable(adjacency: Adjacency, edges: EdgeStore, seeds: Iterable[int], limit: int | None = None) -> list[int]:
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
            for k in chain(adjacency.older_ids(v), adjacency.newer_ids_recent_first(v)):
                w = edges.other_end(k, v)
                if w not in seen:
                    if limit is not None and len(seen) >= limit:
                        return list(seen)
                    seen[w] = None
                    nxt.append(w)
        frontier = nxt
    return list(seen)


class Components:
    """Union-find over the nodes with member lists at the roots, the oldest node and the size
    per root, and the main component's root (largest, ties to the oldest)."""

    def __init__(self) -> None:
        self._parent: list[int] = []
        self._size: list[int] = []
        self._cmin: list[int] = []  # oldest (smallest) node of a root's component
        self._members: list[list[int] | None] = []
        self._main = -1

    def add_node(self) -> None:
        """Append a node in a component of its own."""
        n = len(self._parent)
        self._parent.append(n)
        self._size.append(1)
        self._cmin.append(n)
        self._members.append([n])
        if self._main < 0:
            self._main = n

    def find(self, node: int) -> int:
        """Root of ``node``'s component (amortised O(1))."""
        parent = self._parent
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    def _key(self, root: int) -> tuple[int, int]:
        return self._size[root], -self._cmin[root]

    def union(self, a: int, b: int) -> int:
        """Merge the components of ``a`` and ``b``; returns the new root."""
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

    def rebuild(self, labels: np.ndarray) -> None:
        """Union-find from scratch from per-node component ``labels`` (:func:`component_labels`)."""
        n = len(labels)
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

    def size(self, node: int) -> int:
        return self._size[self.find(node)]

    def oldest(self, node: int) -> int:
        """Smallest node of ``node``'s component."""
        return self._cmin[self.find(node)]

    def nodes(self, node: int) -> list[int]:
        """Sorted nodes of ``node``'s component (O(its size))."""
        members = self._members[self.find(node)]
        assert members is not None
        return sorted(members)

    @property
    def main_root(self) -> int:
        """Root of the main component (largest, ties to the oldest); -1 when empty."""
        return self._main

    def in_main(self, node: int) -> bool:
        """``node`` exists and lies in the main component."""
        return 0 <= node < len(self._parent) and self.find(node) == self._main

    def main_nodes(self) -> list[int]:
        """Sorted nodes of the main component (empty without nodes)."""
        return self.nodes(self._main) if self._parent else []
