"""``python -m datamodules.ingest VIDEO --out SEQ``: a video's frames as a sequence folder that the
training data modules and the SLAM runtime read (docs/datasets.md, Sequence layout).

``SEQ`` gets ``rgb/NNNNNN.png``, ``camera.json`` (pinhole), ``times.txt`` (each frame's time in
the video, seconds: the runtime's motion prior and jitter ratio work in seconds), ``frames.csv``
(per frame: its index in the video and its time), ``tissue_mask.png`` named by camera.json's
``tissue_mask`` when the video shows a border or overlays, and ``ingest.json`` (what was read and
how). Frames are read with the runtime's own reader (:class:`c3f_slam.frames.stream.FrameStream`:
intrinsics from ``--camera``, the ``--fov`` guess, or ``camera.json`` beside the video; a
distorted lens is undistorted to a pinhole camera), every k-th (k the smallest that keeps at most
``--max-fps`` frames per second of video), at most ``--max-frames`` from the start, resized (area
interpolation) so that the longer side is at most ``--max-side`` pixels; the intrinsics follow.
The tissue area is the runtime's (:func:`c3f_slam.frames.tissue.resolve_tissue_mask`: a mask named by
the camera file, else found from the first frames). A frame that repeats the previous picture (a
re-encoded video; the runtime's frame-quality gate says ``duplicate``) is not written: it carries
nothing, and test-time training would learn from a pair with no motion; ``ingest.json`` counts
them. Other frames the gate flags (blurred, dark, ...) are written: the SLAM run skips and counts
them. The folder is built in a hidden folder beside ``SEQ`` and moved into place when complete,
so an error or Ctrl-C never leaves half a sequence. Bad input: one ``error:`` line, exit status 2.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError

FRAMES_CSV = "frames.csv"  #: per frame of the sequence: frame, video_frame, time_s
TISSUE_MASK = "tissue_mask.png"  #: the tissue area at the sequence's frame size (255 = tissue)
RECORD = "ingest.json"  #: what the ingest read and wrote


def frame_step(fps: float, max_fps: float) -> int:
    """The smallest k >= 1 such that every k-th frame of a ``fps`` video is at most ``max_fps`` per second."""
    if not (max_fps > 0):
        raise InputError(f"--max-fps must be positive, got {max_fps}")
    return max(1, math.ceil(fps / max_fps - 1e-9))


def target_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """(width, height) scaled so that the longer side is at most ``max_side`` pixels (never enlarged)."""
    if max_side < 16:
        raise InputError(f"--max-side must be at least 16 pixels, got {max_side}")
    s = min(1.0, max_side / max(width, height))
    return max(1, round(width * s)), max(1, round(height * s))


def open_video(video: str | Path, camera: str | Path | None = None, fov: float | None = None, step: int = 1,
               max_frames: int | None = None):
    """The runtime's :class:`~c3f_slam.frames.stream.FrameStream` of ``video`` with its intrinsics (``camera``
    file, else the ``fov`` guess, else camera.json beside the video); InputError when the video is
    missing or does not decode, or has no intrinsics."""
    from c3f_slam.camera.intrinsics import FovGuess
    from c3f_slam.frames.stream import FrameStream

    video = Path(video)
    if not video.is_file():
        raise InputError(f"--video {video}: " + ("a folder, not a video file" if video.is_dir() else "no such file"))
    lens = FovGuess(fov) if fov is not None else camera
    return FrameStream(video, camera=lens, use_depth=False, step=step, max_frames=max_frames)


def ingest(video: str | Path, out: str | Path, *, camera: str | Path | None = None, fov: float | None = None,
           max_fps: float = 30.0, max_frames: int = 600, max_side: int = 256) -> dict:
    """Write the sequence folder ``out`` from ``video`` (module docstring); returns ``ingest.json``'s record."""
    import cv2

    from c3f_core.atomic import move_into_place, staging_dir
    from c3f_slam.config import FrameQualityConfig, TissueConfig
    from c3f_slam.frames.quality import DUPLICATE, FrameQualityGate
    from c3f_slam.frames.tissue import resolve_tissue_mask
    from c3f_slam.io.sequence import SequenceWriter

    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"--out {out}: exists and is not empty")
    if max_frames < 3:
        raise InputError(f"--max-frames must be at least 3 (training takes frame triplets), got {max_frames}")
    probe = open_video(video, camera, fov)
    step = frame_step(probe.video_fps, max_fps)
    stream = open_video(video, camera, fov, step, max_frames)
    size = target_size(stream.camera.width, stream.camera.height, max_side)
    cam = stream.camera.resize(*size)
    tissue = resolve_tissue_mask(stream, TissueConfig(), stream.camera_file)
    stream.quality = FrameQualityGate(FrameQualityConfig(), tissue.pixels)
    tmp = staging_dir(out)
    rows, statuses = [], {}
    try:
        writer = SequenceWriter(tmp, cam)
        for frame in stream:
            statuses[frame.status] = statuses.get(frame.status, 0) + 1
            if frame.status == DUPLICATE or frame.rgb is None:  # a repeat, or a frame that does not decode
                continue
            rgb = frame.rgb if size == (stream.camera.width, stream.camera.height) else cv2.resize(
                frame.rgb, size, interpolation=cv2.INTER_AREA)
            writer.write_frame(len(rows), rgb)
            rows.append((len(rows), frame.index, round(frame.timestamp, 6)))
        if len(rows) < 3:
            raise InputError(f"--video {video}: {len(rows)} distinct frame(s) decoded, at least 3 needed")
        writer.finish(timestamps=np.array([r[2] for r in rows]))
        mask = write_tissue_mask(tmp, tissue, size)
        with (tmp / FRAMES_CSV).open("w", newline="") as fh:
            csv.writer(fh).writerows([("frame", "video_frame", "time_s"), *rows])
        record = {"video": str(Path(video).resolve()), "fps": probe.video_fps, "video_frames": probe.n_source_frames,
                  "step": step, "frames": len(rows), "seconds": rows[-1][2] - rows[0][2],
                  "source_size": [stream.camera.width, stream.camera.height], "size": list(size),
                  "camera_source": stream.camera_source, "camera": cam.to_dict(), "statuses": statuses,
                  "repeats_dropped": statuses.get(DUPLICATE, 0),
                  "tissue_mask": {**tissue.summary(), "file": mask},
                  "truncated": stream.truncation.message(Path(video)) if stream.truncation else None,
                  "settings": {"max_fps": max_fps, "max_frames": max_frames, "max_side": max_side}}
        (tmp / RECORD).write_text(json.dumps(record, indent=2) + "\n")
        move_into_place(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return record


def write_tissue_mask(seq: Path, tissue, size: tuple[int, int]) -> str | None:
    """The tissue area (a :class:`c3f_slam.frames.tissue.TissueMask` of the source frames) at the
    sequence's frame ``size`` as ``seq/tissue_mask.png``, named by its camera.json's
    ``tissue_mask``; nothing when it is the whole frame. Returns the file name or None."""
    import cv2

    if tissue.whole_frame:
        return None
    pixels = cv2.resize(tissue.pixels.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) * 255
    if not cv2.imwrite(str(seq / TISSUE_MASK), pixels):
        raise OSError(f"could not write {seq / TISSUE_MASK}")
    camera_json = seq / "camera.json"
    camera = json.loads(camera_json.read_text())
    camera_json.write_text(json.dumps({**camera, "tissue_mask": TISSUE_MASK}, indent=2) + "\n")
    return TISSUE_MASK


def read_times(seq: str | Path) -> dict[int, float]:
    """Frame index of the sequence -> its time in the video (seconds), from ``frames.csv``."""
    with (Path(seq) / FRAMES_CSV).open(newline="") as fh:
        return {int(r["frame"]): float(r["time_s"]) for r in csv.DictReader(fh)}


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m datamodules.ingest",
                       description="A video's frames as a sequence folder (rgb/, camera.json, frames.csv, "
                                   "ingest.json), subsampled and resized for a CPU.")
    ap.add_argument("video", type=Path, help="the video file")
    ap.add_argument("--out", type=Path, required=True, help="the sequence folder to write (must not exist)")
    lens = ap.add_mutually_exclusive_group()
    lens.add_argument("--camera", type=Path, help="camera.json of the video (default: camera.json beside it)")
    lens.add_argument("--fov", type=float, metavar="DEG", help="no calibration: a pinhole guess of DEG degrees "
                                                               "horizontal field of view")
    ap.add_argument("--max-fps", type=float, default=30.0, help="frames per second of video kept (default 30)")
    ap.add_argument("--max-frames", type=int, default=600, help="frames written, from the start (default 600)")
    ap.add_argument("--max-side", type=int, default=256, help="longer side of the frames written, pixels "
                                                              "(default 256; never enlarged)")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        rec = ingest(args.video, args.out, camera=args.camera, fov=args.fov, max_fps=args.max_fps,
                     max_frames=args.max_frames, max_side=args.max_side)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    w, h = rec["size"]
    print(f"{rec['frames']} frames (every {rec['step']} of {rec['fps']:g} fps, {w}x{h}) -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
