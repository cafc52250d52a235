"""The same simulated frames written in the published layouts of UTS, SimCol3D and C3VD
(SPEC §5), so that each data set's loader can be tested on real files.

``generate_sequence(..., layout=NAME)`` writes them into ``OUT/NAME/`` beside the project's
own layout. Choices where the public descriptions are ambiguous (a loader must make the
same ones; ``params.json`` and ``camera.json`` of OUT hold the exact intrinsics):

Unity frame (UTS, SimCol3D): left-handed, y up. A camera-to-world pose (R, t) of ours
(right-handed, camera x right, y down, z forward, metres) is written as
``R_u = F R F``, ``t_u = F t`` with ``F = diag(1, -1, 1)``, translation in centimetres,
quaternion of ``R_u`` as ``qx qy qz qw`` (so ``(qx, qy, qz) -> (-qx, qy, -qz)``).
Reading back: ``R = F R_u F``, ``t = F t_u / 100``.

UTS (Zhang et al.)::

    Case0001/left/SUK_L00001.png                RGB, frames numbered from 1
    Case0001/left/SUK_L00001_depth.exr          float32, 3 equal channels, depth_mm / 5
    Case0001/Case0001_Camera Position L Data.txt         "Frame i X=x, Y=y, Z=z " (cm)
    Case0001/Case0001_Camera Quaternion Rotation Data.txt "Frame i X=qx, Y=qy, Z=qz, W=qw "
    Case0001/camera.json                        intrinsics of these frames (not in the original)

  Poses are relative to the first camera (frame 0 = origin, identity), one line per frame
  starting at ``Frame 0``; left camera only (no stereo pair).

SimCol3D (UCL)::

    SyntheticColon_C3F/Frames_S1/FrameBuffer_0000.png   RGB, numbered from 0
    SyntheticColon_C3F/Frames_S1/Depth_0000.png         uint16, 65535 = 20 cm (deeper: clipped to 65535)
    SyntheticColon_C3F/SavedPosition_S1.txt             "tx ty tz" per line (cm, Unity)
    SyntheticColon_C3F/SavedRotationQuaternion_S1.txt   "qx qy qz qw" per line (Unity)
    SyntheticColon_C3F/cam.txt                          K row-major on one line (9 numbers)
    misc/train_file.txt                                 "SyntheticColon_C3F/Frames_S1"

C3VD (print data)::

    c3f_sim/0000_color.png        RGB, numbered from 0
    c3f_sim/0000_depth.tiff       uint16, value / 65535 * 100 mm; 0 = no depth or beyond 100 mm
    c3f_sim/pose.txt              16 comma-separated numbers per line: the camera-to-world 4x4
                                  matrix flattened column-major (the last four are tx, ty, tz, 1),
                                  translation in mm
    c3f_sim/coverage_mesh.obj     the ground-truth mesh in mm
    c3f_sim/camera.json           pinhole intrinsics (C3VD's own are fisheye; not used here)
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from c3f_slam.geometry import invert_pose, matrix_to_quaternion

if TYPE_CHECKING:
    from datamodules.synthetic.generate import SimScene

FLIP_Y = np.diag([1.0, -1.0, 1.0])
SIMCOL_RANGE_M = 0.20
C3VD_RANGE_M = 0.10


def to_unity(T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Our camera-to-world pose -> (translation in cm, quaternion qx qy qz qw) in Unity's frame."""
    R = FLIP_Y @ T_wc[:3, :3] @ FLIP_Y
    return FLIP_Y @ T_wc[:3, 3] * 100.0, matrix_to_quaternion(R)


def _bgr(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)


