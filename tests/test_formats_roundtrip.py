"""Published layouts written by the simulator (quirks included) load to the same frames, depth,
poses and intrinsics as the simulator's own layout of the same sequence."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from c3f_slam import geometry as g
from c3f_slam.io import Sequence
from datamodules.formats import find_sequences, make_format
from tests.published_data import FRAMES, SEQUENCE_DIR

PROJECT_DEPTH_STEP = 1e-4  # the project layout stores depth in 0.1 mm steps


def _open(published, layout):
    sim, root = published(layout)
    found = find_sequences(make_format(layout), root)
    assert len(found) == 1
    return Sequence(sim), make_format(layout).open(next(iter(found.values()))), root


def _no_camera_json(root):
    assert not list(root.rglob("camera.json")), "the published layouts have no camera.json"


@pytest.mark.parametrize("layout", ["uts", "simcol3d"])
def test_unity_layouts_load_exactly(published, layout):
    ref, seq, root = _open(published, layout)
    _no_camera_json(root)
    assert len(seq) == FRAMES and seq.has_depth and seq.has_poses
    for k in ("width", "height", "fx", "fy", "cx", "cy"):
        assert getattr(seq.camera, k) == pytest.approx(getattr(ref.camera, k), rel=1e-6), k
    for i in range(FRAMES):
        assert (seq.read_rgb(i) == ref.read_rgb(i)).all()
        quantum = PROJECT_DEPTH_STEP / 2 + (0.2 / 65280 / 2 if layout == "simcol3d" else 1e-6)
        d, d_ref = seq.read_depth(i), ref.read_depth(i)
        assert_allclose(d, d_ref, atol=quantum)
        expected = g.relative_pose(ref.pose(0), ref.pose(i)) if layout == "uts" else ref.pose(i)  # UTS: first = origin
        assert g.is_rotation(seq.pose(i)[:3, :3])
        assert_allclose(seq.pose(i), expected, atol=1e-6)


def test_uts_files_are_the_release_format(published):
    _, root = published("uts")
    case = root / SEQUENCE_DIR["uts"]
    left = sorted(p.name for p in (case / "left").iterdir())
    assert left[0] == "SUK_L00001.png" and "SUK_L_depth00001.exr" in left  # numbered from 1, the README's names
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    exr = cv2.imread(str(case / "left" / "SUK_L_depth00003.exr"), cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH)
    assert exr.dtype == np.float32 and exr.shape[2] == 3
    ref = Sequence(published("uts")[0]).read_depth(2)
    assert_allclose(exr[..., 0] * 5.0 / 1000.0, ref, atol=PROJECT_DEPTH_STEP)  # x 5 = mm
    pos = (case / "Case0001_Camera Position L Data.txt").read_text().splitlines()
    rot = (case / "Case0001_Camera Quaternion Rotation Data.txt").read_text().splitlines()
    assert len(pos) == len(rot) == FRAMES - 1  # the first frame is the origin and not listed
    assert pos[0].startswith("Frame 0 X=") and rot[0].startswith("Frame 0 X=") and ", W=" in rot[0]


def test_simcol3d_files_are_the_release_format(published):
    _, root = published("simcol3d")
    frames = root / SEQUENCE_DIR["simcol3d"]
    rgba = cv2.imread(str(frames / "FrameBuffer_0002.png"), cv2.IMREAD_UNCHANGED)
    assert rgba.dtype == np.uint16 and rgba.shape[2] == 4  # 16-bit RGBA, as released
    raw = cv2.imread(str(frames / "Depth_0002.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.ndim == 2
    ref = Sequence(published("simcol3d")[0]).read_depth(2)
    near = (raw < 65535) & (ref > 0)
    assert near.mean() > 0.3
    assert_allclose(raw[near] / 256 / 255 * 0.20, ref[near], atol=PROJECT_DEPTH_STEP)  # the release's own reading
    cam = (frames.parent / "cam.txt").read_text().split()
    assert len(cam) == 9 and cam[0] == cam[2] and cam[4] == cam[5] == "24.0" and cam[6:] == ["0", "0", "1"]
    assert (root / "misc" / "train_file.txt").read_text().split() == ["SyntheticColon_C3F/Frames_S1"]
    assert np.loadtxt(frames.parent / "SavedPosition_S1.txt").shape == (FRAMES, 3)


def _window_range(d: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel min and max of the size x size neighbourhood (valid pixels only)."""
    big = np.where(d > 0, d, np.inf).astype(np.float32)
    small = np.where(d > 0, d, -np.inf).astype(np.float32)
    k = np.ones((size, size), np.uint8)
    return cv2.erode(big, k, borderType=cv2.BORDER_REPLICATE), cv2.dilate(small, k, borderType=cv2.BORDER_REPLICATE)


