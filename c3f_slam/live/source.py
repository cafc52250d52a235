"""Frames delivered as a capture delivers them, and the rule that keeps a live run from falling behind.

:class:`PacedSource` reads a :class:`~c3f_slam.frames.stream.FrameStream` on a thread of its own
and hands each frame over at the moment the source would deliver it: a video at its own frame
rate, a sequence folder at its poses.txt timestamps (else ``rate``), a capture device as it
comes; ``rate`` (frames per second) overrides the first two, ``as_fast_as_possible`` paces
nothing. The hand-over is one slot (:class:`LatestFrame`): **the newest frame wins**. When the
run is still busy with an earlier frame as a new one arrives, the frame waiting in the slot is
dropped and counted; nothing queues, so the delay cannot grow and memory stays flat however
long the recording. The run judges the frames it takes (black, saturated, the quality gate),
in order, on its own side.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

from c3f_core.errors import InputError
from c3f_slam.frames.stream import FrameStream, RawFrame, StreamFrame

_END = object()


@dataclass(frozen=True)
class Delivered:
    """A frame as the source delivered it: ``captured_at`` Unix seconds (``time.time()``)."""

    item: RawFrame | StreamFrame
    captured_at: float

    @property
    def index(self) -> int:
        return self.item.index


class LatestFrame:
    """A one-frame slot between a producer and a consumer: :meth:`put` replaces a frame still
    waiting (returned, to be counted as dropped); :meth:`take` waits for one."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: object | None = None

    def put(self, item: object) -> object | None:
        """Leave ``item`` in the slot; returns the frame it replaced (None when the slot was empty)."""
        with self._cond:
            old, self._item = self._item, item
            self._cond.notify()
        return old

    def take(self, timeout: float | None = None) -> object | None:
        """The waiting item (the slot is emptied); None after ``timeout`` seconds without one."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._item is not None, timeout):
                return None
            item, self._item = self._item, None
            return item

    def finish(self, item: object, stop: threading.Event) -> None:
        """Leave a last item (the end, or an error) once the frame waiting was taken (it is
        kept), unless ``stop`` is set meanwhile."""
        with self._cond:
            while self._item is not None and not stop.is_set():
                self._cond.wait(0.1)
            self._item = item
            self._cond.notify()


class PacedSource:
    """The frames of ``stream`` as a live capture: paced, newest frame wins (see the module notes).

    Iterate it for the frames the run takes (judged, in order); :meth:`take_dropped` returns the
    stream indices dropped since it was last called, :attr:`delivered` / :attr:`dropped` count
    them, :meth:`captured_at` gives a taken frame's delivery time. ``rate`` frames per second
    (None: the source's own), ``as_fast_as_possible``: no pacing; ``drop`` False: a frame waits
    until the run took the one before (nothing dropped; the run falls behind the source instead,
    and the delay grows: a recording reviewed whole)."""

    def __init__(self, stream: FrameStream, rate: float | None = None, as_fast_as_possible: bool = False,
                 drop: bool = True) -> None:
        if rate is not None and not rate > 0:
            raise InputError(f"--rate must be > 0 frames per second, got {rate}")
        self.stream = stream
        self.rate = rate
        self.as_fast_as_possible = as_fast_as_possible
        self.drop = drop
        self.delivered = 0
        self.dropped = 0
        self.first_delivery: float | None = None
        self.last_delivery: float | None = None
        self._slot = LatestFrame()
        self._stop = threading.Event()
        self._drops: list[int] = []
        self._lock = threading.Lock()
        self._captured: dict[int, float] = {}
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ pacing
    def describe(self) -> dict:
        """{kind, name, rate_fps}: what the page and live.json say about the source."""
        s = self.stream
        kind = "device" if s.device is not None else "video" if s.is_video else "folder"
        rate = None if self.as_fast_as_possible else self.source_rate()
        return {"kind": kind, "name": str(s.source), "rate_fps": rate,
                "paced": not self.as_fast_as_possible and s.device is None, "drops_frames": self.drop}

    def source_rate(self) -> float | None:
        """Frames per second the source delivers (None: its timestamps, or as they come)."""
        s = self.stream
        if self.rate is not None:
            return self.rate
        if s.device is not None:
            return getattr(s, "video_fps", None)
        if s.is_video:
            return s.video_fps / s.step
        return None if s.sequence is not None and s.sequence.timestamps is not None else 30.0 / s.step

    def _due(self, n: int, item: RawFrame | StreamFrame, t0: float, stamp0: float) -> float | None:
        """Monotonic time at which the n-th frame read is delivered (None: now)."""
        s = self.stream
        if self.as_fast_as_possible or s.device is not None:
            return None
        rate = self.source_rate()
        if rate is not None:
            return t0 + n / rate
        return t0 + (item.timestamp - stamp0)

    def _read(self) -> None:
        """The reader thread: frames into the slot at their time until the end, an error or close."""
        try:
            t0, stamp0 = 0.0, None
            for n, item in enumerate(self.stream.read()):
                if stamp0 is None:  # the source's clock starts with its first frame
                    t0, stamp0 = time.monotonic(), item.timestamp
                due = self._due(n, item, t0, stamp0)
                if due is not None:
                    while not self._stop.is_set() and time.monotonic() < due:
                        self._stop.wait(min(0.05, max(0.0, due - time.monotonic())))
                if self._stop.is_set():
                    return
                now = time.time()
                with self._lock:
                    self._captured[item.index] = now
                    self.delivered += 1
                    self.first_delivery = self.first_delivery or now
                    self.last_delivery = now
                if not self.drop:
                    self._slot.finish(Delivered(item, now), self._stop)
                    continue
                old = self._slot.put(Delivered(item, now))
                if old is not None:
                    with self._lock:
                        self.dropped += 1
                        self._drops.append(old.index)
                        self._captured.pop(old.index, None)
            self._slot.finish(_END, self._stop)
        except BaseException as exc:  # raised in the run loop
            self._slot.finish(exc, self._stop)

    # ------------------------------------------------------------------ the run's side
    def __iter__(self) -> Iterator[StreamFrame]:
        if self.stream.quality is not None:
            self.stream.quality.reset()
        self._stop.clear()
        self._thread = threading.Thread(target=self._read, name="c3f-live-source", daemon=True)
        self._thread.start()
        try:
            while True:
                got = self._slot.take(timeout=0.2)
                if got is None:
                    continue
                if got is _END:
                    return
                if isinstance(got, BaseException):
                    raise got
                assert isinstance(got, Delivered)
                yield self.stream.judge(got.item)
        finally:
            self.close()

    def take_dropped(self) -> list[int]:
        """Stream indices of the frames dropped since the last call, in order."""
        with self._lock:
            out, self._drops = self._drops, []
        return out

    def captured_at(self, index: int) -> float | None:
        """When frame ``index`` was delivered (Unix seconds; forgotten once asked)."""
        with self._lock:
            return self._captured.pop(index, None)

    def delivery_rate(self) -> float | None:
        """Frames per second delivered so far."""
        with self._lock:
            if self.first_delivery is None or self.last_delivery is None or self.delivered < 2:
                return None
            span = self.last_delivery - self.first_delivery
            return (self.delivered - 1) / span if span > 0 else None

    def close(self) -> None:
        """Stop the reader (it ends the frame it is on)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        self._thread = None
