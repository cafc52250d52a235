"""What every reader of a published data set shares (torch-free).

A *format* (:class:`SequenceFormat`) finds the sequences of one data set under a folder and
opens each as a :class:`PublishedSequence`: frames and depth read lazily, one at a time, as
the project uses them everywhere (RGB uint8; depth in metres along the optical axis, float32,
0 = no depth), camera-to-world poses in metres (OpenCV camera: x right, y down, z forward),
pinhole intrinsics in pixels. The file-level quirks of each data set (bit depths, scale
constants, handedness, transposed matrices, numbering) stay inside its module.

Bad files raise :class:`c3f_core.errors.InputError` with one line that names the file.
"""

from __future__ import annotations

import os
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera

MAX_SEARCH_DEPTH = 5  # folder levels searched below SRC for sequences
_LAST_INT = re.compile(r"(\d+)(?!.*\d)")


class PublishedSequence:
    """One sequence of a published data set (a ``datamodules.base.FrameSource``).

    Args:
        name: sequence name, unique within the data set (used by splits and the converter).
        root: the sequence folder.
        camera: pinhole intrinsics of the frames as ``read_rgb`` returns them; its
            ``depth_scale`` is the data set's native depth resolution (units per metre), so
            that the converter writes depth without losing precision.
        rgb_paths: colour frame files, in frame order.
        depth_paths: depth files of the same frames, or None.
        poses: (N, 4, 4) camera-to-world poses in metres, or None.
        mesh_path: the ground-truth surface, or None.
    """

    dataset: ClassVar[str] = "published"

    def __init__(self, name: str, root: Path, camera: PinholeCamera, rgb_paths: list[Path],
                 depth_paths: list[Path] | None, poses: np.ndarray | None, mesh_path: Path | None = None) -> None:
        self._name, self.root, self.camera = name, Path(root), camera
        self.rgb_paths, self.depth_paths = list(rgb_paths), (list(depth_paths) if depth_paths is not None else None)
        self.poses = poses
        self.mesh_path = mesh_path
        if self.depth_paths is not None and len(self.depth_paths) != len(self.rgb_paths):
            raise ValueError("one depth file per frame")
        if poses is not None and len(poses) != len(self.rgb_paths):
            raise ValueError("one pose per frame")

    # ------------------------------------------------------------------ FrameSource
    @property
    def name(self) -> str:
        return self._name

    @property
    def has_depth(self) -> bool:
        return self.depth_paths is not None

    @property
    def has_poses(self) -> bool:
        return self.poses is not None

    def __len__(self) -> int:
        return len(self.rgb_paths)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({self.name!r}, frames={len(self)}, size={self.camera.width}x"
                f"{self.camera.height}, depth={self.has_depth}, poses={self.has_poses})")

    def read_rgb(self, i: int) -> np.ndarray:
        """Frame i as (H, W, 3) uint8 RGB in the geometry of :attr:`camera`."""
        path = self.rgb_paths[i]
        img = self.decode_rgb(path)
        self.camera.check_image(img.shape, str(path))
        return img

    def read_depth(self, i: int) -> np.ndarray:
        """Depth of frame i: (H, W) float32 metres along the optical axis, 0 = no depth."""
        if self.depth_paths is None:
            raise InputError(f"{self.root}: this {self.dataset} sequence has no depth")
        path = self.depth_paths[i]
        depth = self.decode_depth(path)
        self.camera.check_image(depth.shape, str(path))
        return depth

    def pose(self, i: int) -> np.ndarray:
        """Camera-to-world pose of frame i (4x4, metres)."""
        if self.poses is None:
            raise InputError(f"{self.root}: this {self.dataset} sequence has no poses")
        return self.poses[i]

    def read_mesh(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The ground-truth surface as (vertices (V, 3) metres, triangles (F, 3) int), or None."""
        return None

    def read_coverage(self) -> np.ndarray | None:
        """Per-triangle flags of :meth:`read_mesh` (True = the data set saw the face), or None."""
        return None

    # ------------------------------------------------------------------ per format
    def decode_rgb(self, path: Path) -> np.ndarray:
        return decode_rgb(path)

    def decode_depth(self, path: Path) -> np.ndarray:  # pragma: no cover - formats without depth never call it
        raise InputError(f"{path}: this {self.dataset} sequence has no depth")


class SequenceFormat(ABC):
    """A published data set's layout: how to recognise, open and split its sequences.

    Subclasses set ``name`` (the converter's argument), ``title`` and ``layout`` (what a
    sequence folder holds, quoted in errors) and implement :meth:`is_sequence` and :meth:`open`.
    Recognising and finding sequences must not depend on the constructor's options.
    """

    name: ClassVar[str]
    title: ClassVar[str]
    layout: ClassVar[str]

    @abstractmethod
    def is_sequence(self, folder: Path) -> bool:
        """Whether ``folder`` is one sequence of this data set (cheap: file names only)."""

    @abstractmethod
    def open(self, folder: Path) -> PublishedSequence:
        """Open the sequence in ``folder`` (parses poses and lists files; frames stay on disk)."""

    def sequence_name(self, folder: Path) -> str:
        """The name of the sequence in ``folder``, unique within the data set."""
        return Path(folder).name

    def published_split(self, root: Path) -> dict[str, list[str]] | None:
        """The data set's own train/test lists (sequence names), when its release has them."""
        return None

    def find(self, root: str | Path) -> list[Path]:
        """Sequence folders under ``root`` (``root`` itself when it is one), sorted.

        Folders whose names start with '.' are skipped; the search stops at a sequence and
        goes at most :data:`MAX_SEARCH_DEPTH` levels down.
        """
        root = Path(root)
        if not root.is_dir():
            raise InputError(f"{root}: folder not found")
        if self.is_sequence(root):
            return [root]
        found: list[Path] = []
        base = len(root.parts)
        for dirpath, dirnames, _ in os.walk(root):
            here = Path(dirpath)
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
            if here != root and self.is_sequence(here):
                found.append(here)
                dirnames[:] = []
            elif len(here.parts) - base >= MAX_SEARCH_DEPTH:
                dirnames[:] = []
        return sorted(found)


# ---------------------------------------------------------------------- files
def numbered(paths: Iterable[Path], pattern: re.Pattern | None = None) -> dict[int, Path]:
    """Files keyed by their frame number: the first group of ``pattern`` (matched against the
    file name) or, without a pattern, the last integer in the stem. Two files with the same
    number are an error."""
    out: dict[int, Path] = {}
    for p in paths:
        m = pattern.match(p.name) if pattern is not None else _LAST_INT.search(p.stem)
        if m is None:
            continue
        k = int(m.group(1))
        if k in out:
            raise InputError(f"{p.parent}: two files for frame {k}: {out[k].name} and {p.name}")
        out[k] = p
    return dict(sorted(out.items()))


def list_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """Visible files of ``folder`` whose suffix (lower case) is one of ``suffixes``."""
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes and not p.name.startswith(".")
                  and p.is_file())


