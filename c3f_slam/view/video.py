"""H.264 MP4 files that browsers play (Chromium, Firefox, Safari), written atomically.

Frames go to the ffmpeg binary that the ``imageio-ffmpeg`` package ships (libx264, yuv420p,
``+faststart`` so a page can start playing before the whole file is read). The file is
written beside the target under a temporary name and renamed when complete. Frame rate and
quality: :class:`c3f_slam.view.settings.VideoSettings`.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from c3f_core.atomic import atomic_write
from c3f_slam.view.settings import VideoSettings


def even_size(img: np.ndarray) -> np.ndarray:
    """``img`` cropped to even width and height (yuv420p needs both)."""
    h, w = img.shape[:2]
    return img[: h - h % 2, : w - w % 2]


def write_mp4(path: str | Path, frames: Iterable[np.ndarray], video: VideoSettings | None = None) -> int:
    """Write (H, W, 3) uint8 RGB ``frames`` (all the same size) as H.264 at ``video.fps`` frames per
    second and quality ``video.crf`` (``video``: default the defaults); returns the frame count (no
    file is written for none)."""
    video = video or VideoSettings()
    import imageio_ffmpeg  # the ffmpeg binary: only when a video is written

    it = iter(frames)
    first = next(it, None)
    if first is None:
        return 0
    first = even_size(first)
    h, w = first.shape[:2]
    with atomic_write(Path(path), suffix=".mp4") as tmp:
        writer = imageio_ffmpeg.write_frames(str(tmp), (w, h), fps=video.fps, codec="libx264", quality=None,
                                             macro_block_size=2, pix_fmt_out="yuv420p",
                                             output_params=["-crf", str(video.crf), "-preset", "fast",
                                                            "-movflags", "+faststart"])
        writer.send(None)
        try:
            writer.send(np.ascontiguousarray(first))
            n = 1
            for img in it:
                writer.send(np.ascontiguousarray(even_size(img)))
                n += 1
        finally:
            writer.close()
    return n


def label(img: np.ndarray, text: str, corner: str = "top") -> np.ndarray:
    """``img`` with ``text`` drawn white on a dark shadow at its top or bottom left (in place)."""
    scale = max(0.35, img.shape[0] / 600)
    thick = max(1, round(scale * 1.5))
    (_, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    y = th + 4 if corner == "top" else img.shape[0] - base - 3
    for colour, t in (((0, 0, 0), thick + 2), ((255, 255, 255), thick)):
        cv2.putText(img, text, (4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, t, cv2.LINE_AA)
    return img


def centred_text(img: np.ndarray, text: str) -> np.ndarray:
    """``img`` with ``text`` in the middle (in place)."""
    scale = max(0.4, img.shape[0] / 400)
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    org = ((img.shape[1] - tw) // 2, (img.shape[0] + th) // 2)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return img
