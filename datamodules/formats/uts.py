"""UTS-synthetic (Zhang et al., the Unity colon simulator; released as
``colon_reconstruction_dataset``), read as published.

Layout of one case (the stereo release; the left camera is the reference)::

    Case0001/left/SUK_L00001.png ...                 RGB frames, numbered from 1
    Case0001/left/SUK_L_depth00001.exr ...           depth (the simulator's output; the public
                                                     release of the 15 cases has none)
    Case0001/<prefix>_Camera Position L Data.txt     camera positions, Unity frame, cm
    Case0001/<prefix>_Camera Quaternion Rotation Data.txt
    Case0001/right/ ...                              (not read)

Conventions chosen where the sources are ambiguous (each pinned by a test):

- **Frames and depth** are paired by the number in their file names (the README's MATLAB
  reads ``SUK_L%05d.png`` with ``SUK_L_depth%05d.exr``); any PNG/EXR of ``left/`` whose
  name holds "depth" is a depth file. Depth = EXR channel 0 x 5 = millimetres (README:
  ``depth_scale = 5.0``; the author confirmed it in the repository's issue 6), z-depth.
- **Pose lines**, two formats as the releases have them: ``Frame k X=x, Y=y, Z=z`` /
  ``Frame k X=qx, Y=qy, Z=qz, W=qw`` (k from 0), or numeric ``NNNNNN x, y, z`` after a header
  ``id tx ty tz`` (ids from 1). The first frame is the origin and **is not listed** (README:
  "the optical center of the first frame camera is used as the origin"): N frames come with
  N - 1 pose lines, line k being frame k + 1; any other count is an error.
- **Handedness**: Unity's left-handed frame, converted as the README does (:mod:`.unity`);
  positions are centimetres (README: ``transt*10`` "convert cm to mm"). Camera-to-world.
- **Intrinsics**: the simulator's physical camera, focal length 4.969783 mm on a
  10.26 x 7.695 mm sensor, with Unity's horizontal gate fit: square pixels,
  ``fx = fy = 4.969783 * W / 10.26`` for frames W pixels wide. This reproduces the README's
  release values (fx = fy = 232.504 for 480-px-wide frames) and its simulator example
  (155.0 for 320 x 240). The principal point is the image centre ((W - 1) / 2, (H - 1) / 2):
  Unity renders a symmetric frustum; the README's ``cx = cols / 2`` with MATLAB's 1-based
  pixels is half a pixel off it. Sequences rendered with another field of view: give
  ``fov`` (horizontal, degrees; square pixels) instead.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from datamodules.formats.base import (
    PublishedSequence,
    SequenceFormat,
    decode_float_depth,
    decode_rgb,
    list_files,
    numbered,
    single_match,
)
from datamodules.formats.unity import pose_from_unity

FOCAL_MM = 4.969783
SENSOR_WIDTH_MM = 10.26
SENSOR_HEIGHT_MM = 7.695
DEPTH_UNIT_M = 5.0e-3  # metres per EXR depth unit (x 5 = mm)
DEPTH_SCALE = 1.0e5  # depth units per metre when converted (10 um steps, up to 0.65 m)
POSITION_FILE = "*Camera Position L Data.txt"
ROTATION_FILE = "*Camera Quaternion Rotation Data.txt"

_NUM = r"([-+0-9.eE]+|nan|inf)"
_FRAME_POS = re.compile(rf"^Frame\s+(\d+)\s+X={_NUM},\s*Y={_NUM},\s*Z={_NUM}\s*$")
_FRAME_ROT = re.compile(rf"^Frame\s+(\d+)\s+X={_NUM},\s*Y={_NUM},\s*Z={_NUM},\s*W={_NUM}\s*$")


def intrinsics(width: int, height: int, fov: float | None = None) -> PinholeCamera:
    """The UTS camera for frames of ``width`` x ``height`` (see the module docstring)."""
    if fov is not None:
        return PinholeCamera.from_fov(width, height, fov, depth_scale=DEPTH_SCALE)
    f = FOCAL_MM * width / SENSOR_WIDTH_MM
    return PinholeCamera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, depth_scale=DEPTH_SCALE)


def read_pose_lines(path: Path, values: int) -> np.ndarray:
    """(M, values) rows of a UTS pose file in either line format (3 = position, 4 = quaternion)."""
    frame_re = _FRAME_POS if values == 3 else _FRAME_ROT
    rows: list[list[float]] = []
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.lower().startswith("id "):
            continue
        if line.startswith("Frame"):
            m = frame_re.match(line)
            if m is None:
                raise InputError(f"{path}:{lineno}: incomplete pose line {line[:60]!r} (truncated file?)")
            index, vals = int(m.group(1)), m.groups()[1:]
            expected = len(rows)  # "Frame k" lines count from 0
        else:
            parts = [p for p in re.split(r"[,\s]+", line) if p]
            if len(parts) != values + 1:
                hint = " (truncated file?)" if len(parts) < values + 1 else ""
                raise InputError(f"{path}:{lineno}: expected an id and {values} numbers, got {len(parts)} fields{hint}")
            index, vals = _int(parts[0], path, lineno), parts[1:]
            expected = len(rows) + 1  # numeric ids count from 1
        if index != expected:
            raise InputError(f"{path}:{lineno}: pose of frame {index} where {expected} was expected")
        try:
            nums = [float(v) for v in vals]
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line[:60]!r}") from None
        if not all(math.isfinite(v) for v in nums):
            raise InputError(f"{path}:{lineno}: non-finite value")
        rows.append(nums)
    return np.asarray(rows, dtype=np.float64).reshape(-1, values)


def _int(text: str, path: Path, lineno: int) -> int:
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{path}:{lineno}: expected a frame id, got {text!r}") from None


class UTSSequence(PublishedSequence):
    dataset = "UTS-synthetic"

    def decode_depth(self, path: Path) -> np.ndarray:
        return decode_float_depth(path, "UTS depth (OpenEXR)") * np.float32(DEPTH_UNIT_M)


class UTSFormat(SequenceFormat):
    """UTS-synthetic cases. ``fov``: horizontal field of view (degrees) of frames rendered
    with another camera than the release's (None = the release's physical camera)."""

    name = "uts"
    title = "UTS-synthetic"
    layout = "Case*/left/*.png, Case*/*_Camera Position L Data.txt, *_Camera Quaternion Rotation Data.txt"

    def __init__(self, fov: float | None = None) -> None:
        if fov is not None and not 0 < fov < 180:
            raise InputError(f"fov: horizontal field of view must be in (0, 180) degrees, got {fov}")
        self.fov = fov

    def is_sequence(self, folder: Path) -> bool:
        left = folder / "left"
        return left.is_dir() and any(p.suffix.lower() == ".png" for p in left.iterdir())

    def open(self, folder: Path) -> UTSSequence:
        folder = Path(folder)
        left = folder / "left"
        if not self.is_sequence(folder):
            raise InputError(f"{folder}: not a UTS-synthetic case (expected left/*.png)")
        pngs = [p for p in list_files(left, (".png",)) if "depth" not in p.name.lower()]
        frames = numbered(pngs)
        if not frames:
            raise InputError(f"{left}: no numbered colour frames")
        depth_files = numbered(p for p in list_files(left, (".exr",)) if "depth" in p.name.lower())
        depth_paths = None
        if depth_files:
            missing = [k for k in frames if k not in depth_files]
            if missing:
                raise InputError(f"{left}: no depth EXR for frame {missing[0]} ({len(missing)} frame(s) without depth)")
            depth_paths = [depth_files[k] for k in frames]
        poses = self._poses(folder, len(frames))
        rgb_paths = list(frames.values())
        h, w = decode_rgb(rgb_paths[0]).shape[:2]
        return UTSSequence(folder.name, folder, intrinsics(w, h, self.fov), rgb_paths, depth_paths, poses)

    @staticmethod
    def _poses(folder: Path, n_frames: int) -> np.ndarray:
        pos_file = single_match(folder, POSITION_FILE, "UTS camera position file (left camera)")
        rot_file = single_match(folder, ROTATION_FILE, "UTS camera rotation file")
        pos, rot = read_pose_lines(pos_file, 3), read_pose_lines(rot_file, 4)
        if len(pos) != len(rot):
            raise InputError(f"{pos_file}: {len(pos)} positions but {rot_file.name} has {len(rot)} rotations")
        if len(pos) != n_frames - 1:
            raise InputError(f"{pos_file}: {len(pos)} poses for {n_frames} frames (expected {n_frames - 1}: the "
                             "first frame is the origin and is not listed)")
        poses = [np.eye(4)]
        for k, (t, q) in enumerate(zip(pos, rot)):
            try:
                poses.append(pose_from_unity(t, q))
            except ValueError:
                raise InputError(f"{rot_file}: rotation of frame {k + 1} is a zero quaternion") from None
        return np.asarray(poses)
