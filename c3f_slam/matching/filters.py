"""Keypoint correspondence filter and surface area filter (BundleFusion, Dai et al. 2017).

Given candidate correspondences as 3D points (camera frames of i and j, metres, from the
depth maps), :func:`filter_matches` keeps a geometrically consistent subset and the rigid
transform T_ij (p_i ~ T_ij p_j):

1. drop candidates without a 3D point (no depth);
2. pairwise-distance consistency: a rigid motion keeps |p_a - p_b| in both frames, so
   candidates a, b are inconsistent when the two distances differ by more than
   ``pairwise_tolerance + pairwise_relative_tolerance * max(distance)``; the candidate with
   the most inconsistencies is dropped until none is left;
3. Kabsch fit; the candidate with the worst residual (relative to its bound) is dropped and the
   fit redone (:func:`drop_worst_residuals`, from updated sums) until every residual is below
   its bound, ``max_residual + residual_relative_tolerance * z`` (z: the point's depth in frame
   i; predicted depth errs in proportion to the depth, so a run on model depth takes 3 % and
   one on depth files 0); the survivors are fitted once more from their points; with a
   depth-relative bound and ``weighted_fit`` the survivors' transform is then refitted with
   weights 1 / bound^2 (the inverse variance of that error: near points count more);
4. accept only with >= ``min_matches`` survivors and a condition number below
   ``max_condition`` (as BundleFusion: the largest of the ratios sigma_1/sigma_2 of the
   Kabsch cross-covariance and lambda_1/lambda_2 of each point set's covariance; near-
   collinear sets have a huge ratio, coplanar sets are fine);
5. surface area filter: the survivors of each frame are projected onto their two principal
   axes and the area of their minimum-area bounding rectangle is measured; the set is
   rejected when both frames' areas are below ``min_area`` (m^2).

All lengths are metres; :class:`~c3f_slam.config.MatchFilterConfig` holds the thresholds (its
defaults are the colon's; the room preset's: :mod:`c3f_slam.config.presets`), and
:meth:`~c3f_slam.config.MatchFilterConfig.scaled` rescales them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from c3f_slam.config import MatchFilterConfig
from c3f_slam.matching.kabsch import kabsch, residuals, rotation_from_covariance


@dataclass(frozen=True, kw_only=True)
class FilterResult:
    """Outcome of :func:`filter_matches`.

    Attributes:
        inlier_indices: (K,) int64 indices into the candidate arrays that survived (also
            when the set is rejected, for diagnostics; use :attr:`kept` for the output).
        T_ij: 4x4 rigid transform (p_i ~ T_ij p_j) fitted to the survivors, or None.
        residuals: (K,) metres, |T_ij p_j - p_i| of the survivors (after the weighted refit,
            a survivor may exceed its bound by a little).
        condition_number: condition number of the fit (inf when undefined).
        area: m^2, the larger of the two frames' spanned areas (0 when not computed).
        accepted: the set passed every test.
        reason: why it was rejected ("" when accepted).
    """

    inlier_indices: np.ndarray
    T_ij: np.ndarray | None
    residuals: np.ndarray
    condition_number: float
    area: float
    accepted: bool
    reason: str

    @property
    def kept(self) -> np.ndarray:
        """Indices of the accepted correspondences (empty when the set is rejected)."""
        return self.inlier_indices if self.accepted else np.zeros(0, np.int64)


def _ratio(values: np.ndarray) -> float:
    """Largest over second-largest of non-negative values (inf when the second is ~0)."""
    v = np.sort(np.abs(values))[::-1]
    if not np.all(np.isfinite(v)) or v[0] <= 0:
        return float("inf")
    return float(v[0] / v[1]) if v[1] > v[0] * 1e-12 else float("inf")


def condition_number(pts_i: np.ndarray, pts_j: np.ndarray, cross_singular_values: np.ndarray) -> float:
    """BundleFusion's check: max of sigma1/sigma2 (cross-covariance) and lambda1/lambda2 of each set."""
    out = _ratio(cross_singular_values)
    for p in (pts_i, pts_j):
        c = p - p.mean(axis=0)
        out = max(out, _ratio(np.linalg.eigvalsh(c.T @ c / len(p))))
    return out


