"""Each convention the published-data readers chose where the sources are ambiguous is pinned
here, and every kind of bad input stops with one line that names the file."""

from __future__ import annotations

import math
import shutil

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from c3f_core.errors import InputError
from c3f_slam.io import Sequence
from datamodules.formats import find_sequences, make_format
from datamodules.formats.c3vd import read_pose_file
from datamodules.formats.colon10k import PUBLISHED as COLON10K_CAMERA
from datamodules.formats.omnicam import C3VD_CALIBRATION, OmniCamera
from datamodules.formats.simcol3d import read_cam_txt
from datamodules.formats.unity import pose_from_unity, pose_to_unity
from datamodules.formats.uts import intrinsics as uts_intrinsics
from datamodules.formats.uts import read_pose_lines
from tests.published_data import FRAMES, SEQUENCE_DIR, copy_layout


# ---------------------------------------------------------------------- Unity frame
def test_unity_conversion_is_the_readmes():
    """UTS's README: y flips and (qx, qy, qz, qw) -> (-qx, qy, -qz, qw); SimCol3D: TM @ P @ TM."""
    q = np.array([0.1, 0.2, 0.3, 0.9])
    q /= np.linalg.norm(q)
    T = pose_from_unity([1.0, 2.0, 3.0], q)
    assert_allclose(T[:3, 3], [0.01, -0.02, 0.03])  # centimetres, y flipped
    from c3f_slam.geometry import quaternion_to_matrix

    assert_allclose(T[:3, :3], quaternion_to_matrix([-q[0], q[1], -q[2], q[3]]), atol=1e-12)
    TM = np.diag([1.0, -1.0, 1.0, 1.0])
    P = np.eye(4)
    P[:3, :3], P[:3, 3] = quaternion_to_matrix(q), [1.0, 2.0, 3.0]
    assert_allclose(T[:3, :3], (TM @ P @ TM)[:3, :3], atol=1e-12)
    t, q2 = pose_to_unity(T)
    assert_allclose(t, [1.0, 2.0, 3.0])
    assert_allclose(abs(q2 @ q), 1.0)  # the same rotation back (q and -q are one rotation)


# ---------------------------------------------------------------------- UTS
def test_uts_intrinsics_reproduce_the_readme():
    cam = uts_intrinsics(480, 640)  # the release's frames: the README's fx = fy = 232.5044678
    assert cam.fx == pytest.approx(232.5044678, abs=1e-6) and cam.fy == cam.fx
    assert (cam.cx, cam.cy) == (239.5, 319.5)  # the centre of Unity's symmetric frustum
    assert uts_intrinsics(320, 240).fx == pytest.approx(4.969783 * 320 / 10.26)  # its simulator example
    wide = uts_intrinsics(512, 512, fov=120.0)  # a user render: size + field of view
    assert wide.fx == pytest.approx(256 / math.tan(math.radians(60)))


def test_uts_numeric_pose_lines_equal_frame_lines(tmp_path):
    frame = tmp_path / "a.txt"
    frame.write_text("Frame 0 X=1.5, Y=-2.25, Z=3.0 \nFrame 1 X=4.0, Y=5.0, Z=6.5 \n")
    numeric = tmp_path / "b.txt"
    numeric.write_text("id tx ty tz\n000001 1.5, -2.25, 3.0\n000002 4.0, 5.0, 6.5\n")
    assert_allclose(read_pose_lines(frame, 3), read_pose_lines(numeric, 3))
    assert read_pose_lines(frame, 3).shape == (2, 3)


def test_uts_first_frame_is_the_origin(published):
    seq = make_format("uts").open(published("uts")[1] / SEQUENCE_DIR["uts"])
    assert_allclose(seq.pose(0), np.eye(4))  # not listed in the pose files


# ---------------------------------------------------------------------- SimCol3D
def test_simcol3d_cam_txt_of_the_release(tmp_path):
    path = tmp_path / "cam.txt"
    path.write_text("227.60416 0 227.60416 0 237.5 237.5 0 0 1\n")  # the release's file
    cam = read_cam_txt(path, 475, 475)
    assert cam.fx == cam.fy == pytest.approx(227.60416) and (cam.cx, cam.cy) == (237.0, 237.0)
    path.write_text("227.6 0 237 0 227.6 237 0 0\n")
    with pytest.raises(InputError, match=r"cam.txt: expected 9 numbers .* got 8"):
        read_cam_txt(path, 475, 475)


