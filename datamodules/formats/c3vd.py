"""C3VD (Colonoscopy 3D Video Dataset, Bobrow et al. 2023; the public printed-phantom data,
the paper's "print data"), read as published.

Layout of one registered sequence (C3VD; C3VDv2 keeps the same files in sub-folders
``rgb/NNNN.png`` and ``depth/NNNN_depth.tiff`` and ships ``camera_intrinsics.txt``)::

    cecum_t1_a/0000_color.png ...     RGB frames, 1350 x 1080, distorted (fisheye)
    cecum_t1_a/0000_depth.tiff ...    uint16, value / 65535 * 100 mm, z-depth in the fisheye geometry
    cecum_t1_a/pose.txt               one line per frame: 16 comma-separated numbers, camera-to-world, mm
    cecum_t1_a/coverage_mesh.obj      the registered phantom surface, mm; texture coordinate 1 (0, 0) =
                                      face observed in some frame, 2 (1, 1) = never observed
    (NNNN_normals.tiff, NNNN_occlusion.png, NNNN_flow.tiff: not read)

Conventions chosen where the sources are ambiguous (each pinned by a test):

- **Frames** are numbered from 0; the number may be zero-padded or not (the first release of
  ``cecum_t1_a`` was not). Pose line n is frame n.
- **Depth**: 0 (no surface, masked corner) and 65535 (clipped at >= 100 mm) are "no depth",
  as C3VD's ``exampleDataLoader.py`` treats them; other bit depths are an error.
- **pose.txt** holds the camera-to-world matrix **column-major** (C3VD's renderer writes
  glm's ``m[col][row]``: the translation is the 13th-15th numbers); the dataset page says
  "row-major" and some copies are. The storage order is decided per file from where the
  translation sits (a file whose translations are all zero counts as column-major) and the
  matrix must be rigid. Millimetres. The camera frame is OpenCV's (author, C3VD issue 3).
- **Camera**: C3VD's omnidirectional calibration (:mod:`.omnicam`; default
  :data:`~.omnicam.C3VD_CALIBRATION`, or ``camera_intrinsics.txt`` found in the sequence
  folder or up to two folders above it, or a file given as ``calibration``), scaled when the
  frames were resized. Frames and depth are **undistorted to a pinhole camera** with OpenCV
  (``cv2.remap``: bilinear for colour, nearest for depth, so depth values stay exact
  z-depths): same size, principal point at the image centre, focal length ``pinhole_focal``
  (default the calibration's a0, 769.2 px: about 82 x 70 degrees of the fisheye's field).
  Those pinhole intrinsics are what the project uses.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from c3f_core.errors import InputError
from c3f_slam.geometry import is_rotation
from datamodules.formats.base import (
    PublishedSequence,
    SequenceFormat,
    check_pose_count,
    decode_rgb,
    decode_uint16,
    list_files,
    numbered,
    read_number_rows,
    require_file,
)
from datamodules.formats.omnicam import C3VD_CALIBRATION, OmniCamera

DEPTH_RANGE_M = 0.100
DEPTH_FULL_SCALE = 65535
DEPTH_SCALE = DEPTH_FULL_SCALE / DEPTH_RANGE_M  # units per metre: converted depth keeps the raw values
MM = 1e-3
CALIBRATION_FILE = "camera_intrinsics.txt"
_COLOR_V1 = re.compile(r"^(\d+)_color\.png$", re.IGNORECASE)
_COLOR_V2 = re.compile(r"^(\d+)(?:_color)?\.png$", re.IGNORECASE)
_DEPTH = re.compile(r"^(\d+)_depth\.tiff?$", re.IGNORECASE)


def read_pose_file(path: Path) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses in metres from a C3VD ``pose.txt`` (module docstring)."""
    rows = read_number_rows(path, 16, sep=",", what="matrix entries")
    M = rows.reshape(-1, 4, 4)
    t_last_row = np.abs(M[:, 3, :3]).max(axis=1) > 0  # column-major storage puts t here
    t_last_col = np.abs(M[:, :3, 3]).max(axis=1) > 0
    if (t_last_row & t_last_col).any():
        k = int(np.flatnonzero(t_last_row & t_last_col)[0])
        raise InputError(f"{path}:{k + 1}: not a rigid transform (non-zero last row and last column)")
    if t_last_row.any() and t_last_col.any():
        raise InputError(f"{path}: lines disagree on the storage order (translation in the 4th, 8th, 12th "
                         "numbers on some lines, in the 13th-15th on others)")
    T = M if t_last_col.any() else np.transpose(M, (0, 2, 1))
    for k, P in enumerate(T):
        if not (is_rotation(P[:3, :3], atol=1e-4) and np.allclose(P[3], [0, 0, 0, 1], atol=1e-6)):
            raise InputError(f"{path}:{k + 1}: not a rigid camera-to-world transform")
    T = T.copy()
    T[:, :3, 3] *= MM
    return T


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices (V, 3), triangles (F, 3) and, when faces carry C3VD's coverage texture
    coordinates, per-triangle ``observed`` flags (texture coordinate 1 = observed); polygons
    are fanned into triangles. Units as in the file."""
    require_file(path, "mesh")
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    tex: list[int] = []
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text OBJ file") from None
    for lineno, line in enumerate(text.splitlines(), start=1):
        if line.startswith("v "):
            parts = line.split()
            if len(parts) < 4:
                raise InputError(f"{path}:{lineno}: vertex with {len(parts) - 1} coordinates (truncated file?)")
            verts.append([float(parts[1]), float(parts[2]), float(parts[3])])
        elif line.startswith("f "):
            corners = [c.split("/") for c in line.split()[1:]]
            if len(corners) < 3:
                raise InputError(f"{path}:{lineno}: face with {len(corners)} corners (truncated file?)")
            try:
                idx = [int(c[0]) for c in corners]
                t = int(corners[0][1]) if len(corners[0]) > 1 and corners[0][1] else 0
            except ValueError:
                raise InputError(f"{path}:{lineno}: face with a non-integer index: {line.strip()[:60]!r}") from None
            for k in range(1, len(idx) - 1):
                tris.append((idx[0], idx[k], idx[k + 1]))
                tex.append(t)
    if not verts or not tris:
        raise InputError(f"{path}: no triangles")
    V = np.asarray(verts, dtype=np.float64)
    F = np.asarray(tris, dtype=np.int64)
    F = np.where(F > 0, F - 1, F + len(V))  # OBJ indices are 1-based; negative ones count from the end
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"{path}: a face refers to a vertex that does not exist")
    return V, F, _coverage_flags(path, np.asarray(tex))


def _coverage_flags(path: Path, tex: np.ndarray) -> np.ndarray | None:
    """Observed flags from the faces' texture coordinate indices (0 = none on that face): None
    when no face has one; InputError when only some have or one is neither 1 nor 2."""
    if not (tex != 0).any():
        return None
    if (tex == 0).any():
        raise InputError(f"{path}: {int((tex == 0).sum())} of {len(tex)} faces have no coverage texture "
                         "coordinate (expected f a/1 ... = observed or f a/2 ... = never observed on every face)")
    bad = ~np.isin(tex, (1, 2))
    if bad.any():
        raise InputError(f"{path}: coverage texture coordinate {int(tex[bad][0])} on a face (expected 1 = observed, "
                         "2 = never observed)")
    return tex == 1


class C3VDSequence(PublishedSequence):
    """A C3VD sequence; frames and depth come undistorted to :attr:`camera` (a pinhole)."""

    dataset = "C3VD"

    def __init__(self, *args, omni: OmniCamera, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.omni = omni
        self._maps: tuple[np.ndarray, np.ndarray] | None = None

    def _undistort(self, img: np.ndarray, path: Path, interpolation: int) -> np.ndarray:
        h, w = img.shape[:2]
        if (w, h) != (self.omni.width, self.omni.height):
            raise InputError(f"{path}: frame is {w}x{h} but the calibration is for "
                             f"{self.omni.width}x{self.omni.height}")
        if self._maps is None:
            self._maps = self.omni.undistort_maps(self.camera)
        return cv2.remap(img, *self._maps, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def decode_rgb(self, path: Path) -> np.ndarray:
        return self._undistort(decode_rgb(path), path, cv2.INTER_LINEAR)

    def decode_depth(self, path: Path) -> np.ndarray:
        raw = decode_uint16(path, "C3VD depth")
        raw = np.where(raw == DEPTH_FULL_SCALE, 0, raw).astype(np.uint16)
        raw = self._undistort(raw, path, cv2.INTER_NEAREST)
        return raw.astype(np.float32) * np.float32(DEPTH_RANGE_M / DEPTH_FULL_SCALE)

    def read_mesh(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self.mesh_path is None:
            return None
        V, F, _ = read_obj(self.mesh_path)
        return V * MM, F

    def read_coverage(self) -> np.ndarray | None:
        """Per-triangle flags of :meth:`read_mesh`: True where C3VD saw the face in some frame."""
        if self.mesh_path is None:
            return None
        return read_obj(self.mesh_path)[2]


class C3VDFormat(SequenceFormat):
    """C3VD sequences. ``calibration``: an omnidirectional calibration file to use instead of
    the one found beside the data (or C3VD's published one); ``pinhole_focal``: focal length
    (pixels, at the frames' size) of the pinhole camera frames are undistorted to."""

    name = "c3vd"
    title = "C3VD"
    layout = "<seq>/NNNN_color.png + NNNN_depth.tiff + pose.txt (or rgb/, depth/ sub-folders), coverage_mesh.obj"

    def __init__(self, calibration: str | Path | None = None, pinhole_focal: float | None = None) -> None:
        self.calibration = OmniCamera.from_file(calibration) if calibration is not None else None
        if pinhole_focal is not None and not pinhole_focal > 0:
            raise InputError(f"pinhole_focal: must be a positive number of pixels, got {pinhole_focal}")
        self.pinhole_focal = pinhole_focal

    def is_sequence(self, folder: Path) -> bool:
        if not (folder / "pose.txt").is_file():
            return False
        if any(_COLOR_V1.match(p.name) for p in folder.glob("*_color.png")):
            return True
        return (folder / "rgb").is_dir() and any(_COLOR_V2.match(p.name) for p in (folder / "rgb").glob("*.png"))

    def _calibration_for(self, folder: Path) -> OmniCamera:
        if self.calibration is not None:
            return self.calibration
        for parent in (folder, folder.parent, folder.parent.parent):
            if (parent / CALIBRATION_FILE).is_file():
                return OmniCamera.from_file(parent / CALIBRATION_FILE)
        return C3VD_CALIBRATION

    def open(self, folder: Path) -> C3VDSequence:
        folder = Path(folder)
        if not self.is_sequence(folder):
            raise InputError(f"{folder}: not a C3VD sequence (expected NNNN_color.png frames and pose.txt)")
        v2 = not any(_COLOR_V1.match(p.name) for p in folder.glob("*_color.png"))
        colour_dir, depth_dir = (folder / "rgb", folder / "depth") if v2 else (folder, folder)
        frames = numbered(list_files(colour_dir, (".png",)), _COLOR_V2 if v2 else _COLOR_V1)
        depths = numbered(list_files(depth_dir, (".tif", ".tiff")), _DEPTH)
        depth_paths = None
        if depths:
            missing = [k for k in frames if k not in depths]
            if missing:
                raise InputError(f"{depth_dir}: no depth file for frame {missing[0]} "
                                 f"({len(missing)} frame(s) without depth)")
            depth_paths = [depths[k] for k in frames]
        pose_file = folder / "pose.txt"
        poses = read_pose_file(pose_file)
        check_pose_count(len(poses), frames, pose_file)
        rgb_paths = list(frames.values())
        h, w = decode_rgb(rgb_paths[0]).shape[:2]
        try:
            omni = self._calibration_for(folder).scaled(w, h)
        except InputError as exc:
            raise InputError(f"{rgb_paths[0]}: {exc}") from None
        camera = omni.pinhole(self.pinhole_focal, depth_scale=DEPTH_SCALE)
        mesh = folder / "coverage_mesh.obj"
        return C3VDSequence(folder.name, folder, camera, rgb_paths=rgb_paths, depth_paths=depth_paths,
                            poses=poses[list(frames)], mesh_path=mesh if mesh.is_file() else None, omni=omni)