def require_file(path: Path, what: str) -> Path:
    if not path.is_file():
        raise InputError(f"{path}: {what} not found")
    return path


def single_match(folder: Path, pattern: str, what: str) -> Path:
    """The one file of ``folder`` matching the glob ``pattern``."""
    hits = sorted(folder.glob(pattern))
    if not hits:
        raise InputError(f"{folder}: {what} not found (expected a file '{pattern}')")
    if len(hits) > 1:
        raise InputError(f"{folder}: several {what} files ({', '.join(h.name for h in hits)})")
    return hits[0]


def read_number_rows(path: Path, count: int, sep: str | None = None, header: Callable[[str], bool] | None = None,
                     what: str = "numbers") -> np.ndarray:
    """Rows of ``count`` numbers per line, (M, count) float64.

    ``sep``: None = whitespace, else a separator (whitespace around it is ignored). Blank
    lines are skipped; so is a first line for which ``header(line)`` is true. A line with
    fewer numbers (the truncated last line of some releases), more, or a value that is not a
    finite number is an error naming the file and line.
    """
    require_file(path, what)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        if not rows and header is not None and header(line):
            continue
        parts = [p.strip() for p in (line.split(sep) if sep else line.split()) if p.strip()]
        if len(parts) != count:
            hint = " (truncated file?)" if len(parts) < count else ""
            raise InputError(f"{path}:{lineno}: expected {count} {what} per line, got {len(parts)}{hint}")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line[:60]!r}") from None
        if not all(np.isfinite(vals)):
            raise InputError(f"{path}:{lineno}: non-finite value")
        rows.append(vals)
    if not rows:
        raise InputError(f"{path}: no {what}")
    return np.asarray(rows, dtype=np.float64)


def check_pose_count(n_poses: int, frames: dict[int, Path], pose_file: Path) -> None:
    """Poses are indexed by frame number: every frame needs a pose line."""
    need = max(frames) + 1
    if n_poses < need:
        raise InputError(f"{pose_file}: {n_poses} poses, but frame {max(frames)} needs {need} "
                         f"(one line per frame, from frame 0)")


# ---------------------------------------------------------------------- images
def _imread(path: Path, flags: int, what: str) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        if not path.is_file():
            raise InputError(f"{path}: {what} not found")
        raise InputError(f"{path}: {what} does not decode (corrupt or not an image)")
    return img


def decode_rgb(path: Path) -> np.ndarray:
    """A colour image as (H, W, 3) uint8 RGB, whatever it is stored as: 8 or 16 bits per
    channel (16-bit values are rounded to 8 bits), grey, BGR or BGRA (alpha dropped)."""
    img = _imread(path, cv2.IMREAD_UNCHANGED, "image")
    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{path}: colour image must have 8 or 16 bits per channel, got {img.dtype}")
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    if img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    raise InputError(f"{path}: colour image with {img.shape[2]} channels")


def _describe(img: np.ndarray) -> str:
    bits = {np.uint8: "8-bit", np.uint16: "16-bit", np.float32: "32-bit float", np.float64: "64-bit float"}
    ch = 1 if img.ndim == 2 else img.shape[2]
    return f"{bits.get(img.dtype.type, str(img.dtype))} {ch}-channel"


def decode_uint16(path: Path, what: str = "depth image") -> np.ndarray:
    """A single-channel 16-bit image (PNG or TIFF) as (H, W) uint16; other bit depths are an error."""
    img = _imread(path, cv2.IMREAD_UNCHANGED, what)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise InputError(f"{path}: {what} must be single-channel 16-bit, got {_describe(img)}")
    return img


def decode_float_depth(path: Path, what: str = "depth image") -> np.ndarray:
    """First channel of a floating-point image (OpenEXR), (H, W) float32. NaN or negative
    values are an error (never passed on); +inf (a ray that hit nothing) becomes 0 = no depth."""
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    img = _imread(path, cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH, what)
    if img.dtype not in (np.float32, np.float64):
        raise InputError(f"{path}: {what} must be floating point (OpenEXR), got {_describe(img)}")
    d = (img if img.ndim == 2 else img[..., 0]).astype(np.float32)
    if np.isnan(d).any() or (d < 0).any():
        raise InputError(f"{path}: {what} has NaN or negative values")
    d[np.isinf(d)] = 0.0
    return d
