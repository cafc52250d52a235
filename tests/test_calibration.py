"""Intrinsics of a real scope: ``calibrate`` on synthetic checkerboard views (pinhole and
fisheye, known intrinsics), camera.json's lens model and its checks, undistorted frames on the
video and folder paths, and ``run --fov``.

The views are rendered exactly: each pixel's ray (the lens model inverted with OpenCV's
``undistortPoints``) is intersected with the board plane and the board image is sampled there
(``cv2.remap``), so the corners are where ``cv2.projectPoints`` / ``cv2.fisheye.projectPoints``
put them.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.camera.calibration import Undistortion, board_points, find_corners
from c3f_slam.camera.intrinsics import FovGuess, PinholeCamera
from c3f_slam.cli.main import main
from c3f_slam.frames.stream import FrameStream
from c3f_slam.io import SequenceWriter
from tests import checkerboard
from tests import onnx_fixtures as fx

W, H = 640, 480
BOARD, SQUARE = (9, 6), 0.02  # inner corners (a board of 10 x 7 squares), metres per square
PX = 40  # board image pixels per square
PINHOLE = PinholeCamera(W, H, 520.0, 515.0, 322.5, 236.0, distortion=(-0.12, 0.05, 0.001, -0.0005, 0.0))
FISHEYE = PinholeCamera(W, H, 300.0, 298.0, 318.0, 243.5, distortion=(0.03, -0.02, 0.006, -0.001), model="fisheye")
SOLVE = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)


# ------------------------------------------------------------------ rendering
def board_image() -> np.ndarray:
    return checkerboard.board_image(BOARD, PX)


def pixel_rays(cam: PinholeCamera) -> np.ndarray:
    """(H*W, 3) camera-frame rays (z = 1) of every pixel of a distorted camera, row-major."""
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
    D = np.asarray(cam.distortion, np.float64)
    if cam.model == "fisheye":
        xy = cv2.fisheye.undistortPoints(pts, cam.K, D, criteria=SOLVE)
    else:
        xy = cv2.undistortPointsIter(pts, cam.K, D, None, None, SOLVE)
    return np.concatenate([xy.reshape(-1, 2), np.ones((len(pts), 1))], axis=1)


def render(cam: PinholeCamera, rays: np.ndarray, R: np.ndarray, t: np.ndarray, board: np.ndarray) -> np.ndarray:
    """The board with its corner (0, 0) at ``t`` and axes ``R`` (camera frame, metres) seen by ``cam``."""
    n = R[:, 2]
    s = (n @ t) / (rays @ n)
    local = (s[:, None] * rays - t) @ R  # board-frame coordinates of the hit points
    origin = 2 * PX - 0.5  # board-image coordinate of inner corner (0, 0)
    mx = np.where(s > 0, local[:, 0] / SQUARE * PX + origin, -1e6).reshape(cam.height, cam.width)
    my = np.where(s > 0, local[:, 1] / SQUARE * PX + origin, -1e6).reshape(cam.height, cam.width)
    img = cv2.remap(board, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=110)
    return cv2.GaussianBlur(img, (0, 0), 0.6)


def project(cam: PinholeCamera, points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of board points (N, 3) through the camera's lens model."""
    rvec = cv2.Rodrigues(R)[0]
    D = np.asarray(cam.distortion, np.float64)
    if cam.model == "fisheye":
        uv = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3).astype(np.float64), rvec, t, cam.K, D)[0]
    else:
        uv = cv2.projectPoints(points.astype(np.float64), rvec, t, cam.K, D)[0]
    return uv.reshape(-1, 2)


