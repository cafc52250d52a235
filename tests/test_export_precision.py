"""Lighter exports (``--precision float16|int8``): the graphs really are float16 / int8, their
parity with PyTorch's float32 output is measured and bounded, the runtime runs them as it runs
float32 files, and bad options are one line that names the option."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from c3f_core.errors import InputError
from c3f_models import ContraFeat, DepthNet
from c3f_models.cli import main
from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_models.depth.config import DepthNetworkConfig
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.io import Sequence
from c3f_slam.models import DepthModel, DescriptorModel
from export import ParityError, export_model

ROOT = Path(__file__).resolve().parents[1]
ONE_SCALE = DepthNetworkConfig(num_scales=1)
CONTRA_16 = ContraFeatNetworkConfig(descriptor_dim=16, fpn_channels=16, stem_channels=8, head_channels=16)


def _ops(path) -> set[str]:
    return {n.op_type for n in onnx.load(str(path)).graph.node}


def _initializer_types(path) -> set[int]:
    return {i.data_type for i in onnx.load(str(path)).graph.initializer if len(i.dims) >= 2}


@pytest.fixture(scope="module")
def depth_ckpt(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("precision") / "d.ckpt"
    torch.save({"state_dict": DepthNet(ONE_SCALE).state_dict()}, path)
    return path


def test_int8_depth_is_quantised_checked_and_runs_in_the_runtime(depth_ckpt, tiny_sequence, tmp_path):
    """An int8 export holds int8 weights in QDQ form, records its precision, calibration and a
    parity bounded relative to PyTorch's float32 output; the runtime predicts with it close to
    the float32 file."""
    (f32,) = export_model(DepthNet(ONE_SCALE), depth_ckpt, tmp_path / "f32", frames=tiny_sequence, num_frames=2,
                          graphs=["depth"])
    (i8,) = export_model(DepthNet(ONE_SCALE), depth_ckpt, tmp_path / "i8", frames=tiny_sequence, num_frames=2,
                         graphs=["depth"], precision="int8", calibration_frames=4)
    assert {"QuantizeLinear", "DequantizeLinear"} <= _ops(i8) and "DequantizeLinear" not in _ops(f32)
    assert onnx.TensorProto.INT8 in _initializer_types(i8)
    model = DepthModel(i8)
    par = model.metadata.parity
    assert model.metadata.precision == "int8" and par["criterion"] == "relative_mean"
    assert 0 < par["relative_mean_diff"] <= par["tolerance"] == 6e-2 and par["calibration_frames"] == 4
    listed = json.loads((tmp_path / "i8" / "export.json").read_text())["files"]["depthnet.onnx"]
    assert listed["precision"] == "int8"
    seq = Sequence(tiny_sequence)
    rgb = seq.read_rgb(3)
    got, want = model.predict(rgb, seq.camera), DepthModel(f32).predict(rgb, seq.camera)
    assert got.dtype == np.float32 and np.isfinite(got).all()
    assert np.median(np.abs(got - want) / want) < 0.05
    assert "int8 depth model" in model.metadata.describe()


def test_float16_contrafeat_exports_both_graphs_and_the_runtime_uses_the_keypoint_file(tmp_path, tiny_sequence):
    torch.manual_seed(0)
    ckpt = tmp_path / "cf.ckpt"
    torch.save({"state_dict": ContraFeat(CONTRA_16).state_dict()}, ckpt)
    dense, kp = export_model(ContraFeat(CONTRA_16), ckpt, tmp_path / "out", frames=tiny_sequence, num_frames=2,
                             precision="float16")
    assert _initializer_types(dense) == {onnx.TensorProto.FLOAT16}
    runtime = DescriptorModel(dense, prefer_keypoints=True)
    assert runtime.keypoint_file == "used" and runtime.metadata.precision == "float16"
    ds = runtime.metadata.parity["dense_sampling"]
    assert ds["criterion"] == "relative_mean" and ds["relative_mean_diff"] <= ds["tolerance"]
    graph = onnx.load(str(kp)).graph  # the keypoints reach the float32 sampling unrounded
    assert not [n for n in graph.node if n.op_type == "Cast" and "keypoints" in n.input]
    cam = PinholeCamera(64, 64, 50.0, 50.0, 31.5, 31.5)
    points = np.array([[10.0, 12.0], [40.5, 30.25], [63.0, 0.0]], np.float32)
    d = runtime.describe(Sequence(tiny_sequence).read_rgb(2), cam, points)
    assert d.shape == (3, 16) and np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=5e-3)


def test_a_tolerance_the_precision_cannot_meet_fails_and_writes_nothing(depth_ckpt, tiny_sequence, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ParityError, match=r"depthnet.onnx: onnxruntime differs from PyTorch by .* \(mean abs over "
                                          r"the mean magnitude\) .* above the tolerance 1e-09"):
        export_model(DepthNet(ONE_SCALE), depth_ckpt, out, frames=tiny_sequence, num_frames=2, graphs=["depth"],
                     precision="int8", calibration_frames=2, tolerance=1e-9)
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("options, message", [
    ({"precision": "int4"}, "--precision must be one of float32, float16, int8, got int4"),
    ({"precision": "int8", "storage": "float16"}, "--storage float16: applies to --precision float32 only"),
    ({"precision": "int8", "calibration_frames": 0}, "--calibration_frames must be >= 1 for --precision int8"),
    ({"tolerance": -1.0}, "--tolerance must be a positive number, got -1.0"),
])
def test_bad_precision_options_are_one_line(depth_ckpt, tiny_sequence, tmp_path, options, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(")) as exc:
        export_model(DepthNet(ONE_SCALE), depth_ckpt, tmp_path / "out", frames=tiny_sequence, **options)
    assert "\n" not in str(exc.value) and not (tmp_path / "out").exists()


@pytest.mark.e2e
def test_cli_precision_option_exits_2_in_one_line(depth_ckpt, tiny_sequence, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    with pytest.raises(SystemExit) as exc:
        main(["export", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
              "--data.data_dir", str(tiny_sequence.parent), "--trainer.logger", "false", "--ckpt_path",
              str(depth_ckpt), "--frames", str(tiny_sequence), "--output_dir", str(tmp_path / "out"),
              "--precision", "int4"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "--precision must be one of" in err[0]
