"""Precision and recall of keypoint matches against the ground truth (paper §6, table 2).

A found match (a, b) is *correct* when it is a ground-truth match, or when keypoint a is
visible in frame j and keypoint b lies within ``pixel_radius`` pixels of a's projection.
precision = correct / found; recall = ground-truth matches recovered / ground-truth
matches, where a ground-truth match (a, .) counts as recovered when a has a correct found
match (found matches are one-to-one, so recall <= 1). Counts add up over pairs
(micro-average).

Wrong matches are split to show where precision goes: a *near miss* is a wrong match whose
keypoint a is visible in j and whose b lies within ``near_radius`` (default 3 x
``pixel_radius``) of a's projection, i.e. the right place but not the right keypoint. A near
miss *without counterpart* has no keypoint of j within ``pixel_radius`` of a's projection at
all (SIFT did not re-detect it), so no correct match existed for a; a metric filter whose
residual threshold is wider than the correctness radius cannot reject it. The other wrong
matches (far off, or a not visible in j) are gross errors.

``pixel_radius`` has no default here: it is the caller's setting (ContraFeat's
``model.ground_truth.pixel_radius``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from c3f_slam.matching.descriptors import mutual_nearest_neighbours
from c3f_slam.matching.filters import FilterResult, MatchFilterConfig, filter_matches
from c3f_slam.matching.ground_truth import Projection
from c3f_slam.matching.points import lift_keypoints


@dataclass
class MatchCounts:
    """Match counts of one or more frame pairs."""

    found: int = 0
    correct: int = 0
    recalled: int = 0
    ground_truth: int = 0
    pairs: int = 0
    accepted_pairs: int = 0
    near_misses: int = 0
    near_misses_without_counterpart: int = 0

    def __add__(self, other: MatchCounts) -> MatchCounts:
        return MatchCounts(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    @property
    def precision(self) -> float:
        """correct / found (NaN when nothing was found)."""
        return self.correct / self.found if self.found else float("nan")

    @property
    def recall(self) -> float:
        """recovered ground-truth matches / ground-truth matches (NaN without ground truth)."""
        return self.recalled / self.ground_truth if self.ground_truth else float("nan")

    @property
    def gross_errors(self) -> int:
        """Wrong matches that are not near misses (far off, or not visible in j)."""
        return self.found - self.correct - self.near_misses

    @property
    def near_miss_share(self) -> float:
        """Near misses / wrong matches (NaN without wrong matches)."""
        wrong = self.found - self.correct
        return self.near_misses / wrong if wrong else float("nan")

    @property
    def no_counterpart_share(self) -> float:
        """Near misses without counterpart / wrong matches (NaN without wrong matches)."""
        wrong = self.found - self.correct
        return self.near_misses_without_counterpart / wrong if wrong else float("nan")

    @property
    def near_precision(self) -> float:
        """(correct + near misses) / found: precision at the near radius (NaN when nothing was found)."""
        return (self.correct + self.near_misses) / self.found if self.found else float("nan")

    def to_array(self) -> np.ndarray:
        return np.array([getattr(self, f.name) for f in fields(self)], np.int64)

    @classmethod
    def from_array(cls, a) -> MatchCounts:
        return cls(*(int(x) for x in np.asarray(a).reshape(-1)))


def classify_matches(
    matches: np.ndarray,
    kp_j: np.ndarray,
    gt_matches: np.ndarray,
    projection: Projection,
    pixel_radius: float,
) -> np.ndarray:
    """(M,) bool: which found matches (M, 2) are correct (see the module docstring)."""
    matches = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    if len(matches) == 0:
        return np.zeros(0, bool)
    gt = {(int(a), int(b)) for a, b in np.asarray(gt_matches).reshape(-1, 2)}
    in_gt = np.array([(int(a), int(b)) in gt for a, b in matches], bool)
    a, b = matches[:, 0], matches[:, 1]
    with np.errstate(invalid="ignore"):
        dist = np.linalg.norm(np.asarray(kp_j, dtype=np.float64)[b] - projection.uv[a], axis=1)
        near = projection.visible[a] & (dist <= pixel_radius)
    return in_gt | near


def near_misses(
    matches: np.ndarray,
    kp_j: np.ndarray,
    projection: Projection,
    correct: np.ndarray,
    *,
    pixel_radius: float,
    near_radius: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Which wrong matches are near misses, and which of those had no counterpart (module docstring).

    Returns two (M,) bool arrays: near miss; near miss without any keypoint of j within
    ``pixel_radius`` of a's projection. ``near_radius`` defaults to 3 x ``pixel_radius`` (pixels).
    """
    matches = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    near_radius = 3.0 * pixel_radius if near_radius is None else float(near_radius)
    if len(matches) == 0:
        return np.zeros(0, bool), np.zeros(0, bool)
    kp_j = np.asarray(kp_j, dtype=np.float64).reshape(-1, 2)
    uv = projection.uv[matches[:, 0]]
    vis = projection.visible[matches[:, 0]]
    with np.errstate(invalid="ignore"):
        dist = np.linalg.norm(kp_j[matches[:, 1]] - uv, axis=1)
        near = ~np.asarray(correct, bool) & vis & (dist <= near_radius)
        # distance from a's projection to the closest keypoint of j (inf where none / not visible)
        closest = np.full(len(matches), np.inf)
        if near.any() and len(kp_j):
            closest[near] = np.min(np.linalg.norm(uv[near, None, :] - kp_j[None], axis=2), axis=1)
    return near, near & (closest > pixel_radius)


