"""What one processed frame brings to a SLAM back-end (:class:`FrameInput`) and what the
back-end did with it (:class:`FrameDecision`, counted by :class:`DecisionCounts`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from c3f_slam.pipeline.frontend import FrameFeatures


@dataclass(frozen=True)
class FrameInput:
    """One processed frame, built once by the run loop: its ``features`` (stream index,
    timestamp in seconds, keypoints, descriptors, camera-frame points in metres), its
    ``depth`` (H, W) float32 metres (0 / NaN = none) and its ``rgb`` image (H, W, 3) uint8
    (None where not kept: only the dense fallback and refinement read it)."""

    features: FrameFeatures
    depth: np.ndarray
    rgb: np.ndarray | None = None

    @property
    def index(self) -> int:
        return self.features.index

    @property
    def timestamp(self) -> float:
        return self.features.timestamp


#: what a back-end did with a processed frame (:attr:`FrameDecision.kind`)
EXTENDED = "extended"  #: appended to the active fragment (linked to the previous frame)
KEYFRAME = "keyframe"  #: opened a fragment on a new keyframe with edges into the map
ATTACHED = "attached"  #: opened a fragment hung off an earlier keyframe (a revisit: no new keyframe)
LONE = "lone"  #: opened a fragment on a new keyframe without any edge (the first frame, or a new component)
LOST = "lost"  #: not placed (the odometry baseline: no match to the last tracked frame)
KINDS = (EXTENDED, KEYFRAME, ATTACHED, LONE, LOST)
OPENED = frozenset({KEYFRAME, ATTACHED, LONE})  #: the kinds that open a fragment


@dataclass(frozen=True)
class FrameDecision:
    """What a back-end did with one processed frame (stream ``index``): the ``fragment`` it
    joined (its id for fusion; -1: not placed), how (``kind``, one of :data:`KINDS`), why a
    new fragment was opened (``reason``: :mod:`c3f_slam.pipeline.fragments`' ``first`` /
    ``correspondences`` / ``overlap`` / ``size``; None when none was), and whether its match
    to the frames before a tracking break merged the two components (``rejoined``)."""

    index: int
    fragment: int
    kind: str
    reason: str | None = None
    rejoined: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown decision kind {self.kind!r} (one of {', '.join(KINDS)})")

    @property
    def opened(self) -> bool:
        """The frame opened a new fragment."""
        return self.kind in OPENED


class DecisionCounts:
    """How many frames got each decision kind, and how many re-joined a break (summary.json's
    ``frame_decisions``)."""

    def __init__(self) -> None:
        self.kinds: dict[str, int] = dict.fromkeys(KINDS, 0)
        self.rejoined = 0

    def add(self, decision: FrameDecision) -> None:
        self.kinds[decision.kind] += 1
        self.rejoined += decision.rejoined

    def as_dict(self) -> dict[str, int]:
        return {**self.kinds, "rejoined": self.rejoined}
