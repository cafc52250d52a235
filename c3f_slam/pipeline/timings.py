"""Seconds per stage of a run (summary.json's ``timings``): wall-clock time measured by
:meth:`Timings.stage` (a block) or :meth:`Timings.timed` (each step of an iterator), or
measured elsewhere and added (:meth:`Timings.add`: the perception worker's stages)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterable, Iterator
from contextlib import contextmanager


class Timings:
    """Seconds per stage (io, depth, keypoints incl. descriptors, the run loop's wait for them,
    matching, the dense fallback, the dense refinement of keyframe edges, posegraph, fusion).
    Stages of one thread are timed one after another, never nested (a nested block would be
    counted twice). When perception runs ahead in a worker thread (``frames.prefetch``), io,
    depth and keypoints overlap the others, so the stages add up to more than the run's
    wall-clock time; ``wall_seconds`` (set by the run loop) is that time, and ``total``
    reports it."""

    STAGES = ("io", "depth", "keypoints", "wait", "matching", "fallback", "refine", "posegraph", "fusion")

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.wall_seconds: float | None = None  #: the frame loop and the end of the run, wall-clock

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` measured elsewhere to stage ``name``."""
        self.seconds[name] += seconds

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Add the wall-clock seconds of the ``with`` block to stage ``name`` (also when it raises)."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - t0

    def timed(self, name: str, items: Iterable) -> Iterator:
        """``items`` one by one, the time to get each added to stage ``name`` (e.g. reading frames)."""
        it = iter(items)
        while True:
            with self.stage(name):
                try:
                    item = next(it)
                except StopIteration:
                    return
            yield item

    def as_dict(self, n_frames: int) -> dict:
        out = {}
        for s in self.STAGES:
            sec = self.seconds.get(s, 0.0)
            out[s] = {"seconds": sec, "ms_per_frame": 1000.0 * sec / max(n_frames, 1)}
        stages = sum(self.seconds.values())
        total = stages if self.wall_seconds is None else self.wall_seconds
        out["total"] = {"seconds": total, "frames_per_second": n_frames / total if total > 0 else None,
                        "stages_seconds": stages}
        return out
