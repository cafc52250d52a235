"""Frame streaming from sequence folders and video files."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.frames.stream import FrameStream, frame_status, open_stream
from tests.scenes import plane_sequence, plane_texture

W, H, FPS = 32, 24, 25.0


def _write_video(path, frames_rgb, fps=FPS):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (W, H))
    assert writer.isOpened()
    for f in frames_rgb:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()


def _camera_json(path, width=W, height=H):
    cam = PinholeCamera.from_fov(width, height, 110.0)
    path.write_text(json.dumps(cam.to_dict()))
    return cam


@pytest.fixture()
def video(tmp_path):
    tex = cv2.resize(plane_texture(64, seed=1), (W, H))
    red = np.zeros((H, W, 3), np.uint8)
    red[..., 0] = 200
    frames = [tex, np.zeros_like(tex), np.full_like(tex, 255), red, tex]
    path = tmp_path / "clip.avi"
    _write_video(path, frames)
    _camera_json(tmp_path / "camera.json")
    return path


def test_frame_status():
    assert frame_status(np.zeros((4, 4, 3), np.uint8))[0] == "black"
    assert frame_status(np.full((4, 4, 3), 3, np.uint8))[0] == "black"
    assert frame_status(np.full((4, 4, 3), 255, np.uint8))[0] == "saturated"
    half = np.full((4, 4, 3), 255, np.uint8)
    half[:2] = 100
    assert frame_status(half)[0] == "ok"  # a large highlight is not a saturated frame
    assert frame_status(np.full((4, 4, 3), 120, np.uint8)) == ("ok", 120.0)


def test_sequence_folder(tmp_path):
    root = plane_sequence(tmp_path / "plane", frames=6, size=24)
    stream = open_stream(root)
    items = list(stream)
    assert [f.index for f in items] == list(range(6)) and len(stream) == 6
    assert [f.timestamp for f in items] == [float(i) for i in range(6)]  # poses.txt stamps
    f = items[0]
    assert f.rgb.dtype == np.uint8 and f.rgb.shape == (24, 24, 3)
    assert f.depth is not None and f.depth.dtype == np.float32 and abs(float(f.depth[12, 12]) - 0.05) < 1e-3
    assert all(x.usable for x in items)
    sub = FrameStream(root, start=1, step=2, max_frames=2, use_depth=False)
    got = list(sub)
    assert [x.index for x in got] == [1, 3] and len(sub) == 2 and got[0].depth is None


def test_folder_is_read_lazily(tmp_path, monkeypatch):
    import c3f_slam.frames.stream as stream_module

    root = plane_sequence(tmp_path / "plane", frames=6, size=24)
    stream = FrameStream(root)
    calls = []
    original = stream_module.read_rgb
    monkeypatch.setattr(stream_module, "read_rgb", lambda path: (calls.append(Path(path).name), original(path))[1])
    it = iter(stream)
    assert calls == []
    next(it)
    assert calls == ["000000.png"]


def test_video_frames_flags_and_timestamps(video):
    stream = FrameStream(video)
    assert stream.is_video and stream.camera.width == W and len(stream) == 5
    items = list(stream)
    assert [f.index for f in items] == [0, 1, 2, 3, 4]
    assert [f.status for f in items] == ["ok", "black", "saturated", "ok", "ok"]
    assert [f.timestamp for f in items] == pytest.approx([i / FPS for i in range(5)])
    red = items[3].rgb.astype(int)
    assert red[..., 0].mean() > 150 and red[..., 2].mean() < 50  # RGB order, not BGR
    assert all(f.depth is None for f in items)
    skipped = [f.index for f in FrameStream(video, start=1, step=3)]
    assert skipped == [1, 4]
    assert [f.index for f in FrameStream(video, max_frames=2)] == [0, 1]


def test_video_camera_argument(video, tmp_path):
    cam = PinholeCamera.from_fov(W, H, 90.0)
    assert FrameStream(video, camera=cam).camera == cam
    other = tmp_path / "other.json"
    _camera_json(other)
    assert FrameStream(video, camera=other).camera.width == W


def test_errors(tmp_path, video):
    with pytest.raises(InputError, match="no such file"):
        FrameStream(tmp_path / "missing.mp4")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputError, match="not a sequence folder or a video"):
        FrameStream(tmp_path / "notes.txt")
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(InputError, match="junk.mp4"):
        FrameStream(junk)
    (tmp_path / "camera.json").unlink()
    with pytest.raises(InputError, match="intrinsics"):
        FrameStream(video)
    bad = tmp_path / "bad.json"
    _camera_json(bad, width=64, height=48)
    with pytest.raises(InputError, match="64x48"):
        FrameStream(video, camera=bad)
    with pytest.raises(InputError, match="frame range"):
        FrameStream(video, camera=PinholeCamera.from_fov(W, H, 90.0), step=0)
    with pytest.raises(InputError, match="rgb"):
        FrameStream(tmp_path)  # a folder without the sequence layout


@pytest.mark.parametrize("damage", ["cut", "overwritten"])
def test_a_cut_or_damaged_video_is_reported(tmp_path, damage):
    """A video that stops decoding before its declared frame count: the frames before the damage
    are yielded and ``truncation`` says how many of how many."""
    rng = np.random.default_rng(0)
    path = tmp_path / "clip.avi"
    _write_video(path, [rng.integers(0, 255, (H, W, 3), dtype=np.uint8) for _ in range(40)])
    _camera_json(tmp_path / "camera.json")
    intact = FrameStream(path)
    assert len(list(intact)) == 40 and intact.truncation is None
    data = path.read_bytes()
    third = len(data) // 3
    if damage == "cut":
        data = data[:third]
    else:
        data = data[:third] + rng.integers(0, 255, third, dtype=np.uint8).tobytes() + data[2 * third:]
    path.write_bytes(data)
    stream = FrameStream(path)
    frames = list(stream)
    assert 0 < len(frames) < 40
    assert stream.truncation is not None and stream.truncation.declared == 40
    assert stream.truncation.read == frames[-1].index + 1
    assert "ended after" in stream.truncation.message(path) and "of the 40 frames" in stream.truncation.message(path)


def test_an_unreadable_folder_frame_is_yielded_marked(tmp_path):
    root = plane_sequence(tmp_path / "plane", frames=6, size=24)
    bad = sorted((root / "rgb").iterdir())[2]
    bad.write_bytes(b"not a png")
    frames = list(open_stream(root))
    assert [f.status for f in frames] == ["ok", "ok", "unreadable", "ok", "ok", "ok"]
    assert frames[2].rgb is None and bad.name in frames[2].error and not frames[2].usable


def test_frames_not_matching_the_intrinsics_are_an_error_not_unreadable(tmp_path):
    """A size mismatch is wrong intrinsics (one error naming the file), not a frame to skip."""
    root = plane_sequence(tmp_path / "plane", frames=3, size=24)
    cam = json.loads((root / "camera.json").read_text())
    cam.update(width=2 * cam["width"], height=2 * cam["height"])  # same aspect, twice the size
    (root / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(InputError, match=r"rgb/000000\.png: image is 24x24 but the camera intrinsics are for 48x48"):
        list(open_stream(root))
