"""The omnidirectional (Scaramuzza) camera in the runtime: pixel <-> ray, camera.json, the refusals,
undistortion to a pinhole (straight lines straight again, no black border), a video run with such a
lens, and C3VD's reader giving the pinhole and maps it gave before the model moved into the runtime.

Synthetic frames are rendered exactly through the model: each pixel's ray (:meth:`OmniCamera.unproject`)
is intersected with a board plane, or projected into a pinhole frame of the simulator, and sampled
there (``cv2.remap``)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.camera.calibration import Undistortion, find_corners
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.camera.omnidirectional import OmniCamera
from c3f_slam.cli.main import main
from c3f_slam.frames.stream import FrameStream
from c3f_slam.io import SequenceWriter
from datamodules.formats.omnicam import C3VD_CALIBRATION
from tests import checkerboard
from tests import onnx_fixtures as fx

#: C3VD's lens at a fifth of its size (270 x 216), as the runtime's model (not C3VD's file reader)
OMNI = OmniCamera(**asdict(C3VD_CALIBRATION.scaled(270, 216)))
BOARD, SQUARE, PX = (9, 6), 0.16, 24  # inner corners; square side on the plane z = 1; board-image pixels a square


# ------------------------------------------------------------------ rendering
def board_image() -> np.ndarray:
    return checkerboard.board_image(BOARD, PX)


def board_corners() -> np.ndarray:
    """(cols * rows, 3) inner corners on the plane z = 1, the board centred on the optical axis, in
    ``findChessboardCorners``' order."""
    xy = np.stack(np.meshgrid(np.arange(BOARD[0]), np.arange(BOARD[1])), -1).reshape(-1, 2) * SQUARE
    xy = xy - xy.mean(axis=0)
    return np.concatenate([xy, np.ones((len(xy), 1))], axis=1)


def render_board(cam: OmniCamera) -> np.ndarray:
    """The board on the plane z = 1 seen by ``cam`` (grey; 110 where the rays miss it)."""
    rays = cam.pixel_rays().T
    ahead = rays[:, 2] > 1e-6
    s = 1.0 / np.where(ahead, rays[:, 2], 1.0)
    first = board_corners()[0, :2]  # inner corner (0, 0)
    origin = 2 * PX - 0.5  # its board-image coordinate
    maps = [np.where(ahead, (rays[:, k] * s - first[k]) / SQUARE * PX + origin, -1e6) for k in (0, 1)]
    mx, my = (m.reshape(cam.height, cam.width).astype(np.float32) for m in maps)
    return cv2.remap(board_image(), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=110)


def straightness(corners: np.ndarray) -> float:
    """Largest distance (pixels) of a board corner from the straight line through its row."""
    worst = 0.0
    for row in corners.reshape(BOARD[1], BOARD[0], 2):
        centred = row - row.mean(axis=0)
        normal = np.linalg.svd(centred)[2][1]
        worst = max(worst, float(np.abs(centred @ normal).max()))
    return worst


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


# ------------------------------------------------------------------ the model
def test_pixel_ray_pixel_round_trip():
    """Every pixel's ray projects back onto it, and rays off the axis (beyond 90 degrees too, which C3VD's
    lens sees at its corners) come back from their pixel."""
    grid = np.stack(np.meshgrid(np.arange(OMNI.width, dtype=float), np.arange(OMNI.height, dtype=float)), -1)
    grid = grid.reshape(-1, 2)
    rays = OMNI.unproject(grid)
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)
    assert (rays[:, 2] < 0).any()  # the frame corners see behind the lens
    assert np.abs(OMNI.project(rays) - grid).max() < 1e-3
    assert np.array_equal(OMNI.pixel_rays(), rays.T)
    axis = OMNI.project(np.array([[0.0, 0.0, 2.0]]))[0]
    assert axis == pytest.approx((OMNI.cx, OMNI.cy))
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 3)) + [0.0, 0.0, 1.0]
    uv = OMNI.project(pts)
    seen = np.isfinite(uv).all(axis=1)
    assert seen.mean() > 0.5 and not seen.all()  # behind the lens's widest angle: no image
    back = OMNI.unproject(uv[seen])
    assert np.abs(back - pts[seen] / np.linalg.norm(pts[seen], axis=1, keepdims=True)).max() < 1e-5