def board_poses(cam: PinholeCamera, n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` board poses (R, t of corner (0, 0)) tilted up to 40 degrees, the whole board (with its
    white border) inside the image, spread over the frame."""
    rng = np.random.default_rng(seed)
    cols, rows = BOARD
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2, 0.0]) * SQUARE
    outline = np.array([[-1.5, -1.5, 0], [cols + 0.5, -1.5, 0], [-1.5, rows + 0.5, 0], [cols + 0.5, rows + 0.5, 0]])
    outline = outline * SQUARE
    poses = []
    while len(poses) < n:
        R = cv2.Rodrigues(np.radians(rng.uniform([-40, -40, -25], [40, 40, 25])))[0]
        z = rng.uniform(0.18, 0.4) * cam.fx / 520.0
        target = rng.uniform([0.15 * W, 0.15 * H], [0.85 * W, 0.85 * H])
        t = np.array([(target[0] - cam.cx) / cam.fx * z, (target[1] - cam.cy) / cam.fy * z, z]) - R @ centre
        uv = project(cam, outline, R, t)
        if (R[:, 2] @ t) > 0 and np.all((uv > 8) & (uv < [W - 8, H - 8])):
            poses.append((R, t))
    return poses


def render_views(cam: PinholeCamera, n: int = 14, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(grey image, R, t) of ``n`` views of the board."""
    rays, board = pixel_rays(cam), board_image()
    return [(render(cam, rays, R, t, board), R, t) for R, t in board_poses(cam, n, seed)]


def write_views(folder: Path, views) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, (img, _, _) in enumerate(views):
        assert cv2.imwrite(str(folder / f"view_{i:02d}.png"), img)
    return folder


@pytest.fixture(scope="module")
def pinhole_views():
    return render_views(PINHOLE, 14, seed=1)


@pytest.fixture(scope="module")
def fisheye_views():
    return render_views(FISHEYE, 14, seed=2)


def _status(argv: list[str]) -> int:
    """Exit status of ``python -m c3f_slam ARGV`` (argparse's usage errors exit instead of returning)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def _straightness(corners: np.ndarray) -> float:
    """Largest distance (pixels) of a board corner from the straight line through its row."""
    worst = 0.0
    for row in corners.reshape(BOARD[1], BOARD[0], 2):
        centred = row - row.mean(axis=0)
        normal = np.linalg.svd(centred)[2][1]
        worst = max(worst, float(np.abs(centred @ normal).max()))
    return worst


def _write_video(path: Path, frames: list[np.ndarray], size=(W, H)) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, size)
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if f.ndim == 2 else f)
    writer.release()
    return path


# ------------------------------------------------------------------ calibrate
@pytest.mark.parametrize("truth", [PINHOLE, FISHEYE], ids=["pinhole", "fisheye"])
def test_calibrate_recovers_the_focal_lengths(truth, pinhole_views, fisheye_views, tmp_path, capsys):
    views = pinhole_views if truth.model == "pinhole" else fisheye_views
    folder = write_views(tmp_path / "views", views)
    out = tmp_path / "camera.json"
    assert main(["calibrate", str(folder), "--out", str(out), "--board", "9x6", "--square", str(SQUARE),
                 "--model", truth.model]) == 0
    printed = capsys.readouterr().out
    assert "views with the board" in printed and "RMS reprojection error" in printed
    cam = PinholeCamera.from_json(out)
    data = json.loads(out.read_text())
    assert data["model"] == truth.model and len(data["distortion"]) == (5 if truth.model == "pinhole" else 4)
    assert (cam.width, cam.height) == (W, H)
    assert abs(cam.fx / truth.fx - 1) < 0.01 and abs(cam.fy / truth.fy - 1) < 0.01, (cam, truth)
    assert abs(cam.cx - truth.cx) < 3 and abs(cam.cy - truth.cy) < 3


def test_calibrate_from_a_video_every_other_frame(pinhole_views, tmp_path, capsys):
    video = _write_video(tmp_path / "board.avi", [img for img, _, _ in pinhole_views])
    out = tmp_path / "camera.json"
    assert main(["calibrate", str(video), "--out", str(out), "--board", "9x6", "--square", "0.02",
                 "--every", "2"]) == 0
    assert f"of {len(pinhole_views) // 2} looked at" in capsys.readouterr().out
    cam = PinholeCamera.from_json(out)
    assert abs(cam.fx / PINHOLE.fx - 1) < 0.01 and abs(cam.fy / PINHOLE.fy - 1) < 0.01


def _bad_calibrations(tmp: Path, views) -> dict[str, tuple[list[str], str]]:
    """name -> (argv after ``calibrate``, text the error line must hold)."""
    good = write_views(tmp / "good", views[:4])
    few = write_views(tmp / "few", views[:2])
    sizes = write_views(tmp / "sizes", views[:3])
    cv2.imwrite(str(sizes / "view_99.png"), cv2.resize(views[3][0], (320, 240)))
    corrupt = write_views(tmp / "corrupt", views[:3])
    (corrupt / "view_05.png").write_bytes(b"not a png")
    (tmp / "empty").mkdir()
    blank = tmp / "blank"
    blank.mkdir()
    for i in range(3):
        cv2.imwrite(str(blank / f"{i}.png"), np.full((H, W), 128, np.uint8))
    out = ["--out", str(tmp / "camera.json")]
    ok = ["--board", "9x6", "--square", "0.02"]
    return {
        "board_one_number": ([str(good), *out, "--board", "9", "--square", "0.02"], "--board"),
        "board_too_small": ([str(good), *out, "--board", "1x6", "--square", "0.02"], "--board"),
        "square_zero": ([str(good), *out, "--board", "9x6", "--square", "0"], "--square"),
        "every_zero": ([str(good), *out, *ok, "--every", "0"], "--every"),
        "model_unknown": ([str(good), *out, *ok, "--model", "omni"], "--model"),
        "too_few_views": ([str(few), *out, *ok], "found in 2 of 2 views, at least 3"),
        "no_board": ([str(blank), *out, *ok], "found in 0 of 3 views"),
        "sizes_differ": ([str(sizes), *out, *ok], "view_99.png: image is 320x240 but"),
        "unreadable": ([str(corrupt), *out, *ok], "view_05.png: image does not decode"),
        "no_images": ([str(tmp / "empty"), *out, *ok], "empty: no images"),
        "missing": ([str(tmp / "nowhere"), *out, *ok], "nowhere: no such file or folder"),
        "not_a_video": ([str(_text_file(tmp / "notes.txt")), *out, *ok], "notes.txt: not a folder of images"),
    }


def _text_file(path: Path) -> Path:
    path.write_text("hello")
    return path


def test_calibrate_refuses_bad_input_in_one_line(pinhole_views, tmp_path, capsys):
    for name, (argv, text) in _bad_calibrations(tmp_path, pinhole_views).items():
        assert _status(["calibrate", *argv]) == 2, name
        line = _one_error_line(capsys)
        assert text in line, (name, line)
        assert not (tmp_path / "camera.json").exists(), name


# ------------------------------------------------------------------ camera.json
def test_camera_json_lens_model_round_trips(tmp_path):
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(FISHEYE.to_dict()))
    assert PinholeCamera.from_json(path) == FISHEYE
    plain = {k: v for k, v in PINHOLE.to_dict().items() if k not in ("model", "distortion")}
    path.write_text(json.dumps(plain))  # no model, no distortion: a pinhole camera, as before
    cam = PinholeCamera.from_json(path)
    assert cam.model == "pinhole" and cam.distortion == () and not cam.is_distorted
    assert PINHOLE.is_distorted and FISHEYE.is_distorted
    assert not PinholeCamera(W, H, 500, 500, 320, 240, distortion=(0.0,) * 5).is_distorted


@pytest.mark.parametrize("change, text", [
    ({"model": "fisheye", "distortion": [0.1, 0.0, 0.0]}, "a fisheye camera takes 4 distortion coefficients, got 3"),
    ({"distortion": [0.1] * 6}, "a pinhole camera takes 0 or 4 or 5 or 8 or 12 or 14 distortion coefficients, got 6"),
    ({"model": "kannala"}, "camera model must be one of pinhole, fisheye, omnidirectional, got 'kannala'"),
    ({"model": "omnidirectional"}, "missing key(s) a0, a2, a3, a4, c, d, e"),  # a pinhole's fields
    ({"fx": 0}, "camera fx must be a positive finite number"),
    ({"fy": -300}, "camera fy must be a positive finite number"),
    ({"cx": 2000.0}, "principal point cx=2000 px is far outside the 640x480 image"),
    ({"cy": -400.0}, "principal point cy=-400 px is far outside"),
    ({"fx": 0.8, "fy": 0.8, "cx": 0.5, "cy": 0.5}, "field of view of 179.7 degrees"),  # normalised intrinsics
], ids=["fisheye_3", "pinhole_6", "unknown_model", "omni", "fx_zero", "fy_negative", "cx_far", "cy_far",
        "normalised"])
def test_impossible_camera_json_is_one_line_naming_the_file(change, text, tmp_path):
    path = tmp_path / "scope_camera.json"
    path.write_text(json.dumps({**PINHOLE.to_dict(), **change}))
    with pytest.raises(InputError) as exc:
        PinholeCamera.from_json(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(str(path)) and text in msg, msg


# ------------------------------------------------------------------ undistorted frames
def test_fisheye_video_frames_come_out_undistorted(fisheye_views, tmp_path):
    """The board's rows, straight in the world, are bent in the fisheye frames and straight in the
    stream's frames, where the corners sit where the stream's pinhole camera projects them."""
    video = _write_video(tmp_path / "scope.avi", [img for img, _, _ in fisheye_views])
    (tmp_path / "camera.json").write_text(json.dumps(FISHEYE.to_dict()))
    stream = FrameStream(video)
    cam = stream.camera
    assert cam.model == "pinhole" and cam.distortion == () and cam.size == (W, H)
    assert stream.camera_source == (f"file {tmp_path / 'camera.json'} (fisheye lens with distortion "
                                    f"{list(FISHEYE.distortion)}, frames undistorted to pinhole)")
    assert cam.fov_deg()[0] > 90  # a wide view is kept
    checked = 0
    for frame, (raw, R, t) in zip(stream, fisheye_views, strict=True):
        gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
        straight, bent = find_corners(gray, BOARD), find_corners(raw, BOARD)
        if straight is None or bent is None:
            continue  # the board left the narrower pinhole view
        truth = project(cam, board_points(BOARD, SQUARE), R, t)
        err = min(np.abs(straight.reshape(-1, 2) - p).max() for p in (truth, truth[::-1]))
        assert err < 0.6, err
        assert _straightness(straight) < 0.5
        checked += 1
        if _straightness(bent) > 2.0:
            checked += 100  # some view bends a row by more than 2 px before undistortion
    assert checked > 100 + 8


def test_distorted_sequence_folder_is_undistorted(fisheye_views, tmp_path):
    """A folder whose camera.json has a lens: frames and depth (nearest, z-depth) are undistorted,
    on the stream and when the fusion re-reads them from stream.sequence."""
    rays = pixel_rays(FISHEYE)
    writer = SequenceWriter(tmp_path / "seq", FISHEYE)
    for i, (img, R, t) in enumerate(fisheye_views[:2]):
        z = ((R[:, 2] @ t) / (rays @ R[:, 2])).reshape(H, W)  # rays have z = 1: the hit's z-depth
        z[(z <= 0) | (z > 1.0)] = 0  # no depth beyond 1 m (the plane goes on)
        writer.write_frame(i, cv2.cvtColor(img, cv2.COLOR_GRAY2RGB), z.astype(np.float32))
    writer.finish(np.stack([np.eye(4)] * 2))
    assert json.loads((tmp_path / "seq" / "camera.json").read_text())["model"] == "fisheye"
    stream = FrameStream(tmp_path / "seq")
    und = Undistortion(FISHEYE)
    assert stream.camera == und.camera and "fisheye lens" in stream.camera_source
    frames = list(stream)
    pin_rays = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 2)
    pin_rays = np.concatenate([(pin_rays - [und.camera.cx, und.camera.cy]) / [und.camera.fx, und.camera.fy],
                               np.ones((H * W, 1))], axis=1)
    for frame, (img, R, t) in zip(frames, fisheye_views[:2], strict=False):
        assert np.array_equal(frame.rgb, und.rgb(cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)))
        assert np.array_equal(stream.sequence.read_rgb(frame.index), frame.rgb)
        assert np.array_equal(stream.sequence.read_depth(frame.index), frame.depth)
        z = ((R[:, 2] @ t) / (pin_rays @ R[:, 2])).reshape(H, W)
        both = (frame.depth > 0) & (z > 0) & (z < 0.9)
        assert both.mean() > 0.5
        assert np.median(np.abs(frame.depth[both] / z[both] - 1)) < 2e-3  # the pinhole camera's own z-depth


# ------------------------------------------------------------------ run --fov
@pytest.fixture(scope="module")
def depth_model(tmp_path_factory) -> Path:
    return fx.depth_model(tmp_path_factory.mktemp("models") / "depth.onnx", (32, 32), (56, 56))


def test_run_with_a_field_of_view_guess(tiny_sequence, depth_model, tmp_path):
    """A video without camera.json runs with --fov; summary.json says the intrinsics are a guess."""
    frames = [cv2.imread(str(p)) for p in sorted((tiny_sequence / "rgb").glob("*.png"))]
    video = _write_video(tmp_path / "clip.avi", frames, size=(64, 64))
    out = tmp_path / "run"
    assert main(["run", str(video), "--depth-model", str(depth_model), "--fov", "110", "--out", str(out),
                 "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["camera_source"] == "fov guess 110 deg"
    assert s["camera"]["fx"] == pytest.approx(PinholeCamera.from_fov(64, 64, 110.0).fx)
    assert s["camera"]["model"] == "pinhole" and s["camera"]["distortion"] == []


def test_fov_refusals(tiny_sequence, depth_model, tmp_path, capsys):
    video = _write_video(tmp_path / "clip.avi", [np.full((64, 64), 100, np.uint8)] * 3, size=(64, 64))
    shutil.copy(tiny_sequence / "camera.json", tmp_path / "camera.json")
    base = ["run", str(video), "--depth-model", str(depth_model), "--quiet"]
    camera = ["--camera", str(tmp_path / "camera.json")]
    assert _status([*base, "--out", str(tmp_path / "a"), "--fov", "100", *camera]) == 2
    assert "not allowed with argument" in _one_error_line(capsys)
    for bad in ("180", "0", "nan"):
        assert main([*base, "--out", str(tmp_path / "b"), "--fov", bad]) == 2
        assert "--fov must be between 0 and 170 degrees" in _one_error_line(capsys)
    assert main(["run", str(tiny_sequence), "--out", str(tmp_path / "c"), "--fov", "90", "--quiet"]) == 2
    assert "--fov is for videos" in _one_error_line(capsys)
    with pytest.raises(InputError, match="--fov 160 on 64x1000 frames: .*field of view"):
        FovGuess(160.0).camera(64, 1000)
    assert FrameStream(video, camera=tmp_path / "camera.json").camera_source == f"file {tmp_path / 'camera.json'}"


def test_calibrate_help_imports_no_heavy_library():
    from tests.startup import packages_loaded_by

    loaded = packages_loaded_by("c3f_slam", "calibrate", "--help")
    assert "c3f_slam" in loaded and not loaded & {"numpy", "cv2", "open3d", "onnxruntime", "torch"}, sorted(loaded)
