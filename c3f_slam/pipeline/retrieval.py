"""Keyframe candidates for global matching (docs/design.md, Scaling to long sequences).

The paper matches each new keyframe against **all** earlier keyframes: O(#keyframes) pair
matches per keyframe, quadratic over a sequence (a 20,000-frame stream makes thousands of
keyframes). Here a new keyframe is matched against a bounded candidate set instead:

- **recent**: the ``recent`` most recent keyframes (the odometry predecessor and its
  neighbours in time);
- **spatial**: when the new keyframe has a pose estimate through the odometry link, the
  keyframes of its predecessor's component (the main one while tracking) whose camera centre
  lies within ``spatial_radius`` metres of the estimate and whose viewing direction (camera
  z axis) is within ``spatial_max_angle_deg`` of it, nearest first, at most ``spatial``;
- **appearance**: the rest, up to ``max_candidates``, by a global appearance score over *all*
  keyframes (one matrix-vector product), in any component; this is what re-localisation
  (no odometry link after lost tracking) and loops across components rely on.

While the map has at most ``max_candidates`` keyframes, all of them are candidates (the
paper's rule, so small maps behave exactly as before); ``max_candidates=None`` always
matches all keyframes.

Global appearance descriptor (:func:`global_descriptor`): the mean of the keyframe's local
descriptors, each first mapped to unit L2 norm (uint8 SIFT through the Hellinger / RootSIFT
map sqrt(d / sum(d)), float16 ContraFeat descriptors are unit-norm already), stored as
float32 (D values per keyframe, 512 bytes for 128-D). Scores are cosine similarities after
subtracting the mean of all keyframes' global descriptors (:class:`AppearanceIndex`).
Why this and not a bag of words: it needs no vocabulary (a learned one needs training data
the runtime does not have; a fixed random codebook quantises 128-D descriptors that fill a
narrow cone into few, arbitrary cells), it is the same code for both descriptor kinds, costs
D floats per keyframe and one (N, D) @ (D,) product per query. The mean alone is dominated by
what every colon frame shares (the first moment of the descriptor distribution); centring
on the map's mean removes that common part, so the score ranks by what differs between
places. It is a coarse retrieval step: geometry (the match filters) decides, and the recent
and spatial candidates cover the usual neighbours.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from c3f_slam.config import CandidateConfig
from c3f_slam.posegraph.blocks import BlockRows


def global_descriptor(descriptors: np.ndarray) -> np.ndarray:
    """(D,) float32 unit-norm appearance descriptor of one frame's (N, D) local descriptors
    (zeros when there are none). Integer descriptors (uint8 SIFT) are treated as histograms
    (Hellinger map), float ones are L2-normalised."""
    d = np.asarray(descriptors)
    if d.ndim != 2:
        raise ValueError(f"descriptors must be (N, D), got {d.shape}")
    x = d.astype(np.float32)
    if len(x) == 0:
        return np.zeros(d.shape[1], np.float32)
    if np.issubdtype(d.dtype, np.integer):
        x = np.sqrt(np.maximum(x, 0.0) / np.maximum(x.sum(axis=1, keepdims=True), 1e-12))
    else:
        x = x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)
    g = x.mean(axis=0)
    n = float(np.linalg.norm(g))
    return (g / n if n > 0 else g).astype(np.float32)


#: rows per matrix-vector block: OpenBLAS runs a (N, 128) float32 product on several threads
#: from about 4,000 rows on, which on a busy 2-core machine took ~8 ms instead of ~0.1 ms per
#: product (thread wake-ups; measured with OpenBLAS 0.3.31), so the scores are computed in
#: blocks that stay single-threaded.
_BLOCK = 2048


def _matvec(G: np.ndarray, v: np.ndarray) -> np.ndarray:
    """G @ v in row blocks of :data:`_BLOCK` (each below OpenBLAS's threading threshold)."""
    if len(G) <= _BLOCK:
        return G @ v
    return np.concatenate([G[a:a + _BLOCK] @ v for a in range(0, len(G), _BLOCK)])


#: rows per storage block of :class:`AppearanceIndex` (:class:`c3f_slam.posegraph.blocks.BlockRows`);
#: equal to :data:`_BLOCK`, so the products are the same as on one matrix
_STORE_ROWS = 2048


class AppearanceIndex:
    """Global descriptors of all keyframes (a growable (N, D) float32 matrix, stored in
    blocks of :data:`_STORE_ROWS` rows) and their centred-cosine scores against a query."""

    def __init__(self) -> None:
        self._rows: BlockRows | None = None  # created with the first descriptor (its length D)
        self._sq = np.zeros(64, np.float32)  # squared norms of the rows (1, or 0 when empty)
        self._n = 0
        self._sum: np.ndarray | None = None

    def __len__(self) -> int:
        return self._n

    @property
    def nbytes(self) -> int:
        return 0 if self._rows is None else self._n * self._rows.shape[0] * 4

    def add(self, g: np.ndarray) -> int:
        """Append a keyframe's global descriptor; returns its index."""
        g = np.asarray(g, dtype=np.float32).reshape(-1)
        if self._rows is None:
            self._rows = BlockRows((len(g),), np.float32, _STORE_ROWS, capacity=64)
            self._sum = np.zeros(len(g), np.float64)
        D = self._rows.shape[0]
        if len(g) != D:
            raise ValueError(f"descriptor has {len(g)} values, the index {D}")
        self._rows.ensure(self._n)
        if self._n == len(self._sq):
            self._sq = np.concatenate([self._sq, np.zeros_like(self._sq)])
        self._rows.set(self._n, g)
        self._sq[self._n] = float(g @ g)
        assert self._sum is not None
        self._sum += g
        self._n += 1
        return self._n - 1

    def scores(self, g: np.ndarray) -> np.ndarray:
        """(N,) cosine similarity of (G_k - mu) and (g - mu), mu the mean of the N stored
        descriptors; vectorised (two matrix-vector products, no (N, D) temporary)."""
        if self._n == 0 or self._sum is None:
            return np.zeros(0, np.float32)
        q = np.asarray(g, dtype=np.float32).reshape(-1)
        mu = (self._sum / self._n).astype(np.float32)
        Gq, Gmu = self._matvec(q), self._matvec(mu)
        G2 = self._sq[: self._n]
        mq, mm = float(mu @ q), float(mu @ mu)
        dot = Gq - Gmu - mq + mm
        norm_k = np.sqrt(np.maximum(G2 - 2.0 * Gmu + mm, 0.0))
        norm_q = np.sqrt(max(float(q @ q) - 2.0 * mq + mm, 0.0))
        return dot / np.maximum(norm_k * norm_q, 1e-12)

    def _matvec(self, v: np.ndarray) -> np.ndarray:
        """(N,) products of the stored rows with ``v``, block by block (:func:`_matvec`)."""
        assert self._rows is not None
        parts = [_matvec(B, v) for B in self._rows.filled(self._n)]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)