def evaluate_matches(
    matches: np.ndarray,
    kp_j: np.ndarray,
    gt_matches: np.ndarray,
    projection: Projection,
    *,
    pixel_radius: float,
    accepted: bool = True,
    near_radius: float | None = None,
) -> tuple[MatchCounts, np.ndarray]:
    """Counts for one pair and the (M,) correctness of its found matches."""
    matches = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    gt_matches = np.asarray(gt_matches, dtype=np.int64).reshape(-1, 2)
    correct = classify_matches(matches, kp_j, gt_matches, projection, pixel_radius)
    recalled = int(np.isin(np.unique(matches[correct, 0]), gt_matches[:, 0]).sum())
    near, lonely = near_misses(matches, kp_j, projection, correct, pixel_radius=pixel_radius, near_radius=near_radius)
    counts = MatchCounts(
        found=len(matches), correct=int(correct.sum()), recalled=recalled,
        ground_truth=len(gt_matches), pairs=1, accepted_pairs=int(accepted),
        near_misses=int(near.sum()), near_misses_without_counterpart=int(lonely.sum()),
    )
    return counts, correct


@dataclass(kw_only=True)
class PairEvaluation:
    """Matches of one pair with one descriptor, before and after the keypoint filter."""

    matches: np.ndarray
    correct: np.ndarray
    counts: MatchCounts
    kpf_matches: np.ndarray
    kpf_correct: np.ndarray
    kpf_counts: MatchCounts
    filter: FilterResult


def match_and_evaluate(
    desc_i: np.ndarray,
    desc_j: np.ndarray,
    kp_i: np.ndarray,
    kp_j: np.ndarray,
    *,
    depth_i: np.ndarray,
    depth_j: np.ndarray,
    K: np.ndarray,
    gt_matches: np.ndarray,
    projection: Projection,
    pixel_radius: float,
    metric: str = "cosine",
    ratio: float | None = None,
    filter_cfg: MatchFilterConfig | None = None,
    depth_sampling: str = "bilinear",
    near_radius: float | None = None,
) -> PairEvaluation:
    """Mutual-NN matching, then the keypoint filter (3D points from the depth maps), both scored."""
    matches, dist = mutual_nearest_neighbours(desc_i, desc_j, metric=metric, ratio=ratio)
    counts, correct = evaluate_matches(matches, kp_j, gt_matches, projection, pixel_radius=pixel_radius,
                                       near_radius=near_radius)
    pts_i = lift_keypoints(np.asarray(kp_i)[matches[:, 0]], depth_i, K, depth_sampling)
    pts_j = lift_keypoints(np.asarray(kp_j)[matches[:, 1]], depth_j, K, depth_sampling)
    result = filter_matches(pts_i, pts_j, filter_cfg, priority=dist)
    kpf = matches[result.kept]
    kpf_counts, kpf_correct = evaluate_matches(kpf, kp_j, gt_matches, projection, pixel_radius=pixel_radius,
                                               accepted=result.accepted,
                                               near_radius=near_radius)
    return PairEvaluation(matches=matches, correct=correct, counts=counts, kpf_matches=kpf, kpf_correct=kpf_correct,
                          kpf_counts=kpf_counts, filter=result)
