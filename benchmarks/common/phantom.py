"""The C3VD phantom clip of the development data (``../shared/data/c3vd_phantom_preview``, never
part of the repository) as the runtime reads it: its frames split by the clip's own ``split.py``
and written as a 60 frames/s video with the guessed ``camera.json`` beside it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2


def phantom_video(phantom: Path, work: Path) -> Path:
    """The phantom clip's frames (split.py) as a 60 frames/s video with camera.json beside it."""
    frames = work / "phantom_frames"
    video = work / "phantom_video" / "phantom.mp4"
    if video.is_file():
        return video
    subprocess.run([sys.executable, str(phantom / "split.py"), str(frames)], check=True, capture_output=True)
    paths = sorted((frames / "rgb").glob("*.png"))
    first = cv2.imread(str(paths[0]))
    video.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 60.0, first.shape[1::-1])
    for p in paths:
        writer.write(cv2.imread(str(p)))
    writer.release()
    (video.parent / "camera.json").write_text((frames / "camera.json").read_text())
    return video
