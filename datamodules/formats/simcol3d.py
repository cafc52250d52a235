"""SimCol3D (UCL, the MICCAI 2022 SimCol-to-3D challenge data), read as published.

Layout::

    SyntheticColon_I/Frames_S1/FrameBuffer_0000.png ...   RGB(A) frames, numbered from 0
    SyntheticColon_I/Frames_S1/Depth_0000.png ...         16-bit depth
    SyntheticColon_I/SavedPosition_S1.txt                 "tx ty tz" per frame, cm, Unity frame
    SyntheticColon_I/SavedRotationQuaternion_S1.txt       "qx qy qz qw" per frame, Unity frame
    SyntheticColon_I/cam.txt                              intrinsics, 9 numbers on one line
    misc/train_file.txt, misc/test_file.txt               the release's split ("SyntheticColon_I/Frames_S1")

(SyntheticColon_II holds Frames_B*, SyntheticColon_III Frames_O*; the pose files carry the
same code: SavedPosition_B1.txt, ...). A sequence is named ``<scene>_<frames folder>``, e.g.
``SyntheticColon_I_Frames_S1``.

Conventions chosen where the sources are ambiguous (each pinned by a test):

- **Frames** are PNGs with 4 channels (RGBA, stored with 16 bits per channel in the release);
  alpha is dropped and 16-bit values are rounded to 8 bits. 8-bit RGB(A) files load too.
- **Depth**: 16-bit, ``depth_cm = value / 256 / 255 * 20`` as the release's evaluation code
  reads it ("please use this to load ground truth depth"), i.e. 65,280 = 20 cm. The saturated
  value 65,535 (20.08 cm by that rule) means "at or beyond the far limit" and becomes 0 = no
  depth. Other bit depths are an error. z-depth.
- **Poses**: line i is frame i (one line per frame, no header), camera-to-world in Unity's
  left-handed frame, converted as the release's ``read_poses.py`` does: ``TM @ P @ TM`` with
  TM = diag(1, -1, 1, 1) (:mod:`.unity`); positions in centimetres. Frames are matched to
  lines by their number, so a frame removed from the folder does not shift the others.
- **cam.txt** is read like the release's code (9 numbers, row-major 3 x 3), but the file's
  entries are inconsistent as a matrix (the release's reads ``227.60416 0 227.60416 0 237.5
  237.5 0 0 1``: principal point (227.6, 237.5) in a 475-px image, fx != fy). Unity renders a
  symmetric frustum with square pixels, so the focal length is the first number
  (``fx = fy = K[0, 0]``) and the principal point the image centre ((W - 1) / 2, (H - 1) / 2);
  the other entries are not used.
- **Split**: ``misc/train_file.txt`` / ``test_file.txt`` list ``<scene>/Frames_X`` per line
  (a trailing '/' is ignored); they are the default split of the data module.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
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
from datamodules.formats.unity import pose_from_unity

DEPTH_FULL_SCALE = 65280  # 16-bit value of 20 cm (the release's / 256 / 255 * 20)
DEPTH_RANGE_M = 0.20
SATURATED = 65535
DEPTH_SCALE = DEPTH_FULL_SCALE / DEPTH_RANGE_M  # units per metre: converted depth keeps the raw values
_FRAME = re.compile(r"^FrameBuffer_(\d+)\.png$", re.IGNORECASE)
_DEPTH = re.compile(r"^Depth_(\d+)\.png$", re.IGNORECASE)


def read_cam_txt(path: Path, width: int, height: int) -> PinholeCamera:
    """Intrinsics from a SimCol3D ``cam.txt`` for frames of ``width`` x ``height``: its 9
    numbers as a row-major 3 x 3 matrix (the release's ``genfromtxt(...).reshape((3, 3))``);
    only the focal length K[0, 0] is used (module docstring)."""
    require_file(path, "SimCol3D camera file (cam.txt)")
    try:
        nums = [float(x) for x in path.read_text().replace(",", " ").split()]
    except (ValueError, UnicodeDecodeError):
        raise InputError(f"{path}: expected 9 numbers (a 3x3 intrinsic matrix)") from None
    if len(nums) != 9:
        raise InputError(f"{path}: expected 9 numbers (a 3x3 intrinsic matrix), got {len(nums)}")
    K = np.asarray(nums).reshape(3, 3)
    if not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise InputError(f"{path}: not an intrinsic matrix (last row {K[2].tolist()}, expected 0 0 1)")
    f = float(K[0, 0])
    if not (np.isfinite(f) and f > 0):
        raise InputError(f"{path}: focal length must be positive, got {f}")
    return PinholeCamera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, depth_scale=DEPTH_SCALE)


class SimCol3DSequence(PublishedSequence):
    dataset = "SimCol3D"

    def decode_depth(self, path: Path) -> np.ndarray:
        raw = decode_uint16(path, "SimCol3D depth")
        d = raw.astype(np.float32) * np.float32(DEPTH_RANGE_M / DEPTH_FULL_SCALE)
        d[raw == SATURATED] = 0.0
        return d


class SimCol3DFormat(SequenceFormat):
    name = "simcol3d"
    title = "SimCol3D"
    layout = ("SyntheticColon_*/Frames_*/FrameBuffer_NNNN.png + Depth_NNNN.png, "
              "SyntheticColon_*/SavedPosition_*.txt, SavedRotationQuaternion_*.txt, cam.txt")

    def is_sequence(self, folder: Path) -> bool:
        return folder.name.startswith("Frames_") and any(_FRAME.match(p.name) for p in folder.glob("FrameBuffer_*"))

    def sequence_name(self, folder: Path) -> str:
        """``<scene>_<frames folder>``, e.g. ``SyntheticColon_I_Frames_S1``."""
        return f"{Path(folder).parent.name}_{Path(folder).name}"

    def open(self, folder: Path) -> SimCol3DSequence:
        folder = Path(folder)
        if not self.is_sequence(folder):
            raise InputError(f"{folder}: not a SimCol3D frames folder (expected Frames_*/FrameBuffer_NNNN.png)")
        scene, code = folder.parent, folder.name[len("Frames_"):]
        files = list_files(folder, (".png",))
        frames, depths = numbered(files, _FRAME), numbered(files, _DEPTH)
        missing = [k for k in frames if k not in depths]
        if missing:
            raise InputError(f"{folder}: no Depth_{missing[0]:04d}.png for FrameBuffer_{missing[0]:04d}.png "
                             f"({len(missing)} frame(s) without depth)")
        pos_file = scene / f"SavedPosition_{code}.txt"
        rot_file = scene / f"SavedRotationQuaternion_{code}.txt"
        pos = read_number_rows(require_file(pos_file, "SimCol3D position file"), 3, what="position values")
        rot = read_number_rows(require_file(rot_file, "SimCol3D rotation file"), 4, what="quaternion values")
        if len(pos) != len(rot):
            raise InputError(f"{pos_file}: {len(pos)} positions but {rot_file.name} has {len(rot)} rotations")
        check_pose_count(len(pos), frames, pos_file)
        poses = []
        for k in frames:
            try:
                poses.append(pose_from_unity(pos[k], rot[k]))
            except ValueError:
                raise InputError(f"{rot_file}:{k + 1}: zero quaternion") from None
        rgb_paths = list(frames.values())
        h, w = decode_rgb(rgb_paths[0]).shape[:2]
        camera = read_cam_txt(scene / "cam.txt", w, h)
        return SimCol3DSequence(self.sequence_name(folder), folder, camera, rgb_paths,
                                [depths[k] for k in frames], np.asarray(poses))

    def published_split(self, root: Path) -> dict[str, list[str]] | None:
        """``{"train": [...], "test": [...]}`` from ``root/misc/*_file.txt`` (names as
        :meth:`sequence_name` gives them), or None when ``root`` has no such files."""
        misc = Path(root) / "misc"
        out: dict[str, list[str]] = {}
        for split in ("train", "test"):
            path = misc / f"{split}_file.txt"
            if path.is_file():
                out[split] = [self._entry_name(line) for line in path.read_text().splitlines() if line.strip()]
        return out or None

    @staticmethod
    def _entry_name(line: str) -> str:
        parts = [p for p in line.strip().strip("/").split("/") if p]
        return "_".join(parts[-2:])
