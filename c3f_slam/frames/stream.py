"""Frame streaming: one frame at a time from a sequence folder or a video file.

A 54,000-frame colonoscopy video never has to fit in memory: :class:`FrameStream` reads
lazily (OpenCV ``VideoCapture`` for videos, :class:`c3f_slam.io.Sequence` for the project
layout) and yields :class:`StreamFrame` items (index, timestamp, RGB uint8, depth in metres or
None, status). Black frames (mean luma < ``black_threshold``) and saturated frames (at least
``saturated_share`` of pixels with luma >= ``saturated_threshold``) are flagged, not
dropped, so the runtime can skip and report them; so are, with a :attr:`FrameStream.quality`
gate, frames that carry nothing (blurred, dark, washed out, covered, repeated:
:mod:`c3f_slam.frames.quality`), their cause as the status. A frame that cannot be read (a missing or
corrupt image file, a video frame that does not decode) is yielded with status
``unreadable`` and no pixels (``error`` says why); the runtime skips and counts those up to a
limit. A video that ends before the frame count its container declares (damaged or cut
files) is recorded in :attr:`FrameStream.truncation` after iteration.

Timestamps (seconds): a video gives index / fps (the container's fps, else ``fps``); a sequence
folder gives the poses.txt timestamps when present, else index / ``fps`` (``fps`` None: the
frame index itself).

Intrinsics: a video's come from ``camera`` (a camera.json, default the one beside the video, or a
:class:`c3f_slam.camera.intrinsics.FovGuess`), a folder's from its camera.json. A distorted camera (a
``fisheye`` or ``omnidirectional`` model, or pinhole distortion coefficients) has its frames undistorted to a pinhole
camera of the same size (:class:`c3f_slam.camera.calibration.Undistortion`); :attr:`FrameStream.camera`
is then that pinhole camera; :attr:`FrameStream.camera_file` is the camera.json read (None for a
camera given as an object or guessed) and :attr:`FrameStream.camera_source` says where the
intrinsics came from.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.calibration import Undistortion
from c3f_slam.camera.intrinsics import FovGuess, PinholeCamera
from c3f_slam.camera.omnidirectional import OmniCamera
from c3f_slam.frames.quality import FrameQualityGate
from c3f_slam.io.sequence import Sequence, read_depth_png, read_rgb

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".mpg", ".mpeg", ".m4v", ".wmv", ".webm")

OK, BLACK, SATURATED, UNREADABLE = "ok", "black", "saturated", "unreadable"
#: a video is truncated when it yields fewer frames than its container declares, beyond this
#: many (some containers round their frame count)
FRAME_COUNT_SLACK = 1
#: a frame whose mean luma (0..255) is below this is black
BLACK_THRESHOLD = 5.0
#: a frame with at least SATURATED_SHARE of its pixels at a luma of SATURATED_THRESHOLD or more is saturated
SATURATED_THRESHOLD, SATURATED_SHARE = 250.0, 0.9


class RawFrame(NamedTuple):
    """A frame as read (:meth:`FrameStream.read`): stream ``index``, ``timestamp`` seconds, ``rgb``
    (H, W, 3) uint8, ``depth`` (H, W) float32 metres or None."""

    index: int
    timestamp: float
    rgb: np.ndarray
    depth: np.ndarray | None


@dataclass(frozen=True, kw_only=True)
class StreamFrame:
    """One frame: ``rgb`` (H, W, 3) uint8 (None when unreadable), ``depth`` (H, W) float32
    metres or None, ``status`` "ok" / "black" / "saturated" / "unreadable", ``mean_luma`` in
    0..255, ``error`` why an unreadable frame could not be read."""

    index: int
    timestamp: float
    rgb: np.ndarray | None
    depth: np.ndarray | None
    status: str
    mean_luma: float
    error: str = ""

    @property
    def usable(self) -> bool:
        return self.status == OK


def frame_status(
    rgb: np.ndarray, black_threshold: float = BLACK_THRESHOLD, saturated_threshold: float = SATURATED_THRESHOLD,
    saturated_share: float = SATURATED_SHARE,
) -> tuple[str, float]:
    """("ok" | "black" | "saturated", mean luma 0..255) of an RGB uint8 frame."""
    luma = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    mean = float(luma.mean())
    if mean < black_threshold:
        return BLACK, mean
    if float(np.mean(luma >= saturated_threshold)) >= saturated_share:
        return SATURATED, mean
    return OK, mean


def _load_camera(camera: PinholeCamera | OmniCamera | str | Path | None,
                 source: Path) -> tuple[PinholeCamera | OmniCamera, Path | None]:
    """A video's intrinsics (its lens) and the camera.json they were read from (None: given as an object)."""
    if isinstance(camera, PinholeCamera | OmniCamera):
        return camera, None
    if camera is not None:
        return PinholeCamera.from_json(camera), Path(camera)
    beside = source.parent / "camera.json"
    if beside.is_file():
        return PinholeCamera.from_json(beside), beside
    raise InputError(f"{source}: video needs intrinsics: pass a camera.json or --fov DEG (none found at {beside})")