@dataclass
class Candidates:
    """The keyframes to match (ascending ids) and how many came from each source."""

    ids: list[int]
    recent: int = 0
    spatial: int = 0
    appearance: int = 0
    all: bool = False
    sources: dict[int, str] = field(default_factory=dict)


def spatial_neighbours(
    poses: np.ndarray,
    T_query: np.ndarray,
    radius: float,
    max_angle_deg: float,
    k: int,
    *,
    accept: Callable[[int], bool] | None = None,
    exclude: set[int] | frozenset[int] = frozenset(),
) -> list[int]:
    """Up to ``k`` nodes of ``poses`` ((N, 4, 4) camera-to-world) whose camera centre lies
    within ``radius`` of ``T_query``'s and whose z axis is within ``max_angle_deg`` of its,
    nearest first, skipping ``exclude`` and nodes ``accept`` rejects (vectorised distances;
    ``accept`` is called on the nearest ones only)."""
    if k <= 0 or len(poses) == 0:
        return []
    T = np.asarray(T_query, dtype=np.float64)
    d2 = np.sum((poses[:, :3, 3] - T[:3, 3]) ** 2, axis=1)
    cos = np.sum(poses[:, :3, 2] * T[:3, 2], axis=1)  # not a BLAS product (see _BLOCK)
    ok = (d2 <= radius * radius) & (cos >= np.cos(np.deg2rad(max_angle_deg)))
    idx = np.flatnonzero(ok)
    out: list[int] = []
    for v in idx[np.argsort(d2[idx], kind="stable")].tolist():
        if v in exclude or (accept is not None and not accept(v)):
            continue
        out.append(v)
        if len(out) == k:
            break
    return out


