"""ONNX model loading and running without torch (c3f_slam.models) and the SLAM model path.

The models are tiny graphs with closed forms (tests/onnx_fixtures.py), so predictions are
checked exactly, including the frame <-> network-grid mapping (crop + resize).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.cli.main import main
from c3f_slam.config import PREDICTED_DEPTH_RESIDUAL_SHARE
from c3f_slam.frames.preprocess import prepare_network_input
from c3f_slam.frames.stream import StreamFrame
from c3f_slam.models import DepthModel, DescriptorModel, ModelMetadata, OnnxModel, PoseModel
from c3f_slam.pipeline.frontend import ModelDepth
from c3f_slam.pipeline.fusion_frames import CACHE_DIR, PredictedFrames
from c3f_slam.pipeline.sources import resolve_sources
from tests import onnx_fixtures as fx
from tests.test_import_boundary import BLOCK_TORCH

ROOT = Path(__file__).resolve().parents[1]

# A 80x72 frame, centre crop 64x64 at (x0, y0) = (8, 4), network 32x32 (a 2x downsample).
CAM = PinholeCamera(80, 72, 60.0, 60.0, 39.5, 35.5)
CROP, SIZE, X0, Y0 = (64, 64), (32, 32), 8, 4


def _one_error_line(exc: pytest.ExceptionInfo, name: str) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and name in msg, msg
    return msg


def _cli_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def _ramp_frame() -> np.ndarray:
    """Grey value x' + y' + 10 inside the crop box (x', y' crop pixels), white outside."""
    rgb = np.full((72, 80, 3), 255, np.uint8)
    yy, xx = np.mgrid[0:64, 0:64]
    rgb[Y0 : Y0 + 64, X0 : X0 + 64] = (xx + yy + 10)[..., None].astype(np.uint8)
    return rgb


# ---------------------------------------------------------------------- loader


def test_metadata_round_trip(tmp_path):
    meta = fx.metadata("depth", SIZE, CROP)
    assert ModelMetadata.from_props(meta.to_props()) == meta
    model = OnnxModel(fx.depth_model(tmp_path / "d.onnx", SIZE, CROP), expect_kind="depth")
    assert model.metadata == meta
    assert model.metadata.input_size == SIZE and model.metadata.preprocessing.crop == CROP
    assert model.input_names == ("image",) and model.output_names == ("depth",)


def _bad_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    good = fx.depth_model(tmp / "good.onnx", SIZE)
    data = good.read_bytes()
    (tmp / "half.onnx").write_bytes(data[: len(data) // 2])
    (tmp / "noise.onnx").write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    fx.write(tmp / "plain.onnx", fx.depth_graph(SIZE), None)
    props = fx.metadata("depth", SIZE).to_props()
    props["c3f.schema_version"] = "99"
    fx.write(tmp / "future.onnx", fx.depth_graph(SIZE), props)
    fx.descriptor_model(tmp / "feat.onnx", SIZE)
    fx.write(tmp / "renamed.onnx", fx.depth_graph(SIZE, output="disp"), fx.metadata("depth", SIZE))
    fx.write(tmp / "resized.onnx", fx.depth_graph((48, 48)), fx.metadata("depth", SIZE))
    return {
        "missing": (tmp / "nope.onnx", "not found"),
        "truncated": (tmp / "half.onnx", "not a readable ONNX model"),
        "random bytes": (tmp / "noise.onnx", "not a readable ONNX model"),
        "no metadata": (tmp / "plain.onnx", "not a C3Fusion export"),
        "newer schema": (tmp / "future.onnx", "schema version 99 is newer"),
        "wrong kind": (tmp / "feat.onnx", "feat.onnx is a descriptors model, expected a depth model"),
        "graph output": (tmp / "renamed.onnx", "'disp'"),
        "graph size": (tmp / "resized.onnx", "48x48 but the metadata size is 32x32"),
    }


def test_bad_files_give_one_line_errors(tmp_path):
    for case, (path, expected) in _bad_files(tmp_path).items():
        with pytest.raises(InputError) as exc:
            DepthModel(path, option="--depth-model")
        msg = _one_error_line(exc, path.name)
        assert msg.startswith("--depth-model: ") and expected in msg, (case, msg)


def test_run_validates_feeds(tmp_path):
    static = OnnxModel(fx.depth_model(tmp_path / "s.onnx", (128, 128)), option="--depth-model")
    with pytest.raises(InputError) as exc:
        static.run({"image": np.zeros((1, 3, 96, 160), np.float32)})
    assert "input image is 160x96 but the model takes 128x128" in _one_error_line(exc, "s.onnx")
    bad_feeds = (np.zeros((1, 3, 128, 128)), np.zeros((1, 4, 128, 128), np.float32),
                 np.zeros((3, 128, 128), np.float32))
    for bad in bad_feeds:
        with pytest.raises(InputError):
            static.run({"image": bad})
    with pytest.raises(InputError, match="do not match the model inputs"):
        static.run({"img": np.zeros((1, 3, 128, 128), np.float32)})
    dynamic = DepthModel(fx.depth_model(tmp_path / "dyn.onnx", SIZE, dynamic=True))
    x = np.random.default_rng(1).random((2, 3, 24, 40), dtype=np.float32)
    np.testing.assert_allclose(dynamic.predict_batch(x), fx.DEPTH_A + fx.DEPTH_B * x.mean(axis=1), atol=1e-6)


# ---------------------------------------------------------------------- nets on frames


def test_depth_predict_maps_crop_and_resize_exactly(tmp_path):
    path = fx.depth_model(tmp_path / "d.onnx", SIZE, CROP)
    rgb = _ramp_frame()
    yy, xx = np.mgrid[0:64, 0:64].astype(np.float64)
    depth = DepthModel(path).predict(rgb, CAM)
    assert depth.shape == (72, 80) and depth.dtype == np.float32
    inside = np.zeros((72, 80), bool)
    inside[Y0 : Y0 + 64, X0 : X0 + 64] = True
    assert np.all(depth[~inside] == 0)
    # 2x2 area averages are exact on a linear ramp; linear upsampling reproduces it inside
    # (the outermost row and column clamp to the edge sample).
    want = fx.DEPTH_A + fx.DEPTH_B * (xx + yy + 10) / 255.0
    got = depth[Y0 : Y0 + 64, X0 : X0 + 64]
    np.testing.assert_allclose(got[1:-1, 1:-1], want[1:-1, 1:-1], atol=1e-6)
    nearest = DepthModel(path, upsample="nearest").predict(rgb, CAM)[Y0 : Y0 + 64, X0 : X0 + 64]
    block = 2 * (xx // 2) + 2 * (yy // 2) + 11  # the 2x2 block average, crop pixel -> its block
    np.testing.assert_allclose(nearest, fx.DEPTH_A + fx.DEPTH_B * block / 255.0, atol=1e-6)


def test_depth_identity_grid_and_batch_api(tmp_path):
    model = DepthModel(fx.depth_model(tmp_path / "d.onnx", CROP, CROP))
    rgb = np.random.default_rng(2).integers(0, 200, (72, 80, 3), dtype=np.uint8)
    depth, view = model.predict_network(rgb, CAM)
    crop = rgb[Y0 : Y0 + 64, X0 : X0 + 64].astype(np.float64) / 255.0
    np.testing.assert_allclose(depth, fx.DEPTH_A + fx.DEPTH_B * crop.mean(axis=2), atol=1e-6)
    assert view.box == (X0, Y0, 64, 64) and view.camera.cx == CAM.cx - X0 and view.camera.cy == CAM.cy - Y0
    np.testing.assert_array_equal(model.predict(rgb, CAM)[Y0 : Y0 + 64, X0 : X0 + 64], depth)
    assert model.depth_range == (fx.DEPTH_A, fx.DEPTH_A + fx.DEPTH_B)
    with pytest.raises(InputError, match="d.onnx.*crop 64x64 is larger than the image 48x48"):
        model.predict(rgb[:48, :48], PinholeCamera(48, 48, 40.0, 40.0, 23.5, 23.5))


def test_describe_samples_bilinearly_in_network_pixels(tmp_path):
    model = DescriptorModel(fx.descriptor_model(tmp_path / "f.onnx", SIZE, CROP, dim=8))
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 200, (72, 80, 3), dtype=np.uint8)
    # NumPy reference: the network input, the 1x1 conv, L2 normalisation, bilinear sampling
    net, _, _ = prepare_network_input(rgb, CAM, crop=CROP, size=SIZE, specular=False)
    w, b = fx.descriptor_weights(8)
    dmap = np.einsum("kc,hwc->khw", w, net.astype(np.float64) / 255.0) + b[:, None, None]
    dmap /= np.linalg.norm(dmap, axis=0, keepdims=True)
    xy = np.concatenate([rng.uniform([X0, Y0], [X0 + 63, Y0 + 63], (40, 2)),
                         [[X0, Y0], [X0 + 63.0, Y0 + 63.0], [2.0, 70.0], [79.0, 0.0], [40.25, 36.75]]])
    u = (xy[:, 0] - X0 + 0.5) * 32 / 64 - 0.5
    v = (xy[:, 1] - Y0 + 0.5) * 32 / 64 - 0.5
    want = np.stack([map_coordinates(c, [v, u], order=1, mode="nearest") for c in dmap], axis=1)
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    got = model.describe(rgb, CAM, xy)
    assert got.shape == (45, 8) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-5)
    assert model.describe(rgb, CAM, np.zeros((0, 2))).shape == (0, 8)
    dmap_net, _ = model.descriptor_map(rgb, CAM)
    np.testing.assert_allclose(dmap_net, dmap, atol=1e-5)


def test_pose_predict(tmp_path):
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.01, -0.02, 0.03]))[0]
    T[:3, 3] = [0.001, -0.002, 0.004]
    model = PoseModel(fx.pose_model(tmp_path / "p.onnx", T, SIZE, CROP))
    rng = np.random.default_rng(4)
    a, b = (rng.integers(0, 200, (72, 80, 3), dtype=np.uint8) for _ in range(2))
    got = model.predict(a, b, CAM)
    assert got.shape == (4, 4) and got.dtype == np.float64
    np.testing.assert_allclose(got, T, atol=1e-6)
    x = np.zeros((3, 3, 32, 32), np.float32)
    assert model.predict_batch(x, x).shape == (3, 4, 4)


LOAD_WITHOUT_TORCH = r"""
import sys
import numpy as np
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.models import DepthModel
cam = PinholeCamera(80, 72, 60.0, 60.0, 39.5, 35.5)
depth = DepthModel(sys.argv[1]).predict(np.full((72, 80, 3), 51, np.uint8), cam)
assert abs(float(depth[36, 40]) - (A + B * 0.2)) < 1e-6, depth[36, 40]
assert not any(m == "torch" or m.startswith("torch.") for m in sys.modules), "torch got imported"
print("predicted without torch")
"""


def test_loader_runs_with_torch_unimportable(tmp_path):
    path = fx.depth_model(tmp_path / "d.onnx", SIZE, CROP)
    block = BLOCK_TORCH.split("import {package}")[0]
    code = block + LOAD_WITHOUT_TORCH.replace("A + B", f"{fx.DEPTH_A} + {fx.DEPTH_B}")
    out = subprocess.run([sys.executable, "-c", code, str(path)], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "predicted without torch" in out.stdout


# ---------------------------------------------------------------------- SLAM wiring


def test_sources_follow_the_models_given():
    assert resolve_sources(None, None, None, None) == ("sift", "files")
    assert resolve_sources(None, None, "d.onnx", "f.onnx") == ("contrafeat", "model")
    assert resolve_sources("sift", None, "d.onnx", None) == ("sift", "model")
    for args, msg in [(("contrafeat", None, None, None), "needs --feature-model"),
                      ((None, "model", None, None), "needs --depth-model"),
                      (("sift", None, None, "f.onnx"), "--feature-model is used with --descriptors contrafeat"),
                      ((None, "files", "d.onnx", None), "--depth-model is used with --depth-source model")]:
        with pytest.raises(InputError, match=msg):
            resolve_sources(*args)


def test_predicted_frames_cache_round_trip(tmp_path):
    provider = ModelDepth(DepthModel(fx.depth_model(tmp_path / "d.onnx", SIZE, CROP)), CAM)
    rgb = _ramp_frame()
    frame = StreamFrame(index=7, timestamp=0.25, rgb=rgb, depth=None, status="ok", mean_luma=100.0)
    frames = PredictedFrames(tmp_path / "out" / CACHE_DIR, provider)
    assert provider.depth(frame).shape == (72, 80)
    frames.record(0, frame)
    net_rgb, depth = frames.load(0)
    assert net_rgb.shape == (32, 32, 3) and depth.shape == (32, 32) and depth.dtype == np.float32
    np.testing.assert_allclose(depth, provider.predict(frame).network, rtol=1e-3)
    np.testing.assert_array_equal(frames.K, provider.view.camera.K)
    frames.close()
    assert not (tmp_path / "out" / CACHE_DIR).exists()


def test_model_depth_scale_multiplies_both_grids(tmp_path):
    model = DepthModel(fx.depth_model(tmp_path / "d.onnx", SIZE, CROP))
    frame = StreamFrame(index=3, timestamp=0.1, rgb=_ramp_frame(), depth=None, status="ok", mean_luma=100.0)
    plain, scaled = ModelDepth(model, CAM).predict(frame), ModelDepth(model, CAM, scale=2.5).predict(frame)
    assert plain.network.max() > 0
    np.testing.assert_allclose(scaled.network, 2.5 * plain.network, rtol=1e-6)
    np.testing.assert_allclose(scaled.frame, 2.5 * plain.frame, rtol=1e-5, atol=1e-7)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="--depth-scale must be a positive number"):
            ModelDepth(model, CAM, scale=bad)
    assert (ModelDepth(model, CAM).scale, ModelDepth(model, CAM).scale_source) == (1.0, "none")


def test_model_depth_scale_defaults_to_the_recorded_metric_scale(tmp_path):
    meta = fx.metadata("depth", SIZE, CROP)
    meta.depth["metric_scale"] = 4.0
    model = DepthModel(fx.write(tmp_path / "d.onnx", fx.depth_graph(SIZE), meta))
    assert model.metric_scale == 4.0
    frame = StreamFrame(index=3, timestamp=0.1, rgb=_ramp_frame(), depth=None, status="ok", mean_luma=100.0)
    provider = ModelDepth(model, CAM)
    assert (provider.scale, provider.scale_source) == (4.0, "model metadata")
    np.testing.assert_allclose(provider.predict(frame).network, 4.0 * model.predict_network(frame.rgb, CAM)[0],
                               rtol=1e-6)
    given = ModelDepth(model, CAM, scale=1.0)  # the option wins, also when it is 1
    assert (given.scale, given.scale_source) == (1.0, "option")
    for bad in ("x", -2.0, None):
        meta.depth["metric_scale"] = bad
        assert DepthModel(fx.write(tmp_path / "b.onnx", fx.depth_graph(SIZE), meta)).metric_scale is None


def test_depth_scale_needs_model_depth(tiny_sequence, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", str(tiny_sequence), "--depth-source", "files", "--depth-scale", "2", "--out", str(out),
                 "--quiet"]) == 2
    assert "--depth-scale applies to model depth (--depth-model) only" in _cli_error(capsys)


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("models")
    return {
        "depth": fx.depth_model(d / "depth.onnx", SIZE, (56, 56)),
        "feat": fx.descriptor_model(d / "feat.onnx", SIZE, (56, 56)),
    }


def test_slam_with_contrafeat_descriptors(tiny_sequence, models, tmp_path):
    out = tmp_path / "run"
    rc = main(["run", str(tiny_sequence), "--descriptors", "contrafeat", "--feature-model", str(models["feat"]),
               "--depth-source", "files", "--out", str(out), "--set", "fragments.min_correspondences=15", "--quiet"])
    assert rc == 0
    assert (out / "trajectory.txt").is_file()
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["descriptors"] == "contrafeat" and s["depth_source"] == "files"
    assert s["config"]["match_filter"]["residual_relative_tolerance"] == 0.0  # depth files: the fixed bound
    assert s["models"]["descriptors"]["file"].endswith("feat.onnx")


def test_slam_wrong_model_kind_is_one_line_error(tiny_sequence, models, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", str(tiny_sequence), "--depth-model", str(models["feat"]), "--out", str(out), "--quiet"]) == 2
    line = _cli_error(capsys)
    assert "--depth-model" in line and "feat.onnx is a descriptors model, expected a depth model" in line
    assert json.loads((out / "summary.json").read_text())["status"] == "error"


def test_slam_model_depth_without_depth_folder(tiny_sequence, models, tmp_path):
    seq = tmp_path / "rgb_only"
    shutil.copytree(tiny_sequence, seq, ignore=shutil.ignore_patterns("depth"))
    out = tmp_path / "run"
    assert main(["run", str(seq), "--depth-model", str(models["depth"]), "--out", str(out),
                 "--set", "fragments.min_correspondences=15", "--depth-scale", "1.5", "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["depth_source"] == "model" and s["descriptors"] == "sift"
    assert s["depth_scale"] == {"factor": 1.5, "source": "option"}
    assert s["config"]["match_filter"]["residual_relative_tolerance"] == PREDICTED_DEPTH_RESIDUAL_SHARE
    assert s["config"]["match_filter"]["reprojection_refit"] is False  # off by default
    assert s["frames"] == 8 and s["registered_frames"] >= 1 and (out / "trajectory.txt").is_file()
    assert not (out / CACHE_DIR).exists()


def test_slam_model_depth_on_a_video(tiny_sequence, models, tmp_path):
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 64))
    for p in sorted((tiny_sequence / "rgb").glob("*.png")):
        writer.write(cv2.imread(str(p)))
    writer.release()
    shutil.copy(tiny_sequence / "camera.json", tmp_path / "camera.json")
    out = tmp_path / "run"
    assert main(["run", str(video), "--depth-model", str(models["depth"]), "--feature-model", str(models["feat"]),
                 "--out", str(out), "--set", "fragments.min_correspondences=15", "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["frames"] == 8 and s["descriptors"] == "contrafeat"
    assert not (out / CACHE_DIR).exists()


def test_a_truncated_video_is_not_ok(tiny_sequence, models, tmp_path, capsys):
    """A video cut short: the frames before the cut are reconstructed, the run says
    'truncated' (never ok), one error line, exit 2."""
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 64))
    for p in sorted((tiny_sequence / "rgb").glob("*.png")):
        writer.write(cv2.imread(str(p)))
    writer.release()
    data = video.read_bytes()
    video.write_bytes(data[: len(data) // 2])
    shutil.copy(tiny_sequence / "camera.json", tmp_path / "camera.json")
    out = tmp_path / "run"
    assert main(["run", str(video), "--depth-model", str(models["depth"]), "--out", str(out),
                 "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet"]) == 2
    assert "of the 8 frames its container declares" in _cli_error(capsys)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "truncated" and s["frames_declared"] == 8 and 0 < s["frames"] < 8


def test_inspect(models, tmp_path, capsys):
    assert main(["inspect", str(models["depth"])]) == 0
    out = capsys.readouterr().out
    for text in ("kind:            depth", "input size:      32x32", "depth [m]: (batch, 1, height, width)",
                 "centre crop:   56x56", "depth range:     0.01 .. 0.06", "sha256", "parity"):
        assert text in out, text
    assert "metric scale" not in out
    meta = fx.metadata("depth", SIZE, CROP)
    meta.depth.update(metric_scale=5.9, metric_scale_frames=32, metric_scale_spread=0.12)
    assert main(["inspect", str(fx.write(tmp_path / "scaled.onnx", fx.depth_graph(SIZE), meta))]) == 0
    assert "metric scale:    x 5.9 to metres (training data, 32 frames, spread 0.12)" in capsys.readouterr().out
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not onnx")
    assert main(["inspect", str(bad)]) == 2
    assert "bad.onnx" in _cli_error(capsys)


def test_models_with_the_same_preprocessing_share_one_prepared_input(models, monkeypatch):
    """Depth and descriptor models see the same frame: crop/resize/inpainting run once."""
    import c3f_slam.models.nets as nets

    calls = []
    real = nets.prepare_network_input
    monkeypatch.setattr(nets, "prepare_network_input", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(nets.FrameModel, "_last_input", None)
    depth, desc = DepthModel(models["depth"]), DescriptorModel(models["feat"])
    cam = CAM
    rgb = np.random.default_rng(0).integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8)
    x1, _ = depth.prepare(rgb, cam)
    x2, _ = desc.prepare(rgb, cam)
    assert len(calls) == 1 and x1 is x2
    depth.predict(rgb, cam)  # the cached input runs through onnxruntime (read-only array)
    other = rgb.copy()  # equal pixels, another frame object: prepared again
    x3, _ = desc.prepare(other, cam)
    assert len(calls) == 2 and np.array_equal(x3, x1)
