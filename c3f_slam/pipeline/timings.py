"""Seconds per stage of a run (summary.json's ``timings``)."""

from __future__ import annotations

import time
from collections import defaultdict


class Timings:
    """Seconds per stage (io, depth, keypoints incl. descriptors, matching, the dense fallback,
    the dense refinement of keyframe edges, posegraph, fusion)."""

    STAGES = ("io", "depth", "keypoints", "matching", "fallback", "refine", "posegraph", "fusion")

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def add(self, stage: str, t0: float) -> float:
        """Add the time since ``t0`` (``time.perf_counter()``) to ``stage``; returns now."""
        now = time.perf_counter()
        self.seconds[stage] += now - t0
        return now

    def as_dict(self, n_frames: int) -> dict:
        out = {}
        for s in self.STAGES:
            sec = self.seconds.get(s, 0.0)
            out[s] = {"seconds": sec, "ms_per_frame": 1000.0 * sec / max(n_frames, 1)}
        total = sum(self.seconds.values())
        out["total"] = {"seconds": total, "frames_per_second": n_frames / total if total > 0 else None}
        return out
