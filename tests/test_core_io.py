"""Sequence layout, TUM and atomic-write I/O (c3f_slam.io)."""

import json

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from c3f_core.atomic import atomic_write
from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.io import Sequence, SequenceWriter, read_tum, write_tum


def _write_seq(root, n=4, w=32, h=24, depth=True, poses=True):
    cam = PinholeCamera(w, h, 30.0, 30.0, (w - 1) / 2, (h - 1) / 2, depth_scale=10000.0)
    wr = SequenceWriter(root, cam)
    rng = np.random.default_rng(0)
    Ts = []
    for i in range(n):
        rgb = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        d = np.full((h, w), 0.03 + 0.001 * i, np.float32) if depth else None
        wr.write_frame(i, rgb, d)
        Ts.append(g.make_pose(g.axis_angle_to_matrix([0, 0.01 * i, 0]), [0, 0, 0.002 * i]))
    wr.finish(np.stack(Ts) if poses else None)
    return cam, np.stack(Ts)


def test_sequence_round_trip(tmp_path):
    cam, Ts = _write_seq(tmp_path / "s")
    seq = Sequence(tmp_path / "s", min_frames=3)
    assert len(seq) == 4 and seq.has_depth and seq.has_poses
    assert seq.camera == cam
    assert seq.read_rgb(0).shape == (24, 32, 3)
    assert_allclose(seq.read_depth(2), 0.032, atol=1e-4)  # 0.1 mm quantisation
    assert_allclose(seq.poses, Ts, atol=1e-8)


def test_tum_round_trip_and_bad_lines(tmp_path):
    T = np.stack([g.make_pose(g.axis_angle_to_matrix([0.1, 0.2, -0.3]), [1, 2, 3]), np.eye(4)])
    write_tum(tmp_path / "t.txt", np.array([0.0, 1.0]), T)
    stamps, T2 = read_tum(tmp_path / "t.txt")
    assert_allclose(T2, T, atol=1e-8)
    (tmp_path / "bad.txt").write_text("0 1 2 3\n")
    with pytest.raises(InputError, match=r"bad.txt:1: expected 8 numbers"):
        read_tum(tmp_path / "bad.txt")


def test_missing_folder_and_too_few_frames(tmp_path):
    with pytest.raises(InputError, match="sequence folder not found"):
        Sequence(tmp_path / "nope")
    _write_seq(tmp_path / "s", n=2)
    with pytest.raises(InputError, match="2 frame"):
        Sequence(tmp_path / "s", min_frames=3)


def test_corrupt_image_named(tmp_path):
    _write_seq(tmp_path / "s")
    (tmp_path / "s" / "rgb" / "000001.png").write_bytes(b"not a png")
    seq = Sequence(tmp_path / "s")
    with pytest.raises(InputError, match=r"000001.png: image does not decode"):
        seq.read_rgb(1)


def test_pose_count_mismatch(tmp_path):
    _write_seq(tmp_path / "s")
    lines = (tmp_path / "s" / "poses.txt").read_text().splitlines()
    (tmp_path / "s" / "poses.txt").write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(InputError, match="3 poses for 4 frames"):
        Sequence(tmp_path / "s")


def test_wrong_intrinsics_size(tmp_path):
    _write_seq(tmp_path / "s")
    cam = json.loads((tmp_path / "s" / "camera.json").read_text())
    cam["width"] = 64
    (tmp_path / "s" / "camera.json").write_text(json.dumps(cam))
    seq = Sequence(tmp_path / "s")
    with pytest.raises(InputError, match="intrinsics are for 64x24"):
        seq.read_rgb(0)


def test_depth_must_be_uint16(tmp_path):
    _write_seq(tmp_path / "s")
    cv2.imwrite(str(tmp_path / "s" / "depth" / "000000.png"), np.zeros((24, 32, 3), np.uint8))
    with pytest.raises(InputError, match="16-bit"):
        Sequence(tmp_path / "s").read_depth(0)


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert list(tmp_path.iterdir()) == [target]