def test_camera_json_round_trip(tmp_path):
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(OMNI.to_dict()))
    assert json.loads(path.read_text())["model"] == "omnidirectional"
    cam = PinholeCamera.from_json(path)
    assert type(cam) is OmniCamera and cam == OMNI and cam.is_distorted
    data = {**OMNI.to_dict(), "a1": 0, "depth_scale": 5000, "tissue_mask": "mask.png"}  # a1 = 0 may be written
    path.write_text(json.dumps(data))
    assert PinholeCamera.from_json(path).depth_scale == 5000.0


GOOD = OMNI.to_dict()


@pytest.mark.parametrize("change, text", [
    ({"a0": 0.0}, "a0 must be positive"),
    ({"a0": -150.0}, "a0 must be positive"),
    ({"c": 0.02, "d": 0.2, "e": 0.1}, "stretch matrix (c, d, e) = (0.02, 0.2, 0.1) is singular"),
    ({"a3": float("nan")}, "a3 must be finite, got nan"),
    ({"e": float("inf")}, "e must be finite"),
    ({"a2": "small"}, "a2 must be a number, got 'small'"),
    ({"width": 270.5}, "width must be a whole number of pixels"),
    ({"height": 0}, "size must be positive"),
    ({"a1": 0.01}, "a1 = 0.01 (the model has no linear term"),
    ({"cx": 300.0}, "cx=300 px is not inside the 270x216 frame"),
    ({"cy": -1.0}, "cy=-1 px is not inside"),
    ({"depth_scale": 0}, "depth_scale must be positive"),
    ({"a4": None}, "a4 must be a number, got None"),
], ids=["a0_zero", "a0_negative", "singular", "nan", "inf", "string", "width_fraction", "height_zero", "a1",
        "cx_outside", "cy_outside", "depth_scale", "null"])