def test_simcol3d_depth_scale_and_saturation(published, tmp_path):
    root = copy_layout(published("simcol3d")[1], tmp_path / "s")
    frames = root / SEQUENCE_DIR["simcol3d"]
    raw = np.array([[0, 65280], [32640, 65535]], np.uint16)
    cv2.imwrite(str(frames / "Depth_0000.png"), np.tile(raw, (24, 24)))
    d = make_format("simcol3d").open(frames).read_depth(0)
    assert_allclose(d[:2, :2], [[0.0, 0.20], [0.10, 0.0]], atol=1e-7)  # 65280 = 20 cm; 65535 = beyond: none


def test_simcol3d_poses_follow_frame_numbers(published, tmp_path):
    sim, layout = published("simcol3d")
    root = copy_layout(layout, tmp_path / "s")
    frames = root / SEQUENCE_DIR["simcol3d"]
    (frames / "FrameBuffer_0002.png").unlink()  # a removed (bad) frame
    (frames / "Depth_0002.png").unlink()
    seq = make_format("simcol3d").open(frames)
    ref = Sequence(sim)
    assert len(seq) == FRAMES - 1
    assert_allclose(seq.pose(2), ref.pose(3), atol=1e-6)  # FrameBuffer_0003 keeps pose line 3


def test_simcol3d_published_split(published):
    split = make_format("simcol3d").published_split(published("simcol3d")[1])
    assert split == {"train": ["SyntheticColon_C3F_Frames_S1"], "test": []}


# ---------------------------------------------------------------------- C3VD
def test_c3vd_stretch_matrix_is_the_renderers():
    """glm::mat2(c, d, e, 1) is column-major: u - cx = c x + e y, v - cy = d x + y."""
    cam = OmniCamera(100, 80, 50.0, 40.0, 60.0, 0.0, 0.0, 0.0, c=1.01, d=0.02, e=-0.03)
    x, y = 10.0, -5.0  # sensor coordinates
    ray = np.array([x, y, 60.0])  # a0 only: z = 60 for every rho
    u, v = cam.project(ray[None])[0]
    assert (u, v) == pytest.approx((50.0 + 1.01 * x - 0.03 * y, 40.0 + 0.02 * x + y))
    rays = cam.pixel_rays()  # the inverse: the ray of a pixel projects back onto it
    back = cam.project(rays.T)
    grid = np.stack(np.meshgrid(np.arange(100.0), np.arange(80.0)), -1).reshape(-1, 2)
    assert np.abs(back - grid).max() < 1e-6


def test_c3vd_calibration_file_and_scaling(tmp_path):
    path = tmp_path / "camera_intrinsics.txt"
    path.write_text(C3VD_CALIBRATION.to_text())
    assert OmniCamera.from_file(path) == C3VD_CALIBRATION
    half = C3VD_CALIBRATION.scaled(675, 540)
    p = np.array([[0.01, -0.02, 0.03], [0.0, 0.0, 1.0]])
    full_px, half_px = C3VD_CALIBRATION.project(p), half.project(p)
    assert_allclose((full_px + 0.5) / 2 - 0.5, half_px, atol=1e-6)  # the same rays on a half-size grid
    with pytest.raises(InputError, match="aspect ratio"):
        C3VD_CALIBRATION.scaled(500, 500)
    path.write_text("width = 10\nheight = 8\ncx = 5\n")
    with pytest.raises(InputError, match=r"camera_intrinsics.txt: calibration lacks cy"):
        OmniCamera.from_file(path)


def test_c3vd_pose_storage_order(tmp_path):
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.1, -0.2, 0.3]))[0]
    T[:3, 3] = [10.0, -20.0, 30.0]  # mm
    col = tmp_path / "col.txt"
    col.write_text(",".join(f"{v:.9g}" for v in T.T.reshape(-1)) + "\n")  # as C3VD's renderer writes it
    row = tmp_path / "row.txt"
    row.write_text(",".join(f"{v:.9g}" for v in T.reshape(-1)) + "\n")  # as the dataset page describes it
    expected = T.copy()
    expected[:3, 3] /= 1000.0
    assert_allclose(read_pose_file(col)[0], expected, atol=1e-9)
    assert_allclose(read_pose_file(row)[0], expected, atol=1e-9)
    bad = tmp_path / "bad.txt"
    bad.write_text(",".join(["1"] * 16) + "\n")
    with pytest.raises(InputError, match=r"bad.txt:1: not a rigid transform"):
        read_pose_file(bad)


