"""The project's own sequence layout (docs/datasets.md, Sequence layout), read and written.

::

    SEQ/
      rgb/NNNNNN.png          colour frames (PNG or JPEG)
      depth/NNNNNN.png        optional, uint16, ``depth_scale`` units per metre, 0 = no depth
      camera.json             width, height, fx, fy, cx, cy, optional distortion, depth_scale
      poses.txt               optional, TUM, camera-to-world, metres, one line per frame
      times.txt               optional, without poses.txt: each frame's time, seconds, one line
                              per frame (a video's frames keep their times: see read_times)
      mesh.ply                optional ground-truth surface

Frames are matched between ``rgb/`` and ``depth/`` by file stem. Depth is returned in
metres as float32 with 0 where there is no depth (NaN or negative values in a file are
rejected, never passed on).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from c3f_core.atomic import atomic_write, atomic_write_text
from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.io.tum import read_tum, write_tum

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
TIMES = "times.txt"  #: a sequence's frame times (seconds), when it has no poses.txt


def read_times(path: str | Path, n_frames: int) -> np.ndarray:
    """(n_frames,) float64 seconds from a times file (one number per line, ``#`` comments);
    InputError naming the file when a line is not a number, the count is not ``n_frames`` or
    the times do not increase."""
    path = Path(path)
    lines = [ln.split("#", 1)[0].strip() for ln in path.read_text().splitlines()]
    try:
        t = np.array([float(ln) for ln in lines if ln], dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{path}: not a list of times in seconds ({exc})") from None
    if len(t) != n_frames:
        raise InputError(f"{path}: {len(t)} times for {n_frames} frames")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(f"{path}: the times must be finite and increase from frame to frame")
    return t


def write_times(path: str | Path, timestamps: np.ndarray) -> None:
    """A times file (:func:`read_times`), microsecond precision, written atomically."""
    atomic_write_text(Path(path), "# time of each frame, seconds\n" + "".join(f"{t:.6f}\n" for t in timestamps))


def read_rgb(path: str | Path) -> np.ndarray:
    """Read a colour image as (H, W, 3) uint8 RGB; raise InputError if it does not decode."""
    path = Path(path)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        if not path.is_file():
            raise InputError(f"{path}: image not found")
        raise InputError(f"{path}: image does not decode (corrupt or not an image)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_depth_png(path: str | Path, depth_scale: float) -> np.ndarray:
    """Read a uint16 depth PNG as (H, W) float32 metres (0 = no depth)."""
    path = Path(path)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        if not path.is_file():
            raise InputError(f"{path}: depth image not found")
        raise InputError(f"{path}: depth image does not decode (corrupt or not an image)")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise InputError(f"{path}: depth must be a single-channel 16-bit PNG, got {raw.dtype} with shape {raw.shape}")
    return raw.astype(np.float32) / np.float32(depth_scale)


def encode_depth(depth_m: np.ndarray, depth_scale: float, what: str = "depth") -> np.ndarray:
    """Metres to the uint16 encoding; NaN/inf/<=0 become 0 (no depth); overflow is an error."""
    d = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    scaled = np.where(valid, np.round(d * depth_scale), 0)
    if scaled.max(initial=0) > np.iinfo(np.uint16).max:
        raise InputError(
            f"{what}: depth {d[valid].max():.3f} m does not fit uint16 at depth_scale {depth_scale}"
        )
    return scaled.astype(np.uint16)


def _list_images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))


class Sequence:
    """A sequence on disk in the project's layout; frames are read lazily, one at a time."""

    def __init__(self, root: str | Path, min_frames: int = 1) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"{self.root}: sequence folder not found")
        rgb_dir = self.root / "rgb"
        if not rgb_dir.is_dir():
            raise InputError(f"{self.root}: no rgb/ folder (expected the layout rgb/, camera.json, ...)")
        self.rgb_paths = _list_images(rgb_dir)
        if len(self.rgb_paths) < min_frames:
            raise InputError(
                f"{rgb_dir}: {len(self.rgb_paths)} frame(s), at least {min_frames} needed"
            )
        self.camera = PinholeCamera.from_json(self.root / "camera.json")

        depth_dir = self.root / "depth"
        self.depth_paths: list[Path] | None = None
        if depth_dir.is_dir():
            by_stem = {p.stem: p for p in _list_images(depth_dir)}
            missing = [p.stem for p in self.rgb_paths if p.stem not in by_stem]
            if missing:
                raise InputError(
                    f"{depth_dir}: no depth for {len(missing)} frame(s), first {missing[0]!r}"
                )
            self.depth_paths = [by_stem[p.stem] for p in self.rgb_paths]

        self.timestamps: np.ndarray | None = None
        self.poses: np.ndarray | None = None
        pose_file = self.root / "poses.txt"
        if pose_file.is_file():
            stamps, poses = read_tum(pose_file)
            if len(poses) != len(self.rgb_paths):
                raise InputError(
                    f"{pose_file}: {len(poses)} poses for {len(self.rgb_paths)} frames in {rgb_dir}"
                )
            self.timestamps, self.poses = stamps, poses
        elif (self.root / TIMES).is_file():
            self.timestamps = read_times(self.root / TIMES, len(self.rgb_paths))

    # ------------------------------------------------------------------ access
    @property
    def name(self) -> str:
        return self.root.name

    @property
    def frame_names(self) -> list[str]:
        return [p.stem for p in self.rgb_paths]

    @property
    def has_depth(self) -> bool:
        return self.depth_paths is not None

    @property
    def has_poses(self) -> bool:
        return self.poses is not None

    @property
    def mesh_path(self) -> Path | None:
        p = self.root / "mesh.ply"
        return p if p.is_file() else None

    def __len__(self) -> int:
        return len(self.rgb_paths)

    def __repr__(self) -> str:
        return (
            f"Sequence({str(self.root)!r}, frames={len(self)}, size={self.camera.width}x{self.camera.height},"
            f" depth={self.has_depth}, poses={self.has_poses})"
        )

    def read_rgb(self, i: int) -> np.ndarray:
        """Frame i as (H, W, 3) uint8 RGB; its size must match camera.json."""
        img = read_rgb(self.rgb_paths[i])
        self.camera.check_image(img.shape, str(self.rgb_paths[i]))
        return img

    def read_depth(self, i: int) -> np.ndarray:
        """Depth of frame i, (H, W) float32 metres, 0 = no depth."""
        if self.depth_paths is None:
            raise InputError(f"{self.root}: sequence has no depth/ folder")
        d = read_depth_png(self.depth_paths[i], self.camera.depth_scale)
        self.camera.check_image(d.shape, str(self.depth_paths[i]))
        return d

    def pose(self, i: int) -> np.ndarray:
        """Camera-to-world pose of frame i (4x4, metres)."""
        if self.poses is None:
            raise InputError(f"{self.root}: sequence has no poses.txt")
        return self.poses[i]