def test_impossible_omnidirectional_camera_is_one_line_naming_the_file(change, text, tmp_path):
    path = tmp_path / "scope_omni.json"
    path.write_text(json.dumps({**GOOD, **change}))
    with pytest.raises(InputError) as exc:
        PinholeCamera.from_json(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ") and text in msg, msg


def test_missing_omnidirectional_field(tmp_path):
    path = tmp_path / "omni.json"
    path.write_text(json.dumps({k: v for k, v in GOOD.items() if k not in ("a0", "e")}))
    with pytest.raises(InputError, match=r"omni.json: missing key\(s\) a0, e \(an omnidirectional camera needs"):
        PinholeCamera.from_json(path)


# ------------------------------------------------------------------ undistortion
def test_undistortion_straightens_the_board_without_a_border():
    """The board's rows, bent by the lens, are straight in the undistorted frame, and its corners sit
    where the undistortion's pinhole camera projects them (within 1 px). The pinhole's focal length is
    the smallest that keeps every pixel inside the lens's frame."""
    und = Undistortion.of(OMNI)
    cam = und.camera
    assert cam.model == "pinhole" and cam.size == OMNI.size and (cam.cx, cam.cy) == (134.5, 107.5)
    assert cam.fx == cam.fy and 90 < cam.fov_deg()[0] < 120  # a wide view is kept
    mx, my = und.maps
    assert mx.min() >= 0 and my.min() >= 0 and mx.max() <= OMNI.width - 1 and my.max() <= OMNI.height - 1
    wx, wy = OMNI.undistort_maps(PinholeCamera.centred(OMNI.width, OMNI.height, cam.fx * 0.99))
    assert min(wx.min(), wy.min()) < 0 or wx.max() > OMNI.width - 1 or wy.max() > OMNI.height - 1  # 1 % wider: out
    points = board_corners()
    bent = OMNI.project(points)
    assert straightness(bent) > 3.0  # the lens bends the rows by several pixels
    raw = render_board(OMNI)
    straight = find_corners(und.rgb(raw), BOARD)
    assert straight is not None
    truth = (points @ cam.K.T)[:, :2]
    err = min(np.abs(straight.reshape(-1, 2) - p).max() for p in (truth, truth[::-1]))
    assert err < 1.0, err
    assert straightness(straight) < 0.5
    found = find_corners(raw, BOARD)  # and in the lens's frame, where the model says
    assert found is not None
    assert min(np.abs(found.reshape(-1, 2) - p).max() for p in (bent, bent[::-1])) < 1.0


def test_sequence_folder_with_an_omnidirectional_camera_json(tmp_path):
    """A folder whose camera.json is an omnidirectional lens is read undistorted: z-depth of a plane
    facing the lens stays its z, with no pixel left without depth (no border)."""
    lens = OmniCamera(width=64, height=48, cx=31.8, cy=23.2, a0=40.0, a2=-0.004, a3=0.0, a4=0.0)
    writer = SequenceWriter(tmp_path / "seq", lens)
    writer.write_frame(0, np.full((48, 64, 3), 100, np.uint8), np.full((48, 64), 0.05, np.float32))
    writer.finish(np.eye(4)[None])
    stream = FrameStream(tmp_path / "seq")
    assert stream.camera == Undistortion(lens).camera and "omnidirectional lens" in stream.camera_source
    frame = next(iter(stream))
    assert frame.rgb.shape == (48, 64, 3) and np.all(frame.depth == np.float32(0.05))


# ------------------------------------------------------------------ a video through such a lens
def _video_lens(src: PinholeCamera) -> OmniCamera:
    """A 64 x 64 omnidirectional lens about 100 degrees wide across the frame, axis off the centre."""
    a0 = 1.3 * src.fx
    return OmniCamera(width=src.width, height=src.height, cx=31.8, cy=31.2, a0=a0, a2=-0.12 * a0 / 32**2,
                      a3=0.0, a4=-1e-7, c=1.002, d=0.001, e=-0.002)


@pytest.fixture(scope="module")
def depth_model(tmp_path_factory) -> Path:
    return fx.depth_model(tmp_path_factory.mktemp("models") / "depth.onnx", (32, 32), (56, 56))


def test_run_on_an_omnidirectional_video(tiny_sequence, depth_model, tmp_path, capsys):
    """The simulator's frames seen through an omnidirectional lens, written as an mp4, run with its
    camera.json; summary.json names the lens and says the frames were undistorted. A camera.json with
    a bad field stops the run with one line naming the file and field, exit status 2."""
    src = PinholeCamera.from_json(tiny_sequence / "camera.json")
    lens = _video_lens(src)
    rays = lens.pixel_rays().T
    uv = rays @ src.K.T
    uv = uv[:, :2] / uv[:, 2:]
    mx, my = (uv[:, k].reshape(lens.height, lens.width).astype(np.float32) for k in (0, 1))
    video = tmp_path / "scope.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, lens.size)
    assert writer.isOpened()
    for p in sorted((tiny_sequence / "rgb").glob("*.png")):
        writer.write(cv2.remap(cv2.imread(str(p)), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
    writer.release()
    camera = tmp_path / "omni.json"
    camera.write_text(json.dumps(lens.to_dict()))
    stream = FrameStream(video, camera=camera)
    und = Undistortion(lens)
    assert stream.camera == und.camera and 60 < und.camera.fov_deg()[0] < 130
    out = tmp_path / "run"
    assert main(["run", str(video), "--camera", str(camera), "--depth-model", str(depth_model), "--out", str(out),
                 "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["camera_source"].startswith(f"file {camera} (omnidirectional lens cx=31.8, cy=31.2, a0=")
    assert s["camera_source"].endswith(", frames undistorted to pinhole)")
    assert s["camera"]["model"] == "pinhole" and s["camera"]["fx"] == pytest.approx(und.camera.fx)
    assert s["frames"] == 8
    bad = tmp_path / "bad_omni.json"
    bad.write_text(json.dumps({**lens.to_dict(), "a0": -1.0}))
    assert main(["run", str(video), "--camera", str(bad), "--depth-model", str(depth_model),
                 "--out", str(tmp_path / "bad_run"), "--quiet"]) == 2
    line = one_error_line(capsys)
    assert str(bad) in line and "a0 must be positive" in line


# ------------------------------------------------------------------ C3VD's reader, unchanged
#: computed by the C3VD reader's code before the model moved into the runtime (datamodules.formats.omnicam
#: at commit 48d5b2f): C3VD_CALIBRATION.scaled(135, 108), its pinhole(None / 60.0, depth_scale=655350.0) and
#: undistort_maps at (row, column): (map x, map y), and the maps' sums
BEFORE = {
    None: {(0, 0): (23.59206199645996, 18.65300750732422), (0, 134): (111.42472839355469, 18.906208038330078),
           (107, 0): (23.38423728942871, 88.78897094726562), (107, 134): (111.21690368652344, 89.04216766357422),
           (54, 67): (67.40299987792969, 54.34757614135742), (10, 20): (31.885128021240234, 20.779775619506836),
           (90, 120): (107.40327453613281, 81.566162109375), "sums": (982757.3754291534, 785097.8438520432)},
    60.0: {(0, 0): (19.245527267456055, 15.161429405212402), (0, 134): (115.79188537597656, 15.439750671386719),
           (107, 0): (19.0170841217041, 92.25542449951172), (107, 134): (115.56343841552734, 92.53374481201172),
           (54, 67): (67.402587890625, 54.48859786987305), (10, 20): (27.055692672729492, 16.283668518066406),
           (90, 120): (112.8154296875, 85.31670379638672), "sums": (982757.37586689, 785097.8440783024)},
}


def test_c3vd_reader_gives_the_pinhole_and_maps_it_gave_before():
    small = C3VD_CALIBRATION.scaled(135, 108)
    assert (small.cx, small.cy, small.a0, small.a2) == pytest.approx(
        (67.4044839263292, 53.847588754834305, 76.9243600037458, -0.00812770624150226), rel=1e-12)
    assert (small.a3, small.a4) == pytest.approx((6.256742445789248e-05, -1.1966218214427998e-06), rel=1e-12)
    for focal, expected in BEFORE.items():
        pin = small.pinhole(focal, depth_scale=655350.0)
        f = 76.9243600037458 if focal is None else focal
        assert pin == PinholeCamera(135, 108, f, f, 67.0, 53.5, depth_scale=655350.0)
        mx, my = small.undistort_maps(pin)
        for (r, c), (x, y) in ((k, v) for k, v in expected.items() if k != "sums"):
            assert (float(mx[r, c]), float(my[r, c])) == pytest.approx((x, y), abs=1e-4)
        sums = float(mx.astype(np.float64).sum()), float(my.astype(np.float64).sum())
        assert sums == pytest.approx(expected["sums"], abs=0.05)
    full = C3VD_CALIBRATION.project(np.array([[0.01, -0.02, 0.03], [0.5, 0.3, 0.2], [1.0, 0.0, -0.1]]))
    assert np.abs(full - [[882.8487155955125, 137.355608404497], [1299.5431752215327, 918.0368052236934],
                          [1537.6931435117208, 545.4526197554535]]).max() < 1e-6
    # the runtime's reading of C3VD's lens is the same model: the same rays and maps
    runtime = OmniCamera(**asdict(small))
    assert np.array_equal(runtime.pixel_rays(), small.pixel_rays())
    assert all(np.array_equal(a, b) for a, b in zip(runtime.undistort_maps(pin), small.undistort_maps(pin)))