def test_c3vd_unpadded_names_calibration_beside_and_clipped_depth(published, tmp_path):
    root = copy_layout(published("c3vd")[1], tmp_path / "c")
    s = root / SEQUENCE_DIR["c3vd"]
    before = make_format("c3vd").open(s).read_rgb(1)
    (s / "0001_color.png").rename(s / "1_color.png")  # the first release of cecum_t1_a
    seq = make_format("c3vd").open(s)
    assert [p.name for p in seq.rgb_paths][:2] == ["0000_color.png", "1_color.png"]
    assert (seq.read_rgb(1) == before).all()
    other = C3VD_CALIBRATION.scaled(135, 108)
    (s / "camera_intrinsics.txt").write_text(OmniCamera(**{**other.__dict__, "a0": other.a0 * 1.1}).to_text())
    assert make_format("c3vd").open(s).camera.fx == pytest.approx(other.a0 * 1.1)  # C3VDv2's file is used
    raw = cv2.imread(str(s / "0000_depth.tiff"), cv2.IMREAD_UNCHANGED)
    assert (raw == 65535).any() and (raw == 65535).mean() < (seq.read_depth(0) == 0).mean() + 1e-9


def test_c3vd_v2_subfolders(published, tmp_path):
    s = published("c3vd")[1] / SEQUENCE_DIR["c3vd"]
    v2 = tmp_path / "c1_v2"
    (v2 / "rgb").mkdir(parents=True)
    (v2 / "depth").mkdir()
    for k in range(FRAMES):
        shutil.copy(s / f"{k:04d}_color.png", v2 / "rgb" / f"{k:04d}.png")
        shutil.copy(s / f"{k:04d}_depth.tiff", v2 / "depth" / f"{k:04d}_depth.tiff")
    shutil.copy(s / "pose.txt", v2 / "pose.txt")
    a, b = make_format("c3vd").open(s), make_format("c3vd").open(v2)
    assert (a.read_depth(3) == b.read_depth(3)).all() and (a.read_rgb(3) == b.read_rgb(3)).all()


# ---------------------------------------------------------------------- Colon10K
def test_colon10k_published_intrinsics(published, tmp_path):
    root = copy_layout(published("colon10k")[1], tmp_path / "k")
    for calib in root.glob("calib_*.txt"):
        calib.unlink()
    seq = make_format("colon10k").open(root / SEQUENCE_DIR["colon10k"])
    assert seq.camera == COLON10K_CAMERA
    assert (seq.camera.fx, seq.camera.cx, seq.camera.cy) == (145.4410, 135.6993, 107.8946)
    small = tmp_path / "small" / "seq" / "image"
    small.mkdir(parents=True)
    cv2.imwrite(str(small / "00000.jpg"), np.zeros((100, 120, 3), np.uint8))
    with pytest.raises(InputError, match=r"00000.jpg: frames are 120x100; .* 270x216 \(give a calibration file\)"):
        make_format("colon10k").open(small.parent)


# ---------------------------------------------------------------------- bad input
def test_folder_of_another_layout_says_what_was_expected(published):
    root = published("simcol3d")[1]
    with pytest.raises(InputError, match=r"no UTS-synthetic sequences found \(expected Case\*/left/\*.png.*"
                                         r"it looks like SimCol3D data \(simcol3d\)"):
        find_sequences(make_format("uts"), root)