def spanned_area(points: np.ndarray) -> float:
    """m^2: area of the minimum-area rectangle around the points on their principal plane."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) < 3:
        return 0.0
    c = p - p.mean(axis=0)
    _, vecs = np.linalg.eigh(c.T @ c)
    plane = c @ vecs[:, [2, 1]]  # the two major principal axes
    (_, _), (w, h), _ = cv2.minAreaRect(plane.astype(np.float32))
    return float(w) * float(h)


def pairwise_distances(points: np.ndarray) -> np.ndarray:
    """(N, N) Euclidean distances of (N, 3) points, the same bits as
    ``np.linalg.norm(p[:, None] - p[None], axis=-1)`` at a fraction of its cost (one coordinate
    at a time instead of a reduction over a short last axis, in two preallocated arrays)."""
    n = len(points)
    total = np.empty((n, n), np.result_type(points.dtype, np.float32))
    buf = np.empty_like(total)
    for k in range(points.shape[1]):
        out = total if k == 0 else buf
        np.subtract.outer(points[:, k], points[:, k], out=out)
        np.multiply(out, out, out=out)
        if k:
            np.add(total, buf, out=total)
    return np.sqrt(total, out=total)


def consistent_subset(
    pts_i: np.ndarray, pts_j: np.ndarray, tolerance: float, relative_tolerance: float = 0.0,
    priority: np.ndarray | None = None,
) -> np.ndarray:
    """(K,) indices of a pairwise-distance consistent subset (greedy, most-inconsistent first).

    ``priority``: optional (N,) cost, lower = better (e.g. descriptor distance); among
    candidates with equally many inconsistencies the highest cost (default: the highest
    index) goes first.
    """
    n = len(pts_i)
    if n < 2:
        return np.arange(n)
    d_i, d_j = pairwise_distances(pts_i), pairwise_distances(pts_j)
    # |d_i - d_j| > tolerance + relative_tolerance * max(d_i, d_j), in place (the same bits)
    bound = np.maximum(d_i, d_j)
    bound *= relative_tolerance
    bound += tolerance
    np.subtract(d_i, d_j, out=d_i)
    bad = np.abs(d_i, out=d_i) > bound
    count = bad.sum(axis=1).astype(np.int64)
    alive = np.ones(n, bool)
    tie = np.arange(n) if priority is None else np.argsort(np.argsort(np.asarray(priority, dtype=np.float64)))
    # key = count * (n + 1) + rank: most inconsistencies first, then the worst priority
    while True:
        key = np.where(alive, count * (n + 1) + tie, -1)
        worst = int(np.argmax(key))
        if not alive[worst] or count[worst] == 0:
            break
        alive[worst] = False
        count -= bad[:, worst]
    return np.flatnonzero(alive)


def drop_worst_residuals(
    src: np.ndarray, dst: np.ndarray, bound: np.ndarray, min_matches: int
) -> tuple[np.ndarray, bool]:
    """The residual loop of :func:`filter_matches`: fit (Kabsch, ``dst ~ T src``), drop the
    point with the largest residual relative to its ``bound`` (metres; the first of equal
    ones) while it exceeds it, refit. Returns the (K,) indices of the points kept and whether
    every residual is within its bound; False when fewer than ``min_matches`` would be left
    (the indices are then the set before that drop).

    Each refit updates the sums of the points it keeps (centred on the first mean) instead of
    fitting again from the points, a constant cost per dropped point; the caller fits the
    survivors once more with :func:`kabsch`, so its transform is the plain fit of that set.
    """
    n = len(src)
    p = src - src.mean(axis=0)
    q = dst - dst.mean(axis=0)
    s_p, s_q, s_pq = p.sum(axis=0), q.sum(axis=0), p.T @ q
    res, ratio = np.empty(n), np.empty(n)
    alive = np.ones(n, bool)
    m = n
    while True:
        c_p, c_q = s_p / m, s_q / m
        R, _ = rotation_from_covariance(s_pq / m - np.outer(c_p, c_q))
        diff = p @ R.T
        diff += c_q - R @ c_p
        diff -= q
        np.einsum("ij,ij->i", diff, diff, out=res)
        np.sqrt(res, out=res)
        np.divide(res, bound, out=ratio)
        ratio[~alive] = -np.inf
        worst = int(np.argmax(ratio))
        if res[worst] <= bound[worst]:
            return np.flatnonzero(alive), True
        if m - 1 < min_matches:
            return np.flatnonzero(alive), False
        alive[worst] = False
        m -= 1
        s_p -= p[worst]
        s_q -= q[worst]
        s_pq -= np.outer(p[worst], q[worst])


def filter_matches(
    pts_i: np.ndarray,
    pts_j: np.ndarray,
    cfg: MatchFilterConfig | None = None,
    priority: np.ndarray | None = None,
) -> FilterResult:
    """Keypoint correspondence filter + surface area filter on candidate 3D correspondences.

    Args:
        pts_i, pts_j: (N, 3) camera-frame points of the candidates in frames i and j
            (metres; NaN rows = no depth, dropped).
        cfg: thresholds (default: the colon's, :class:`MatchFilterConfig`).
        priority: optional (N,) cost, lower = better (descriptor distance); breaks ties and,
            with ``cfg.max_matches``, chooses which candidates are considered.
    """
    cfg = cfg or MatchFilterConfig()
    pts_i = np.asarray(pts_i, dtype=np.float64).reshape(-1, 3)
    pts_j = np.asarray(pts_j, dtype=np.float64).reshape(-1, 3)
    if pts_i.shape != pts_j.shape:
        raise ValueError(f"pts_i and pts_j must have the same shape, got {pts_i.shape} and {pts_j.shape}")

    def reject(idx: np.ndarray, reason: str, T=None, res=None, cn=float("inf"), area=0.0) -> FilterResult:
        return FilterResult(inlier_indices=idx, T_ij=T, residuals=np.zeros(len(idx)) if res is None else res,
                            condition_number=cn, area=area, accepted=False, reason=reason)

    idx = np.flatnonzero(np.isfinite(pts_i).all(1) & np.isfinite(pts_j).all(1))
    if priority is not None:
        priority = np.asarray(priority, dtype=np.float64).reshape(-1)
        idx = idx[np.argsort(priority[idx], kind="stable")]
    if cfg.max_matches is not None:
        idx = idx[: cfg.max_matches]
    if len(idx) < cfg.min_matches:
        return reject(idx, f"too few matches with depth ({len(idx)} < {cfg.min_matches})")
    if cfg.use_pairwise:
        sub = consistent_subset(
            pts_i[idx], pts_j[idx], cfg.pairwise_tolerance, cfg.pairwise_relative_tolerance,
            None if priority is None else priority[idx],
        )
        idx = idx[sub]
        if len(idx) < cfg.min_matches:
            return reject(idx, f"too few pairwise-consistent matches ({len(idx)} < {cfg.min_matches})")
    # Kabsch, dropping the worst residual (over its bound) until all are below their bounds
    bound = cfg.max_residual + cfg.residual_share * np.abs(pts_i[:, 2])
    kept, within = drop_worst_residuals(pts_j[idx], pts_i[idx], bound[idx], cfg.min_matches)
    idx = idx[kept]
    T, sv = kabsch(pts_j[idx], pts_i[idx], return_singular_values=True)  # the survivors' fit, exactly
    res = residuals(T, pts_j[idx], pts_i[idx])
    if not within:
        return reject(idx, f"too few matches under the residual threshold (< {cfg.min_matches})", T, res)
    if cfg.weighted_fit and cfg.residual_share > 0:  # inverse variance of a depth-proportional error
        T = kabsch(pts_j[idx], pts_i[idx], weights=1.0 / bound[idx] ** 2)
        res = residuals(T, pts_j[idx], pts_i[idx])
    cn = condition_number(pts_i[idx], pts_j[idx], sv)
    if not cn < cfg.max_condition:
        return reject(idx, f"degenerate configuration (condition number {cn:.3g} >= {cfg.max_condition:g})", T, res, cn)
    area = max(spanned_area(pts_i[idx]), spanned_area(pts_j[idx]))
    if cfg.use_area and area < cfg.min_area:
        return reject(idx, f"surface area too small ({area:.3g} m^2 < {cfg.min_area:g} m^2)", T, res, cn, area)
    order = np.argsort(idx, kind="stable")
    return FilterResult(inlier_indices=idx[order], T_ij=T, residuals=res[order], condition_number=cn, area=area,
                        accepted=True, reason="")


__all__ = [
    "FilterResult", "MatchFilterConfig", "condition_number", "consistent_subset", "drop_worst_residuals",
    "filter_matches", "spanned_area",
]
