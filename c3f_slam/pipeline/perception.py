"""What the run loop needs of a frame before the back-end sees it: depth, keypoints and
descriptors (:class:`Perception`), computed in the loop or ahead of it (:class:`Prefetcher`).

Perception depends on the frame alone, never on the map, so the next frames can be perceived
while the back-end matches, optimises and fuses the current one: the networks run in
onnxruntime and OpenCV, which release the GIL, so a worker thread overlaps them with the
back-end's NumPy and Open3D work. The results, and their order, are those of the serial loop
(same trajectory bit for bit); a bounded queue (``prefetch`` frames) keeps memory flat. With
``workers`` > 1 several frames are perceived at once (each network run and each SIFT detection
is a call of its own on one frame, so they may overlap); frames are still read one after another
and handed to the loop in order. An error in a worker (a corrupt model, an unreadable video) is
raised in the run loop at the frame where it happened; closing the prefetcher stops and joins
the workers.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from c3f_slam.frames.stream import StreamFrame
from c3f_slam.pipeline.frontend import DepthPrediction, DepthProvider, FrameFeatures, Frontend, ModelDepth


@dataclass(frozen=True)
class PerceivedFrame:
    """A streamed frame with what perception made of it: ``depth`` (H, W) float32 metres and
    ``features`` (None for an unusable frame), ``prediction`` (model depth only: the
    network-grid depth fusion re-uses), and ``seconds`` spent per stage (io, depth, keypoints)."""

    frame: StreamFrame
    depth: np.ndarray | None = None
    features: FrameFeatures | None = None
    prediction: DepthPrediction | None = None
    seconds: dict[str, float] = field(default_factory=dict)


class Perception:
    """Depth (its provider), then keypoints and descriptors (the frontend) of a usable frame."""

    def __init__(self, depth: DepthProvider, frontend: Frontend) -> None:
        self.depth = depth
        self.frontend = frontend

    def __call__(self, frame: StreamFrame, io_seconds: float = 0.0) -> PerceivedFrame:
        """The frame perceived; ``io_seconds``: the time it took to read (recorded as ``io``)."""
        seconds = {"io": io_seconds}
        if not frame.usable:
            return PerceivedFrame(frame, seconds=seconds)
        t0 = time.perf_counter()
        if isinstance(self.depth, ModelDepth):  # the network-grid depth travels too, for fusion
            prediction = self.depth.predict(frame)
            depth = prediction.frame
        else:
            prediction, depth = None, self.depth.depth(frame)
        t1 = time.perf_counter()
        feat = self.frontend.describe(frame, self.frontend.keypoints(frame.rgb), depth)
        seconds.update(depth=t1 - t0, keypoints=time.perf_counter() - t1)
        return PerceivedFrame(frame, depth, feat, prediction, seconds)


def _timed_frames(frames: Iterable[StreamFrame]) -> Iterator[tuple[StreamFrame, float]]:
    """Each frame with the seconds it took to read."""
    it = iter(frames)
    while True:
        t0 = time.perf_counter()
        try:
            frame = next(it)
        except StopIteration:
            return
        yield frame, time.perf_counter() - t0


_DONE = object()


class Prefetcher:
    """Perceived frames of ``frames`` in order. ``prefetch`` 0: perceived in the caller's loop;
    k >= 1: by worker threads, at most k frames ahead of the caller: one thread reads the frames
    and perceives them itself (``workers`` 1) or hands each to a pool of ``workers`` threads. A
    run passes its ``frames.prefetch`` and ``frames.perception_workers``
    (:class:`c3f_slam.config.FramesConfig`, where their defaults are). Use as a context manager
    (or call :meth:`close`) so that an early exit stops the workers."""

    def __init__(self, frames: Iterable[StreamFrame], perceive: Perception, prefetch: int, workers: int) -> None:
        if prefetch < 0:
            raise ValueError(f"prefetch must be >= 0, got {prefetch}")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.frames, self.perceive, self.prefetch, self.workers = frames, perceive, prefetch, workers
        self.wait_seconds = 0.0  #: time the caller waited for the workers (prefetch >= 1)
        self._queue: queue.Queue | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pool: ThreadPoolExecutor | None = None

    def __enter__(self) -> Prefetcher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[PerceivedFrame]:
        if self.prefetch == 0:
            for frame, io in _timed_frames(self.frames):
                yield self.perceive(frame, io)
            return
        yield from self._threaded()

    def _threaded(self) -> Iterator[PerceivedFrame]:
        self._queue = queue.Queue(maxsize=self.prefetch)
        self._thread = threading.Thread(target=self._work, name="c3f-perception", daemon=True)
        self._thread.start()
        while True:
            t0 = time.perf_counter()
            item = self._queue.get()
            self.wait_seconds += time.perf_counter() - t0
            if item is _DONE:
                return
            if isinstance(item, Future):
                t0 = time.perf_counter()
                exc = item.exception()
                self.wait_seconds += time.perf_counter() - t0
                item = exc if exc is not None else item.result()
            if isinstance(item, BaseException):
                raise item
            yield item

    def _work(self) -> None:
        """The reader: frames perceived (or, with a pool, their futures) into the queue, in order,
        until the end, an error or :meth:`close`."""
        if self.workers > 1:
            self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="c3f-perception")
        try:
            for frame, io in _timed_frames(self.frames):
                item = self.perceive(frame, io) if self._pool is None else self._pool.submit(self.perceive, frame, io)
                if not self._put(item):
                    return
            self._put(_DONE)
        except BaseException as exc:  # handed to the caller, raised at this frame
            self._put(exc)

    def _put(self, item: object) -> bool:
        """Queue ``item`` unless closed meanwhile (returns False then)."""
        assert self._queue is not None
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def close(self) -> None:
        """Stop the workers (each finishes the frame it is on; queued frames are dropped) and
        wait for them."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
