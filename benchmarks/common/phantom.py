"""The C3VD phantom clip of the development data (``../shared/data/c3vd_phantom_preview``, never
part of the repository) as a video, for the protocols that run the runtime on a scope's own video.

- :func:`phantom_video`: the frames as a 60 frames/s video with the guessed ``camera.json`` beside it.

The clip's reader (the split folder, the depth render as a reference, the convention) is
:mod:`datamodules.phantom`; the real-frame depth evaluation is :mod:`c3f_models.zoo.real`.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from datamodules.phantom import write_video


def phantom_video(phantom: Path, work: Path) -> Path:
    """The phantom clip's frames (split.py) as a 60 frames/s video with camera.json beside it."""
    frames = work / "phantom_frames"
    video = work / "phantom_video" / "phantom.mp4"
    if video.is_file():
        return video
    subprocess.run([sys.executable, str(phantom / "split.py"), str(frames)], check=True, capture_output=True)
    write_video(sorted((frames / "rgb").glob("*.png")), video)
    (video.parent / "camera.json").write_text((frames / "camera.json").read_text())
    return video


__all__ = ["phantom_video"]