def _imwrite(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


class _Layout:
    def __init__(self, root: Path, scene: "SimScene") -> None:
        self.root, self.scene = root, scene
        self.poses = scene.path.poses

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def finish(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _camera_json(self, folder: Path) -> None:
        (folder / "camera.json").write_text(json.dumps(self.scene.camera.to_dict(), indent=2) + "\n")


class UTSLayout(_Layout):
    def __init__(self, root: Path, scene: "SimScene") -> None:
        super().__init__(root, scene)
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # OpenCV writes EXR only when asked to
        self.case = root / "Case0001"
        (self.case / "left").mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        stem = self.case / "left" / f"SUK_L{i + 1:05d}"
        _imwrite(stem.with_suffix(".png"), _bgr(rgb))
        d = (depth.astype(np.float32) * 1000.0 / 5.0)[..., None].repeat(3, axis=2)
        _imwrite(Path(f"{stem}_depth.exr"), d)

    def finish(self) -> None:
        first = invert_pose(self.poses[0])
        pos, rot = [], []
        for i, T in enumerate(self.poses):
            t, q = to_unity(first @ T)
            pos.append(f"Frame {i} X={t[0]:.6f}, Y={t[1]:.6f}, Z={t[2]:.6f} ")
            rot.append(f"Frame {i} X={q[0]:.9f}, Y={q[1]:.9f}, Z={q[2]:.9f}, W={q[3]:.9f} ")
        (self.case / "Case0001_Camera Position L Data.txt").write_text("\n".join(pos) + "\n")
        (self.case / "Case0001_Camera Quaternion Rotation Data.txt").write_text("\n".join(rot) + "\n")
        self._camera_json(self.case)


class SimColLayout(_Layout):
    def __init__(self, root: Path, scene: "SimScene") -> None:
        super().__init__(root, scene)
        self.scene_dir = root / "SyntheticColon_C3F"
        self.frames = self.scene_dir / "Frames_S1"
        self.frames.mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        _imwrite(self.frames / f"FrameBuffer_{i:04d}.png", _bgr(rgb))
        v = np.clip(np.round(depth.astype(np.float64) / SIMCOL_RANGE_M * 65535.0), 0, 65535).astype(np.uint16)
        _imwrite(self.frames / f"Depth_{i:04d}.png", v)

    def finish(self) -> None:
        pos, rot = [], []
        for T in self.poses:
            t, q = to_unity(T)
            pos.append(f"{t[0]:.6f} {t[1]:.6f} {t[2]:.6f}")
            rot.append(f"{q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
        (self.scene_dir / "SavedPosition_S1.txt").write_text("\n".join(pos) + "\n")
        (self.scene_dir / "SavedRotationQuaternion_S1.txt").write_text("\n".join(rot) + "\n")
        K = self.scene.camera.K
        (self.scene_dir / "cam.txt").write_text(" ".join(f"{v:.6f}" for v in K.reshape(-1)) + "\n")
        (self.root / "misc").mkdir(exist_ok=True)
        (self.root / "misc" / "train_file.txt").write_text("SyntheticColon_C3F/Frames_S1\n")


class C3VDLayout(_Layout):
    def __init__(self, root: Path, scene: "SimScene") -> None:
        super().__init__(root, scene)
        self.seq = root / "c3f_sim"
        self.seq.mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        _imwrite(self.seq / f"{i:04d}_color.png", _bgr(rgb))
        d = depth.astype(np.float64)
        v = np.round(d / C3VD_RANGE_M * 65535.0)
        v = np.where((d > 0) & (v < 65535), v, 0).astype(np.uint16)
        _imwrite(self.seq / f"{i:04d}_depth.tiff", v)

    def finish(self) -> None:
        lines = []
        for T in self.poses:
            M = T.copy()
            M[:3, 3] *= 1000.0
            lines.append(",".join(f"{v:.9g}" for v in M.T.reshape(-1)))  # column-major
        (self.seq / "pose.txt").write_text("\n".join(lines) + "\n")
        import open3d as o3d

        mesh = self.scene.colon.to_legacy_mesh()
        mesh.scale(1000.0, center=np.zeros(3))
        o3d.io.write_triangle_mesh(str(self.seq / "coverage_mesh.obj"), mesh, write_vertex_normals=False,
                                   write_vertex_colors=False, write_triangle_uvs=False, print_progress=False)
        self._camera_json(self.seq)


_WRITERS = {"uts": UTSLayout, "simcol": SimColLayout, "c3vd": C3VDLayout}


def layout_writer(name: str, root: Path, scene: "SimScene") -> _Layout:
    """Writer of layout ``name`` (``uts``, ``simcol`` or ``c3vd``) into the folder ``root``."""
    return _WRITERS[name](Path(root), scene)
