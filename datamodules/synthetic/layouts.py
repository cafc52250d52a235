"""The same simulated sequence written in the published layouts of UTS-synthetic, SimCol3D,
C3VD and Colon10K (docs/datasets.md, Published data sets), quirks included, so that each loader in
:mod:`datamodules.formats` is tested on files as the data sets publish them.

``generate_sequence(..., layout=NAME)`` writes them into ``OUT/NAME/`` beside the project's
own layout (which holds the exact depth, poses and intrinsics to compare with). No writer
adds a file the published data does not have (no ``camera.json``): the loaders must find the
intrinsics where the data sets keep them. The writers get the frames as rendered: the nuisances
of real recordings (``SimParams.nuisance``) go into the project's layout only. What each writer
reproduces:

UTS (``uts``)::

    Case0001/left/SUK_L00001.png                     RGB, frames numbered from 1
    Case0001/left/SUK_L_depth00001.exr               float32, 3 equal channels, depth_mm / 5
    Case0001/Case0001_Camera Position L Data.txt     "Frame k X=x, Y=y, Z=z " (cm, Unity frame)
    Case0001/Case0001_Camera Quaternion Rotation Data.txt   "Frame k X=qx, Y=qy, Z=qz, W=qw "

  Poses relative to the first camera, which is not listed: line k is frame k + 2 of the
  names above (0-based frame k + 1). The release's camera has a 91.8 degree horizontal field
  of view (4.969783 mm on a 10.26 mm sensor); frames simulated with another ``camera.fov``
  load with the reader's ``fov`` option.

SimCol3D (``simcol3d``)::

    SyntheticColon_C3F/Frames_S1/FrameBuffer_0000.png   16-bit RGBA, numbered from 0
    SyntheticColon_C3F/Frames_S1/Depth_0000.png         uint16, 65280 = 20 cm (deeper: 65535)
    SyntheticColon_C3F/SavedPosition_S1.txt             "tx ty tz" per line (cm, Unity frame)
    SyntheticColon_C3F/SavedRotationQuaternion_S1.txt   "qx qy qz qw" per line (Unity frame)
    SyntheticColon_C3F/cam.txt                          "f 0 f 0 W/2 H/2 0 0 1", the release's pattern
    misc/train_file.txt, misc/test_file.txt             "SyntheticColon_C3F/Frames_S1" in train

C3VD (``c3vd``): frames **rendered through C3VD's fisheye** (its published omnidirectional
calibration, scaled to the frame size: frames must have its 5:4 aspect, e.g. 135 x 108)::

    c3f_sim/0000_color.png        RGB, numbered from 0, black beyond 85 degrees off the axis
    c3f_sim/0000_depth.tiff       uint16, floor(65535 * depth / 100 mm), 0 = none, 65535 = clipped
    c3f_sim/pose.txt              camera-to-world 4x4 column-major (translation = numbers 13-15),
                                  mm, 6 significant digits (C++ stream defaults, as C3VD's writer)
    c3f_sim/coverage_mesh.obj     the mesh in mm; "vt 0.0 0.0" / "vt 1.0 1.0" and faces
                                  "f a/1 b/1 c/1" where a pixel of some frame saw the face, "/2" elsewhere

Colon10K (``colon10k``)::

    c3f_sim/image/00000.jpg       JPEG frames, numbered from 0
    calib_<W>_<H>.txt             "Pinhole fx fy cx cy 0" / "W H" (the simulator's exact camera)
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.geometry import invert_pose
from datamodules.formats import c3vd, simcol3d, uts
from datamodules.formats.omnicam import C3VD_CALIBRATION
from datamodules.formats.unity import pose_to_unity
from datamodules.synthetic.render import Renderer
from datamodules.synthetic.scene import SimScene, render_frames

C3VD_MAX_ANGLE_DEG = 85.0  # fisheye pixels further off the axis are masked (black, no depth)


def _bgr(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)


def _imwrite(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


class _Layout:
    def __init__(self, root: Path, scene: SimScene) -> None:
        self.root, self.scene = root, scene
        self.poses = scene.path.poses

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def finish(self) -> None:
        """Write what follows the frames (poses, calibration, mesh)."""


class UTSLayout(_Layout):
    def __init__(self, root: Path, scene: SimScene) -> None:
        super().__init__(root, scene)
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # OpenCV writes EXR only when asked to
        self.case = root / "Case0001"
        (self.case / "left").mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        left = self.case / "left"
        _imwrite(left / f"SUK_L{i + 1:05d}.png", _bgr(rgb))
        d = (depth.astype(np.float32) / np.float32(uts.DEPTH_UNIT_M))[..., None].repeat(3, axis=2)
        _imwrite(left / f"SUK_L_depth{i + 1:05d}.exr", d)

    def finish(self) -> None:
        first = invert_pose(self.poses[0])
        pos, rot = [], []
        for k, T in enumerate(self.poses[1:]):
            t, q = pose_to_unity(first @ T)
            pos.append(f"Frame {k} X={t[0]:.6f}, Y={t[1]:.6f}, Z={t[2]:.6f} ")
            rot.append(f"Frame {k} X={q[0]:.9f}, Y={q[1]:.9f}, Z={q[2]:.9f}, W={q[3]:.9f} ")
        (self.case / "Case0001_Camera Position L Data.txt").write_text("\n".join(pos) + "\n")
        (self.case / "Case0001_Camera Quaternion Rotation Data.txt").write_text("\n".join(rot) + "\n")


class SimColLayout(_Layout):
    def __init__(self, root: Path, scene: SimScene) -> None:
        super().__init__(root, scene)
        self.scene_dir = root / "SyntheticColon_C3F"
        self.frames = self.scene_dir / "Frames_S1"
        cam = scene.camera
        if not (math.isclose(cam.fx, cam.fy) and math.isclose(cam.cx, (cam.width - 1) / 2)
                and math.isclose(cam.cy, (cam.height - 1) / 2)):
            raise InputError("layout simcol3d: SimCol3D's cam.txt holds one focal length; the camera needs square "
                             "pixels and a centred principal point")
        self.frames.mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        rgba = np.concatenate([_bgr(rgb), np.full(rgb.shape[:2] + (1,), 255, np.uint8)], axis=2)
        _imwrite(self.frames / f"FrameBuffer_{i:04d}.png", rgba.astype(np.uint16) * 257)
        v = np.round(depth.astype(np.float64) * simcol3d.DEPTH_SCALE)
        _imwrite(self.frames / f"Depth_{i:04d}.png", np.clip(v, 0, simcol3d.SATURATED).astype(np.uint16))

    def finish(self) -> None:
        pos, rot = [], []
        for T in self.poses:
            t, q = pose_to_unity(T)
            pos.append(f"{t[0]:.6f} {t[1]:.6f} {t[2]:.6f}")
            rot.append(f"{q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
        (self.scene_dir / "SavedPosition_S1.txt").write_text("\n".join(pos) + "\n")
        (self.scene_dir / "SavedRotationQuaternion_S1.txt").write_text("\n".join(rot) + "\n")
        cam = self.scene.camera
        (self.scene_dir / "cam.txt").write_text(
            f"{cam.fx:.5f} 0 {cam.fx:.5f} 0 {cam.width / 2} {cam.height / 2} 0 0 1\n")
        (self.root / "misc").mkdir(exist_ok=True)
        (self.root / "misc" / "train_file.txt").write_text("SyntheticColon_C3F/Frames_S1\n")
        (self.root / "misc" / "test_file.txt").write_text("")


class C3VDLayout(_Layout):
    def __init__(self, root: Path, scene: SimScene) -> None:
        super().__init__(root, scene)
        cam = scene.camera
        try:
            self.omni = C3VD_CALIBRATION.scaled(cam.width, cam.height)
        except InputError:
            raise InputError(f"layout c3vd: frames must have C3VD's 5:4 aspect (1350x1080 or scaled, e.g. "
                             f"135x108), got {cam.width}x{cam.height}") from None
        rays = self.omni.pixel_rays()
        self.valid = rays[2] > math.cos(math.radians(C3VD_MAX_ANGLE_DEG))
        dirs = np.where(self.valid, rays / np.where(self.valid, rays[2], 1.0), np.array([[0.0], [0.0], [1.0]]))
        o = self.omni
        self.renderer = Renderer(scene.colon, scene.atlas, PinholeCamera(o.width, o.height, o.a0, o.a0, o.cx, o.cy),
                                 scene.params.appearance, scene=scene.raycaster, rays_cam=dirs)
        self.views = render_frames(scene, self.renderer)
        self.seq = root / "c3f_sim"
        self.seq.mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        k, rgb_f, depth_f = next(self.views)  # the same frame through the fisheye
        if k != i:
            raise RuntimeError(f"layout c3vd: frames written out of order ({i} after {k - 1})")
        mask = self.valid.reshape(depth_f.shape)
        rgb_f = np.where(mask[..., None], rgb_f, 0).astype(np.uint8)
        _imwrite(self.seq / f"{i:04d}_color.png", _bgr(rgb_f))
        v = np.floor(np.clip(depth_f.astype(np.float64) / c3vd.DEPTH_RANGE_M, 0.0, 1.0) * c3vd.DEPTH_FULL_SCALE)
        _imwrite(self.seq / f"{i:04d}_depth.tiff", np.where(mask, v, 0).astype(np.uint16))

    def finish(self) -> None:
        lines = []
        for T in self.poses:
            M = T.copy()
            M[:3, 3] /= c3vd.MM
            lines.append(",".join(f"{v:.6g}" for v in M.T.reshape(-1)))  # glm column-major, ostream precision
        (self.seq / "pose.txt").write_text("\n".join(lines) + "\n")
        self._write_coverage_mesh()

    def _write_coverage_mesh(self) -> None:
        colon = self.scene.colon
        seen = np.zeros(len(colon.triangles), bool)
        for T in self.poses:
            hits = self.renderer.trace(T)
            hit = np.isfinite(hits.t) & self.valid
            seen[hits.prim[hit]] = True
        out = ["# C3VD-style coverage mesh (c3f simulator), mm"]
        out += [f"v {x:.6g} {y:.6g} {z:.6g}" for x, y, z in colon.vertices.astype(np.float64) / c3vd.MM]
        out += ["vt 0.0 0.0", "vt 1.0 1.0"]
        tri = colon.triangles.astype(np.int64) + 1
        out += [f"f {a}/{t} {b}/{t} {c}/{t}" for (a, b, c), t in zip(tri, np.where(seen, 1, 2))]
        (self.seq / "coverage_mesh.obj").write_text("\n".join(out) + "\n")


class Colon10KLayout(_Layout):
    def __init__(self, root: Path, scene: SimScene) -> None:
        super().__init__(root, scene)
        self.images = root / "c3f_sim" / "image"
        self.images.mkdir(parents=True, exist_ok=True)

    def write_frame(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> None:
        _imwrite(self.images / f"{i:05d}.jpg", _bgr(rgb))

    def finish(self) -> None:
        c = self.scene.camera
        (self.root / f"calib_{c.width}_{c.height}.txt").write_text(
            f"Pinhole {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r} 0\n{c.width} {c.height}\ncrop\n{c.width} {c.height}\n")


_WRITERS = {"uts": UTSLayout, "simcol3d": SimColLayout, "c3vd": C3VDLayout, "colon10k": Colon10KLayout}


def layout_writer(name: str, root: Path, scene: SimScene) -> _Layout:
    """Writer of layout ``name`` (``uts``, ``simcol3d``, ``c3vd`` or ``colon10k``) into the folder ``root``."""
    return _WRITERS[name](Path(root), scene)