def test_c3vd_fisheye_frames_undistort_to_the_pinhole_view(published):
    ref, seq, root = _open(published, "c3vd")
    _no_camera_json(root)
    for k in ("width", "height", "fx", "fy", "cx", "cy"):
        assert getattr(seq.camera, k) == pytest.approx(getattr(ref.camera, k), rel=1e-6), k
    for i in range(FRAMES):
        d, d_ref = seq.read_depth(i), ref.read_depth(i)
        d_ref = np.where(d_ref < 0.1, d_ref, 0.0)  # C3VD depth ends at 100 mm
        both = (d > 0) & (d_ref > 0)
        assert both.mean() > 0.5 and ((d > 0) == (d_ref > 0)).mean() > 0.97
        # nearest-neighbour undistortion: each depth comes from the nearest fisheye pixel's ray, up to
        # 0.7 fisheye pixels off the exact one, which is up to ~1.6 pinhole pixels at the edge of the view
        lo, hi = _window_range(d_ref, 5)
        inside = (d >= lo - PROJECT_DEPTH_STEP) & (d <= hi + PROJECT_DEPTH_STEP)
        assert inside[both].mean() > 0.99
        grey = [cv2.cvtColor(x, cv2.COLOR_RGB2GRAY).astype(np.float64) for x in (seq.read_rgb(i), ref.read_rgb(i))]
        a, b = (x - x.mean() for x in grey)
        assert (a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()) > 0.9  # same picture (exposure differs)
        assert_allclose(seq.pose(i), ref.pose(i), atol=1e-6)  # 6 significant digits of mm


def test_c3vd_files_are_the_release_format(published):
    sim, root = published("c3vd")
    s = root / SEQUENCE_DIR["c3vd"]
    colour = cv2.imread(str(s / "0000_color.png"), cv2.IMREAD_UNCHANGED)
    assert colour.shape == (108, 135, 3) and (colour[0, 0] == 0).all()  # fisheye: corners masked
    raw = cv2.imread(str(s / "0000_depth.tiff"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw[0, 0] == 0 and (raw == 65535).any()  # beyond 100 mm: clipped
    rows = np.loadtxt(s / "pose.txt", delimiter=",")
    ref = Sequence(sim)
    assert rows.shape == (FRAMES, 16) and (rows[:, 3] == 0).all() and (rows[:, 15] == 1).all()
    assert_allclose(rows[2, 12:15], ref.pose(2)[:3, 3] * 1000, atol=1e-3)  # column-major, mm
    text = (s / "coverage_mesh.obj").read_text()
    assert "vt 0.0 0.0\nvt 1.0 1.0" in text and "/1 " in text and "/2 " in text


def test_c3vd_mesh_and_coverage(published):
    import open3d as o3d

    sim, root = published("c3vd")
    seq = make_format("c3vd").open(root / SEQUENCE_DIR["c3vd"])
    V, F = seq.read_mesh()
    truth = o3d.io.read_triangle_mesh(str(sim / "mesh.ply"))
    assert_allclose(V, np.asarray(truth.vertices), rtol=1e-5, atol=1e-7)  # mm with 6 digits -> metres
    assert (F == np.asarray(truth.triangles)).all()
    seen = seq.read_coverage()
    assert seen.shape == (len(F),) and 0.02 < seen.mean() < 0.9  # a short insertion sees part of the colon


def test_colon10k_layout(published):
    ref, seq, root = _open(published, "colon10k")
    _no_camera_json(root)
    assert not seq.has_depth and not seq.has_poses and len(seq) == FRAMES
    assert seq.camera == ref.camera  # the calibration file written beside the sequences
    for i in range(FRAMES):
        assert np.abs(seq.read_rgb(i).astype(int) - ref.read_rgb(i)).mean() < 3.0  # JPEG
