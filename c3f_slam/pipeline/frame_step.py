"""What one processed frame brings to a SLAM back-end (:class:`FrameInput`)."""

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
