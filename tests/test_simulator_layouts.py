"""The simulator's UTS / SimCol3D / C3VD layouts hold the same frames, depth and poses as
its own layout (conventions documented in datamodules/synthetic/layouts.py)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from c3f_slam import geometry as g
from c3f_slam.io import Sequence
from datamodules.synthetic import generate_sequence, tiny_params

F = np.diag([1.0, -1.0, 1.0])


def _from_unity(t_cm, q) -> np.ndarray:
    R = F @ g.quaternion_to_matrix(q) @ F
    return g.make_pose(R, F @ np.asarray(t_cm) / 100.0)


@pytest.fixture(scope="module", params=["uts", "simcol", "c3vd"])
def layout(request, tmp_path_factory) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp(request.param) / "seq"
    generate_sequence(tiny_params(frames=4, size=48, seed=3), out, progress=False, layout=request.param)
    return request.param, out


def test_layout_matches_the_project_layout(layout):
    name, out = layout
    seq = Sequence(out)
    root = out / name
    depth0 = seq.read_depth(2).astype(np.float64)
    q = 0.5 / seq.camera.depth_scale + 1e-6  # the project layout stores 0.1 mm steps
    rgb0 = seq.read_rgb(2)
    if name == "uts":
        case = root / "Case0001"
        rgb = cv2.imread(str(case / "left" / "SUK_L00003.png"))[..., ::-1]
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
        d = cv2.imread(str(case / "left" / "SUK_L00003_depth.exr"), cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH)[..., 0] * 5.0 / 1000.0
        pos = [line for line in (case / "Case0001_Camera Position L Data.txt").read_text().splitlines() if line]
        rot = [line for line in (case / "Case0001_Camera Quaternion Rotation Data.txt").read_text().splitlines() if line]
        assert len(pos) == len(rot) == 4 and pos[0].startswith("Frame 0 X=")

        def parse(line, keys):
            return [float(line.split(f"{k}=")[1].split(",")[0].split()[0]) for k in keys]

        poses = [_from_unity(parse(p, "XYZ"), parse(r, "XYZW")) for p, r in zip(pos, rot)]
        expected = [g.relative_pose(seq.pose(0), seq.pose(i)) for i in range(4)]
        assert_allclose(d, depth0, atol=q)
    elif name == "simcol":
        scene = root / "SyntheticColon_C3F"
        rgb = cv2.imread(str(scene / "Frames_S1" / "FrameBuffer_0002.png"))[..., ::-1]
        raw = cv2.imread(str(scene / "Frames_S1" / "Depth_0002.png"), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16
        d = raw / 65535.0 * 0.20
        ok = raw < 65535
        assert_allclose(d[ok], depth0[ok], atol=q + 0.2 / 65535)
        t = np.loadtxt(scene / "SavedPosition_S1.txt")
        quat = np.loadtxt(scene / "SavedRotationQuaternion_S1.txt")
        poses = [_from_unity(t[i], quat[i]) for i in range(4)]
        expected = list(seq.poses)
        K = np.array((scene / "cam.txt").read_text().split(), float).reshape(3, 3)
        assert_allclose(K, seq.camera.K)
    else:
        s = root / "c3f_sim"
        rgb = cv2.imread(str(s / "0002_color.png"))[..., ::-1]
        raw = cv2.imread(str(s / "0002_depth.tiff"), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16
        ok = (raw > 0) & (raw < 65535)
        assert ok.mean() > 0.3
        assert_allclose(raw[ok] / 65535.0 * 0.1, depth0[ok], atol=q + 0.1 / 65535)
        rows = np.loadtxt(s / "pose.txt", delimiter=",")
        assert rows.shape == (4, 16) and (rows[:, 15] == 1).all()
        poses = []
        for r in rows:
            M = r.reshape(4, 4).T  # column-major
            M[:3, 3] /= 1000.0
            poses.append(M)
        expected = list(seq.poses)
        assert (s / "coverage_mesh.obj").is_file()
    assert (rgb == rgb0).all()
    for P, E in zip(poses, expected):
        assert g.is_rotation(P[:3, :3])
        assert_allclose(P, E, atol=1e-6)
