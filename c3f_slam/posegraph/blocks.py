"""Growable row storage for maps that only grow (pose-graph edges, keyframe descriptors).

:class:`BlockRows` keeps an (n, *shape) array as a list of fixed blocks of ``block_rows``
rows (a power of two), the first one growing to that size by doubling: a big array is never
copied as a whole or over-allocated by more than one block when it grows, and the values
read back are exact copies of the ones written.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np


class BlockRows:
    """A growable (n, *shape) array of ``dtype`` in blocks of ``block_rows`` rows (see the
    module notes); the first block starts with ``capacity`` rows."""

    __slots__ = ("shape", "dtype", "block_rows", "_shift", "blocks")

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype | type = np.float64, block_rows: int = 4096,
                 capacity: int = 16) -> None:
        if block_rows < 1 or block_rows & (block_rows - 1):
            raise ValueError(f"block_rows must be a power of two, got {block_rows}")
        self.shape = tuple(shape)
        self.dtype = np.dtype(dtype)
        self.block_rows = block_rows
        self._shift = block_rows.bit_length() - 1
        self.blocks = [np.zeros((max(min(capacity, block_rows), 1),) + self.shape, self.dtype)]

    def ensure(self, k: int) -> None:
        """Make row ``k`` (at most one past the last row) writable."""
        b, r = k >> self._shift, k & (self.block_rows - 1)
        if b == len(self.blocks):
            self.blocks.append(np.zeros((self.block_rows,) + self.shape, self.dtype))
        elif r == len(self.blocks[b]):  # only the first block is ever short
            grown = np.zeros((min(2 * r, self.block_rows),) + self.shape, self.dtype)
            grown[:r] = self.blocks[b]
            self.blocks[b] = grown

    def row(self, k: int) -> np.ndarray:
        """Row ``k`` (a view)."""
        return self.blocks[k >> self._shift][k & (self.block_rows - 1)]

    def set(self, k: int, value: np.ndarray) -> None:
        self.blocks[k >> self._shift][k & (self.block_rows - 1)] = value

    def take(self, ids: np.ndarray) -> np.ndarray:
        """Rows ``ids`` (int64 array) as one new (len(ids), *shape) array (exact copies)."""
        if len(self.blocks) == 1:
            return self.blocks[0][ids]
        out = np.empty((len(ids),) + self.shape, self.dtype)
        b = ids >> self._shift
        for u in np.unique(b).tolist():
            m = b == u
            out[m] = self.blocks[u][ids[m] & (self.block_rows - 1)]
        return out

    def filled(self, n: int) -> Iterator[np.ndarray]:
        """The first ``n`` rows, block by block (views)."""
        for b, block in enumerate(self.blocks):
            rows = min(len(block), n - b * self.block_rows)
            if rows <= 0:
                return
            yield block[:rows]

    @property
    def nbytes(self) -> int:
        """Bytes allocated (at capacity)."""
        return sum(a.nbytes for a in self.blocks)
