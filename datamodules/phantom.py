"""The C3VD phantom clip of the development data (``c3vd_phantom_preview``, never part of the
repository): its frames split by the clip's own ``split.py``, read as the runtime reads them.
No torch.

- :func:`split_folder` / :func:`read_phantom`: the split folder (``rgb/``, ``depth_render/``,
  ``occlusion/``: ``NNNNNN.png`` each, 446x448; ``camera.json``) with the data set's depth render
  as a reference depth;
- :func:`write_video`: frames as a video file (the clip as a scope would record it).

Reference convention (checked by eye on frames 0, 96, 192, 288 beside their renders): the depth
render is 8-bit grey with **brighter = farther** (the lumen is the brightest region, the near
wall the darkest), relative only, no unit; 0 (black) is no surface: the border, and holes past
the render's far end beside the lumen. :class:`PhantomFrames` keeps the grey level as depth
(larger = farther) with 0 as NaN. The occlusion panel is white (> 127) where the surface is hidden
from this view; those pixels, the border (the tissue mask found from the frames, as the runtime
finds it) and the render's holes are left out of every comparison (:meth:`PhantomFrames.valid`).
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from c3f_core.errors import InputError

#: the folders of a split phantom clip, one PNG per frame each (split.py's names)
SPLIT_DIRS = ("rgb", "depth_render", "occlusion")


def write_video(paths: list[Path], video: Path, *, fps: float = 60.0) -> Path:
    """The images ``paths`` (one size) as an mp4v video ``video`` of ``fps`` frames per second."""
    first = cv2.imread(str(paths[0]))
    video.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), fps, first.shape[1::-1])
    for p in paths:
        writer.write(cv2.imread(str(p)))
    writer.release()
    return video


def is_split(folder: Path) -> bool:
    """True when ``folder`` holds a split clip: rgb/, depth_render/, occlusion/ and camera.json."""
    return all((folder / d).is_dir() for d in SPLIT_DIRS) and (folder / "camera.json").is_file()


def split_folder(phantom: Path, work: Path) -> Path:
    """The split clip of ``phantom``: the folder itself when it is one (:func:`is_split`), else
    ``phantom/split.py``'s output in ``work/phantom_frames`` (split once); InputError naming
    ``--phantom`` when it is neither."""
    phantom = Path(phantom)
    if is_split(phantom):
        return phantom
    if not phantom.is_dir():
        raise InputError(f"--phantom {phantom}: no such folder")
    if not (phantom / "split.py").is_file():
        raise InputError(f"--phantom {phantom}: neither a split clip (rgb/, depth_render/, occlusion/, camera.json) "
                         "nor the clip's folder with split.py")
    out = Path(work) / "phantom_frames"
    if not is_split(out):
        subprocess.run([sys.executable, str(phantom / "split.py"), str(out)], check=True, capture_output=True)
    return out


def frame_names(split: Path) -> list[str]:
    """The frame files (``NNNNNN.png``) of the split clip, sorted; InputError when there is none or
    a panel lacks one."""
    names = sorted(p.name for p in (split / "rgb").glob("*.png"))
    if not names:
        raise InputError(f"{split / 'rgb'}: no frame (NNNNNN.png)")
    for d in SPLIT_DIRS[1:]:
        missing = [n for n in names if not (split / d / n).is_file()]
        if missing:
            raise InputError(f"{split / d / missing[0]}: missing ({len(missing)} of {len(names)} frames have no {d})")
    return names


def _read(path: Path, flags: int) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        raise InputError(f"{path}: not a readable image")
    return img


def _read_rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(_read(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


@dataclass(frozen=True)
class PhantomFrames:
    """Frames of a split clip: ``indices`` (frame numbers in the clip), ``rgb`` (H, W, 3) uint8
    RGB, ``depth`` (H, W) float32 reference depth (the render's grey level 1..255, larger =
    farther, relative; NaN where the render is 0: no surface), ``occluded`` (H, W) bool (True =
    hidden from this view), ``camera`` (the split's guessed camera.json), ``tissue`` the
    :class:`~c3f_slam.frames.tissue.TissueMask` found from the clip's frames."""

    indices: list[int]
    rgb: list[np.ndarray]
    depth: list[np.ndarray]
    occluded: list[np.ndarray]
    camera: object
    tissue: object

    def valid(self, k: int) -> np.ndarray:
        """(H, W) bool pixels of the ``k``-th frame read that count: tissue, not occluded, with depth."""
        return self.tissue.pixels & ~self.occluded[k] & np.isfinite(self.depth[k])


def read_phantom(split: Path, every: int = 1) -> PhantomFrames:
    """Every ``every``-th frame (from frame 0) of the split clip in ``split`` (module notes for the
    convention); the tissue mask is detected from frames spread over the whole clip
    (:func:`c3f_slam.frames.tissue.detect_tissue_mask`, default settings). InputError naming the
    file or option on bad input."""
    from c3f_slam.camera.intrinsics import PinholeCamera
    from c3f_slam.config import TissueConfig
    from c3f_slam.frames.tissue import detect_tissue_mask

    if every < 1:
        raise InputError(f"phantom_every must be at least 1, got {every}")
    split = Path(split)
    if not is_split(split):
        raise InputError(f"--phantom {split}: not a split clip (rgb/, depth_render/, occlusion/, camera.json)")
    names = frame_names(split)
    camera = PinholeCamera.from_json(split / "camera.json")
    cfg = TissueConfig()
    sample = sorted({int(i) for i in np.linspace(0, len(names) - 1, min(cfg.frames, len(names))).round()})
    tissue = detect_tissue_mask([_read_rgb(split / "rgb" / names[i]) for i in sample], cfg)
    indices = list(range(0, len(names), every))
    rgb, depth, occluded = [], [], []
    for i in indices:
        n = names[i]
        frame = _read_rgb(split / "rgb" / n)
        if frame.shape[:2] != (camera.height, camera.width):
            raise InputError(f"{split / 'rgb' / n}: {frame.shape[1]}x{frame.shape[0]} but camera.json says "
                             f"{camera.width}x{camera.height}")
        grey = _read(split / "depth_render" / n, cv2.IMREAD_GRAYSCALE)
        occ = _read(split / "occlusion" / n, cv2.IMREAD_GRAYSCALE)
        for what, img in (("depth_render", grey), ("occlusion", occ)):
            if img.shape != frame.shape[:2]:
                raise InputError(f"{split / what / n}: {img.shape[1]}x{img.shape[0]} but the frame is "
                                 f"{frame.shape[1]}x{frame.shape[0]}")
        rgb.append(frame)
        depth.append(np.where(grey > 0, grey.astype(np.float32), np.float32(np.nan)))
        occluded.append(occ > 127)
    return PhantomFrames(indices, rgb, depth, occluded, camera, tissue)


__all__ = ["SPLIT_DIRS", "PhantomFrames", "frame_names", "is_split", "read_phantom", "split_folder", "write_video"]