def _damage(kind: str, layout: str, root):
    s = root / SEQUENCE_DIR[layout]
    if kind == "missing poses":
        {"uts": s / "Case0001_Camera Quaternion Rotation Data.txt", "simcol3d": s.parent / "SavedPosition_S1.txt",
         "c3vd": s / "pose.txt"}[layout].unlink()
    elif kind == "missing depth":
        {"uts": s / "left" / "SUK_L_depth00003.exr", "simcol3d": s / "Depth_0002.png",
         "c3vd": s / "0002_depth.tiff"}[layout].unlink()
    elif kind == "truncated pose line":
        pose = {"uts": s / "Case0001_Camera Position L Data.txt", "simcol3d": s.parent / "SavedPosition_S1.txt",
                "c3vd": s / "pose.txt"}[layout]
        lines = pose.read_text().splitlines()
        pose.write_text("\n".join(lines[:-1] + [lines[-1][: len(lines[-1]) // 2]]) + "\n")
    elif kind == "fewer poses":  # every pose file of the sequence one line short
        files = {"uts": [s / "Case0001_Camera Position L Data.txt", s / "Case0001_Camera Quaternion Rotation Data.txt"],
                 "simcol3d": [s.parent / "SavedPosition_S1.txt", s.parent / "SavedRotationQuaternion_S1.txt"],
                 "c3vd": [s / "pose.txt"]}[layout]
        for pose in files:
            pose.write_text("\n".join(pose.read_text().splitlines()[:-1]) + "\n")


BAD = {  # kind -> the error each reader gives, as a regex
    "missing poses": {"uts": r"Case0001: UTS camera rotation file not found",
                      "simcol3d": r"SavedPosition_S1.txt: SimCol3D position file not found",
                      "c3vd": r"no C3VD sequences found"},
    "missing depth": {"uts": r"left: no depth EXR for frame 3", "simcol3d": r"Frames_S1: no Depth_0002.png",
                      "c3vd": r"c3f_sim: no depth file for frame 2"},
    "truncated pose line": {"uts": r"Position L Data.txt:4: incomplete pose line .*\(truncated file\?\)",
                            "simcol3d": r"SavedPosition_S1.txt:5: expected 3 position values per line, got \d "
                                        r"\(truncated file\?\)",
                            "c3vd": r"pose.txt:5: expected 16 matrix entries per line, got \d+ \(truncated file\?\)"},
    "fewer poses": {"uts": r"Position L Data.txt: 3 poses for 5 frames \(expected 4",
                    "simcol3d": r"SavedPosition_S1.txt: 4 poses, but frame 4 needs 5",
                    "c3vd": r"pose.txt: 4 poses, but frame 4 needs 5"},
}


@pytest.mark.parametrize("kind", list(BAD))
@pytest.mark.parametrize("layout", ["uts", "simcol3d", "c3vd"])
def test_bad_files_give_one_line_naming_the_file(published, tmp_path, layout, kind):
    root = copy_layout(published(layout)[1], tmp_path / layout)
    _damage(kind, layout, root)
    with pytest.raises(InputError, match=BAD[kind][layout]) as err:
        fmt = make_format(layout)
        for path in find_sequences(fmt, root).values():
            fmt.open(path)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("layout, name, what", [
    ("uts", "left/SUK_L_depth00002.exr", "must be floating point"),
    ("simcol3d", "Depth_0001.png", r"must be single-channel 16-bit, got 8-bit 1-channel"),
    ("c3vd", "0001_depth.tiff", r"must be single-channel 16-bit, got 8-bit 1-channel"),
])
def test_depth_of_the_wrong_bit_depth(published, tmp_path, layout, name, what):
    root = copy_layout(published(layout)[1], tmp_path / layout)
    seq_dir = root / SEQUENCE_DIR[layout]
    path = seq_dir / name
    path.write_bytes(cv2.imencode(".png", np.full((48, 48), 7, np.uint8))[1].tobytes())  # 8-bit, under its name
    seq = make_format(layout).open(seq_dir)
    with pytest.raises(InputError, match=rf"{path.name}: .*{what}"):
        seq.read_depth(1)


@pytest.mark.parametrize("layout, name", [("uts", "left/SUK_L00002.png"), ("simcol3d", "FrameBuffer_0001.png"),
                                          ("c3vd", "0001_color.png"), ("colon10k", "image/00001.jpg")])
def test_corrupt_image(published, tmp_path, layout, name):
    root = copy_layout(published(layout)[1], tmp_path / layout)
    seq_dir = root / SEQUENCE_DIR[layout]
    (seq_dir / name).write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    seq = make_format(layout).open(seq_dir)
    with pytest.raises(InputError, match=rf"{(seq_dir / name).name}: image does not decode"):
        seq.read_rgb(1)


def test_unknown_layout_and_option():
    with pytest.raises(InputError, match=r"data.layout: unknown data set 'kitti'"):
        make_format("kitti", option_prefix="data.")
    with pytest.raises(InputError, match=r"layout_options: uts does not take 'calibration' \(it takes fov\)"):
        make_format("uts", calibration="x")