def select_candidates(
    n_keyframes: int,
    cfg: CandidateConfig,
    *,
    appearance: np.ndarray | None = None,
    poses: np.ndarray | None = None,
    T_query: np.ndarray | None = None,
    accept: Callable[[int], bool] | None = None,
) -> Candidates:
    """Candidates among keyframes 0..n_keyframes-1 for a new keyframe.

    ``appearance``: (n_keyframes,) scores (higher = more alike; :meth:`AppearanceIndex.scores`);
    ``poses`` (n_keyframes, 4, 4) and ``T_query``: the keyframes' and the new keyframe's
    camera-to-world poses for the spatial candidates (skipped when ``T_query`` is None);
    ``accept(k)``: whether keyframe k may be a spatial candidate (same component).
    At most ``cfg.max_candidates``; all keyframes while there are no more than that.
    """
    n = int(n_keyframes)
    cap = cfg.max_candidates
    if cap is None or n <= cap:
        return Candidates(list(range(n)), all=True, sources={k: "all" for k in range(n)})
    chosen: dict[int, str] = {}
    for k in range(n - 1, max(n - 1 - min(cfg.recent, cap), -1), -1):
        chosen[k] = "recent"
    if T_query is not None and poses is not None and len(chosen) < cap:
        room = min(cfg.spatial, cap - len(chosen))
        for k in spatial_neighbours(poses[:n], T_query, cfg.spatial_radius, cfg.spatial_max_angle_deg, room,
                                    accept=accept, exclude=set(chosen)):
            chosen[k] = "spatial"
    room = cap - len(chosen)
    if appearance is not None and room > 0:
        s = np.array(appearance[:n], dtype=np.float64)
        if len(s) != n:
            raise ValueError(f"{len(s)} appearance scores for {n} keyframes")
        s[list(chosen)] = -np.inf
        s[np.isnan(s)] = -np.inf  # NaN never wins
        m = min(room, n - len(chosen))
        top = np.argpartition(-s, m - 1)[:m] if m > 0 else np.zeros(0, np.int64)
        for k in top[np.argsort(-s[top], kind="stable")].tolist():
            if np.isfinite(s[k]):
                chosen[k] = "appearance"
    counts = {src: sum(1 for v in chosen.values() if v == src) for src in ("recent", "spatial", "appearance")}
    return Candidates(sorted(chosen), all=False, sources=chosen, **counts)


class KeyframeRetrieval:
    """Appearance index plus candidate selection for :class:`c3f_slam.pipeline.slam.FragmentSlam`."""

    def __init__(self, cfg: CandidateConfig | None = None) -> None:
        self.cfg = cfg or CandidateConfig()
        self.index = AppearanceIndex()

    def __len__(self) -> int:
        return len(self.index)

    def candidates(
        self,
        g: np.ndarray,
        poses: np.ndarray | None = None,
        T_query: np.ndarray | None = None,
        accept: Callable[[int], bool] | None = None,
    ) -> Candidates:
        """Candidates for a new keyframe with global descriptor ``g`` (before :meth:`add`)."""
        n = len(self.index)
        cap = self.cfg.max_candidates
        scores = None if cap is None or n <= cap else self.index.scores(g)
        return select_candidates(n, self.cfg, appearance=scores, poses=poses, T_query=T_query, accept=accept)

    def add(self, g: np.ndarray) -> int:
        return self.index.add(g)
