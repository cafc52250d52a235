"""Node poses of a pose graph: camera-to-world ``T_wc`` (metres) in one growable (N, 4, 4) array."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


class NodePoses:
    """Camera-to-world poses of the nodes 0..n-1 ("world" = the graph's reference frame).

    The poses live in one array that doubles when full: :attr:`buffer` (rows [0, n) are the
    nodes) is replaced then, so read it anew after :meth:`add`."""

    def __init__(self) -> None:
        self.buffer = np.zeros((16, 4, 4))
        self.n = 0

    def add(self, T_wc: np.ndarray) -> int:
        """Append a node with pose ``T_wc``; returns its index."""
        T = np.asarray(T_wc, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"node pose must be a finite 4x4 matrix, got shape {T.shape}")
        n = self.n
        if n == len(self.buffer):
            grown = np.zeros((2 * len(self.buffer), 4, 4))
            grown[:n] = self.buffer[:n]
            self.buffer = grown
        self.buffer[n] = T
        self.n = n + 1
        return n

    def copy(self) -> np.ndarray:
        """(N, 4, 4) copy of the poses."""
        return self.buffer[: self.n].copy()

    def get(self, node: int) -> np.ndarray:
        """Pose of one node (a copy)."""
        if not 0 <= node < self.n:
            raise IndexError(f"node {node} not in graph of {self.n} nodes")
        return self.buffer[node].copy()

    def view(self) -> np.ndarray:
        """Read-only (N, 4, 4) view of the poses (no copy; invalid after the next change)."""
        v = self.buffer[: self.n]
        v.flags.writeable = False
        return v

    def set(self, node: int, T_wc: np.ndarray) -> None:
        self.buffer[node] = np.asarray(T_wc, dtype=np.float64)

    def transform(self, nodes: Iterable[int], G: np.ndarray) -> None:
        """Left-multiply the poses of ``nodes`` by G (move them rigidly in the world)."""
        idx = np.fromiter(nodes, dtype=np.int64)
        if len(idx):
            self.buffer[idx] = np.asarray(G, dtype=np.float64) @ self.buffer[idx]