class UndistortedSequence(Sequence):
    """A sequence folder whose frames (and depth) are read undistorted when its camera.json has a
    lens distortion: ``camera`` is then the pinhole camera, ``lens`` the camera.json as written."""

    def __init__(self, root: str | Path) -> None:
        super().__init__(root)
        self.lens = self.camera
        self.undistortion = Undistortion.of(self.lens)
        if self.undistortion is not None:
            self.camera = self.undistortion.camera

    def read_rgb(self, i: int) -> np.ndarray:
        img = super().read_rgb(i)
        return img if self.undistortion is None else self.undistortion.rgb(img)

    def read_depth(self, i: int) -> np.ndarray:
        depth = super().read_depth(i)
        return depth if self.undistortion is None else self.undistortion.depth(depth)


@dataclass(frozen=True)
class Truncation:
    """A video that ended at frame ``read`` (the frames before it decoded) of ``declared``."""

    read: int
    declared: int

    def message(self, source: Path) -> str:
        return (f"{source}: the video ended after {self.read} of the {self.declared} frames its container "
                "declares (damaged or cut file)")


class FrameStream:
    """Iterate frames of ``source`` (a sequence folder or a video file) lazily.

    ``camera``: intrinsics (object, camera.json path or :class:`FovGuess`) for a video; default
    camera.json beside the video. A sequence folder always uses its own camera.json. Frames
    ``start, start + step, ...`` are yielded, at most ``max_frames``; ``index`` is the frame
    number in the source. ``use_depth``: read depth/ when the folder has it.
    """

    def __init__(
        self,
        source: str | Path | int,
        camera: PinholeCamera | OmniCamera | FovGuess | str | Path | None = None,
        use_depth: bool = True,
        start: int = 0,
        step: int = 1,
        max_frames: int | None = None,
        fps: float | None = None,
        black_threshold: float = BLACK_THRESHOLD,
        saturated_threshold: float = SATURATED_THRESHOLD,
        saturated_share: float = SATURATED_SHARE,
    ) -> None:
        #: a capture device's OpenCV index (``source`` an int), read like a video without an end
        self.device: int | None = source if isinstance(source, int) and not isinstance(source, bool) else None
        self.source = Path(f"capture device {source}") if self.device is not None else Path(source)
        if start < 0 or step < 1 or (max_frames is not None and max_frames < 0):
            raise InputError(f"bad frame range: start={start} step={step} max_frames={max_frames}")
        if fps is not None and not fps > 0:
            raise InputError(f"fps must be positive, got {fps}")
        self.start, self.step, self.max_frames, self.fps = start, step, max_frames, fps
        self.use_depth = use_depth
        self._thresholds = (black_threshold, saturated_threshold, saturated_share)
        self.sequence: Sequence | None = None
        self.truncation: Truncation | None = None  #: set while iterating a video that ends early
        #: the frame-quality gate every otherwise usable frame passes, in order (None: none); its
        #: cause becomes the frame's status (:mod:`c3f_slam.frames.quality`)
        self.quality: FrameQualityGate | None = None
        if self.device is None and not self.source.exists():
            raise InputError(f"{self.source}: no such file or folder")
        if self.device is None and self.source.is_dir():
            if isinstance(camera, FovGuess):
                raise InputError(f"{self.source}: --fov is for videos; a sequence folder uses its camera.json")
            self.sequence = UndistortedSequence(self.source)
            self.undistortion = self.sequence.undistortion
            self.camera = self.sequence.camera
            self.camera_file: Path | None = self.source / "camera.json"
            self.is_video = False
        else:
            if self.device is None and self.source.suffix.lower() not in VIDEO_SUFFIXES:
                raise InputError(
                    f"{self.source}: not a sequence folder or a video ({', '.join(VIDEO_SUFFIXES)})"
                )
            self.is_video = True
            if isinstance(camera, FovGuess):  # the guess needs the frames' size
                width, height = self._probe_video()
                lens, self.camera_file = camera.camera(width, height), None
            elif camera is None and self.device is not None:
                raise InputError(f"{self.source}: a capture device needs intrinsics: pass --camera camera.json "
                                 "or --fov DEG")
            else:  # a missing or bad camera.json is told before the video is opened
                lens, self.camera_file = _load_camera(camera, self.source)
                width, height = self._probe_video()
            lens.check_image((height, width), str(self.source))
            self.undistortion = Undistortion.of(lens)
            self.camera = lens if self.undistortion is None else self.undistortion.camera
        #: where the intrinsics came from, for summary.json: "file PATH", "fov guess DEG deg" or "given"
        self.camera_source = (f"file {self.camera_file}" if self.camera_file is not None
                              else camera.describe() if isinstance(camera, FovGuess) else "given")
        if self.undistortion is not None:
            self.camera_source += f" ({self.undistortion.describe()})"

    # ------------------------------------------------------------------ video
    def _open(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(self.device if self.device is not None else str(self.source))
        if not cap.isOpened():
            cap.release()
            if self.device is not None:
                raise InputError(f"{self.source}: does not open (no such camera, or in use)")
            raise InputError(f"{self.source}: video does not open (unsupported codec or corrupt file)")
        return cap

    def _probe_video(self) -> tuple[int, int]:
        """Open once to check that the first frame decodes; its (width, height)."""
        cap = self._open()
        try:
            ok, bgr = cap.read()
            if not ok or bgr is None:
                raise InputError(f"{self.source}: no frame could be decoded")
            container_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            self.video_fps = container_fps if container_fps > 0 else (self.fps or 30.0)
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            self._n_source = n if n > 0 else None
            return bgr.shape[1], bgr.shape[0]
        finally:
            cap.release()

    def _iter_video(self) -> Iterator[tuple[int, float, np.ndarray, None]]:
        cap = self._open()
        self.truncation = None
        t0 = time.monotonic()
        try:
            index = 0
            while True:
                if index < self.start or (index - self.start) % self.step:
                    if not cap.grab():  # skip without decoding
                        self._note_end(index)
                        return
                    index += 1
                    continue
                ok, bgr = cap.read()
                if not ok or bgr is None:
                    self._note_end(index)
                    return
                self.camera.check_image(bgr.shape, f"{self.source} frame {index}")
                if self.undistortion is not None:
                    bgr = self.undistortion.rgb(bgr)
                stamp = time.monotonic() - t0 if self.device is not None else index / self.video_fps
                yield index, stamp, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), None
                index += 1
        finally:
            cap.release()

    def _note_end(self, index: int) -> None:
        """The video stopped at frame ``index``: note it when its container declared more."""
        declared = self._n_source
        if declared is not None and declared - index > FRAME_COUNT_SLACK:
            self.truncation = Truncation(index, declared)

    # ------------------------------------------------------------------ folder
    def _iter_folder(self) -> Iterator[tuple[int, float, np.ndarray | None, np.ndarray | None] | StreamFrame]:
        seq = self.sequence
        assert seq is not None
        for index in range(self.start, len(seq), self.step):
            if seq.timestamps is not None:
                stamp = float(seq.timestamps[index])
            else:
                stamp = index / self.fps if self.fps else float(index)
            want_depth = self.use_depth and seq.has_depth
            try:  # a missing or corrupt file: an unreadable frame
                rgb = read_rgb(seq.rgb_paths[index])
                depth = read_depth_png(seq.depth_paths[index], seq.camera.depth_scale) if want_depth else None
            except InputError as exc:
                yield StreamFrame(index=index, timestamp=stamp, rgb=None, depth=None, status=UNREADABLE,
                                  mean_luma=0.0, error=str(exc))
                continue
            seq.camera.check_image(rgb.shape, str(seq.rgb_paths[index]))  # wrong intrinsics: an error
            if depth is not None:
                seq.camera.check_image(depth.shape, str(seq.depth_paths[index]))
            if self.undistortion is not None:
                rgb = self.undistortion.rgb(rgb)
                depth = None if depth is None else self.undistortion.depth(depth)
            yield index, stamp, rgb, depth

    # ------------------------------------------------------------------ public
    @property
    def n_source_frames(self) -> int | None:
        """Frames in the source (a video's container count may be approximate or None)."""
        return len(self.sequence) if self.sequence is not None else self._n_source

    def __len__(self) -> int:
        """Expected number of yielded frames (from the container's count for a video)."""
        n = self.n_source_frames or 0
        k = max(0, -(-(n - self.start) // self.step))
        return k if self.max_frames is None else min(k, self.max_frames)

    def read(self) -> Iterator[RawFrame | StreamFrame]:
        """The frames as read, not judged yet (:meth:`judge`); an unreadable one as its
        :class:`StreamFrame`. A live run reads on one thread and judges on another."""
        raw = self._iter_video() if self.is_video else self._iter_folder()
        if self.max_frames is not None:
            raw = islice(raw, self.max_frames)
        for item in raw:
            yield item if isinstance(item, StreamFrame) else RawFrame(*item)

    def judge(self, item: RawFrame | StreamFrame) -> StreamFrame:
        """A frame read, flagged: black, saturated, then the quality gate's causes, in stream
        order (the gate compares a frame with the ones before it)."""
        if isinstance(item, StreamFrame):
            return item
        status, mean = frame_status(item.rgb, *self._thresholds)
        if status == OK and self.quality is not None:  # blurred, dark, washed out, covered, repeated
            status = self.quality.assess(item.rgb).status
        return StreamFrame(index=item.index, timestamp=item.timestamp, rgb=item.rgb, depth=item.depth, status=status,
                           mean_luma=mean)

    def __iter__(self) -> Iterator[StreamFrame]:
        if self.quality is not None:
            self.quality.reset()
        for item in self.read():
            yield self.judge(item)


def open_stream(source: str | Path, **kwargs) -> FrameStream:
    """Shortcut for :class:`FrameStream`; raises InputError on a bad source."""
    return FrameStream(source, **kwargs)