class SequenceWriter:
    """Writes a sequence in the project's layout; every file is written atomically.

    Frame files are named by index with six digits. ``finish`` writes camera.json and
    poses.txt last, so a sequence folder without camera.json is an unfinished one.
    """

    def __init__(self, root: str | Path, camera: PinholeCamera) -> None:
        self.root = Path(root)
        self.camera = camera
        (self.root / "rgb").mkdir(parents=True, exist_ok=True)
        self._n = 0

    def write_frame(self, index: int, rgb: np.ndarray, depth_m: np.ndarray | None = None) -> None:
        """Write frame ``index``: (H, W, 3) uint8 RGB and optional (H, W) depth in metres."""
        name = f"{index:06d}.png"
        self.camera.check_image(rgb.shape, f"frame {index}")
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"frame {index}: rgb must be (H, W, 3) uint8, got {rgb.dtype} {rgb.shape}")
        with atomic_write(self.root / "rgb" / name) as tmp:
            if not cv2.imwrite(str(tmp), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
                raise OSError(f"could not write {self.root / 'rgb' / name}")
        if depth_m is not None:
            self.camera.check_image(depth_m.shape, f"depth {index}")
            (self.root / "depth").mkdir(exist_ok=True)
            enc = encode_depth(depth_m, self.camera.depth_scale, f"depth {index}")
            with atomic_write(self.root / "depth" / name) as tmp:
                if not cv2.imwrite(str(tmp), enc):
                    raise OSError(f"could not write {self.root / 'depth' / name}")
        self._n = max(self._n, index + 1)

    def finish(self, poses: np.ndarray | None = None, timestamps: np.ndarray | None = None) -> None:
        """Write camera.json and (if given) poses.txt, camera-to-world; ``timestamps`` (seconds)
        without ``poses``: times.txt."""
        import json

        if poses is not None:
            if timestamps is None:
                timestamps = np.arange(len(poses), dtype=np.float64)
            write_tum(self.root / "poses.txt", timestamps, poses)
        elif timestamps is not None:
            write_times(self.root / TIMES, np.asarray(timestamps, dtype=np.float64))
        atomic_write_text(self.root / "camera.json", json.dumps(self.camera.to_dict(), indent=2) + "\n")
