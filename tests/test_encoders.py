"""Encoders chosen by name (docs/add_network.md): the interface every encoder follows, the choice and
its refusals, MobileNetV3-Small weights from a local file, the descriptor network's key layout, and
end to end a MobileNet DepthNet and ContraFeat from YAML through fit, ONNX export and the runtime."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import onnx
import pytest
import torch
import torchvision

from c3f_core.errors import InputError
from c3f_models.cli import main
from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_models.contrafeat.module import ContraFeat
from c3f_models.contrafeat.network import ContraFeatNet
from c3f_models.depth.config import DepthNetworkConfig
from c3f_models.depth.module import DepthNet
from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from c3f_models.encoders import ENCODERS, STRIDES, MobileNetConfig, MobileNetEncoder, ResnetConfig, ResnetEncoder
from c3f_slam.models.metadata import ModelMetadata

ROOT = Path(__file__).resolve().parents[1]
MOBILENET = "mobilenet_v3_small"
TINY_DESCRIPTORS = dict(descriptor_dim=8, fpn_channels=8, stem_channels=4)


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


def _weights(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@pytest.mark.parametrize("name", sorted(ENCODERS))
@pytest.mark.parametrize("in_channels", [3, 6])
def test_every_encoder_gives_five_maps_at_the_strides(name, in_channels):
    cls = ENCODERS[name]
    encoder = cls(cls.config_class(in_channels=in_channels)).eval()
    maps = encoder(torch.rand(2, in_channels, 50, 38))  # not multiples of 32
    assert [m.shape[1] for m in maps] == encoder.num_ch_enc and len(maps) == len(STRIDES)
    assert [tuple(m.shape[-2:]) for m in maps] == [(math.ceil(50 / s), math.ceil(38 / s)) for s in STRIDES]


def test_mobilenet_is_a_small_encoder():
    mobile, resnet = MobileNetEncoder(MobileNetConfig()), ResnetEncoder(ResnetConfig())
    assert mobile.num_ch_enc == [16, 16, 24, 48, 96] and _weights(mobile) == 870_560
    assert _weights(resnet) == 11_176_512  # ResNet18 without its classifier
    assert MobileNetEncoder(MobileNetConfig(width_mult=0.5)).num_ch_enc == [8, 8, 16, 24, 48]


def test_networks_take_the_chosen_encoder():
    config = DepthNetworkConfig(encoder=MOBILENET, pose_encoder=MOBILENET, num_scales=2)
    depth, pose = DepthNetwork(config), PoseNetwork(config)
    assert isinstance(depth.encoder, MobileNetEncoder) and isinstance(pose.encoder, MobileNetEncoder)
    x = torch.rand(2, 3, 64, 64)
    assert depth(x)[0].shape == (2, 1, 64, 64) and pose(x, x).shape == (2, 4, 4)
    by_path = DepthNetwork(DepthNetworkConfig(encoder="c3f_models.encoders.MobileNetEncoder",
                                              encoder_options={"width_mult": 0.5}, num_scales=1))
    assert isinstance(by_path.encoder, MobileNetEncoder) and by_path.encoder.num_ch_enc[-1] == 48
    descriptors = ContraFeatNet(ContraFeatNetworkConfig(backbone=MOBILENET, **TINY_DESCRIPTORS))
    assert descriptors(x).shape == (2, 8, 64, 64)
    assert isinstance(DepthNetwork(DepthNetworkConfig(num_scales=1)).encoder, ResnetEncoder)  # the default


@pytest.mark.parametrize(("settings", "message"), [
    ({"encoder": "nope"}, r"model.network.encoder must be one of \['mobilenet_v3_small', 'resnet'\] or the class"),
    ({"encoder": "torch.nn.Conv2d"}, "class path of a c3f_models.encoders.Encoder subclass"),
    ({"encoder": MOBILENET, "dcn": True}, "model.network.dcn is a ResNet option, but model.network.encoder is"),
    ({"pose_encoder": MOBILENET, "pose_encoder_width": 32}, "model.network.pose_encoder_width is a ResNet option"),
    ({"encoder": MOBILENET, "encoder_options": {"depth": 3}}, "encoder_options: mobilenet_v3_small has no setting "
                                                              "'depth' .it takes width_mult"),
    ({"encoder_options": {"layers": 34}}, "encoder_options.layers: set by model.network.encoder_layers"),
    ({"pose_encoder": MOBILENET, "pose_encoder_options": {"in_channels": 3}}, "set by PoseNet"),
    ({"pose_encoder_options": {"dcn": True}}, "pose_encoder_options.dcn: set by PoseNet .no deformable"),
])
def test_encoder_choice_refusals(settings, message):
    with pytest.raises(InputError, match=message):
        DepthNetworkConfig(**settings)


def test_encoder_build_refusals():
    with pytest.raises(InputError, match=r"model.network.encoder_options.width_mult must be positive"):
        DepthNetwork(DepthNetworkConfig(encoder=MOBILENET, encoder_options={"width_mult": 0.0}))
    with pytest.raises(InputError, match="model.network.backbone_width is a ResNet option"):
        ContraFeatNetworkConfig(backbone=MOBILENET, backbone_width=32)
    with pytest.raises(InputError, match="backbone_options.dcn: set by the descriptor network .no deformable"):
        ContraFeatNetworkConfig(backbone_options={"dcn": True})


def test_mobilenet_weights_from_a_local_torchvision_file(tmp_path):
    ref = torchvision.models.mobilenet_v3_small(weights=None)
    path = tmp_path / "mobilenet_v3_small.pth"
    torch.save(ref.state_dict(), path)
    depth = DepthNetwork(DepthNetworkConfig(encoder=MOBILENET, pretrained_path=str(path), num_scales=1))
    assert torch.equal(depth.encoder.features[9].block[1][0].weight, ref.features[9].block[1][0].weight)
    pose = PoseNetwork(DepthNetworkConfig(pose_encoder=MOBILENET, pose_pretrained_path=str(path)))
    first, want = pose.encoder.features[0][0].weight, ref.features[0][0].weight
    assert first.shape[1] == 6 and torch.allclose(first[:, :3], want / 2) and torch.allclose(first[:, 3:], want / 2)
    with pytest.raises(InputError, match=r"model.network.pretrained_path: .* does not fit this MobileNetV3-Small: "
                                         r".*wrong-shaped"):
        DepthNetwork(DepthNetworkConfig(encoder=MOBILENET, encoder_options={"width_mult": 0.5},
                                        pretrained_path=str(path)))
    # a DepthNet checkpoint's MobileNet depth encoder starts ContraFeat's stream
    ckpt = tmp_path / "depthnet.ckpt"
    model = DepthNet(DepthNetworkConfig(encoder=MOBILENET, pose_encoder=MOBILENET, num_scales=1))
    torch.save({"state_dict": model.state_dict()}, ckpt)
    net = ContraFeatNet(ContraFeatNetworkConfig(backbone=MOBILENET, pretrained_path=str(ckpt), **TINY_DESCRIPTORS))
    assert torch.equal(net.encoder.features[4].block[0][1].running_var,
                       model.depth_net.encoder.features[4].block[0][1].running_var)


@pytest.mark.parametrize(("backbone", "first_key"), [("resnet", "conv1.weight"), (MOBILENET, "features.0.0.weight")])
def test_descriptor_network_keeps_encoder_keys_at_its_top_level(backbone, first_key):
    """The encoder's keys sit beside fpn/stem/head (the layout of the zoo's trained weights); they load back."""
    config = ContraFeatNetworkConfig(backbone=backbone, **TINY_DESCRIPTORS)
    trained = ContraFeat(config).eval()
    state = trained.state_dict()
    assert next(iter(state)) == "net." + first_key and not any(k.startswith("net.encoder.") for k in state)
    fresh = ContraFeat(config).eval()
    fresh.load_state_dict(state)
    x = torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        torch.testing.assert_close(fresh.net(x), trained.net(x), rtol=0, atol=0)


def test_mobilenet_configs_build_from_yaml_with_cli_overrides(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["c3f_models"])
    depth = main(["--config", str(ROOT / "configs/depthnet/small.yaml"), "--config",
                  str(ROOT / "configs/depthnet/mobilenet.yaml"), "--model.network.encoder_options",
                  "{width_mult: 0.75}", "--trainer.logger", "false"], run=False).model
    assert isinstance(depth, DepthNet) and depth.network_config.encoder == MOBILENET
    assert isinstance(depth.pose_net.encoder, MobileNetEncoder) and depth.hparams["network"]["encoder_options"] == {
        "width_mult": 0.75}
    features = main(["--config", str(ROOT / "configs/contrafeat/small.yaml"), "--config",
                     str(ROOT / "configs/contrafeat/mobilenet.yaml"), "--trainer.logger", "false"], run=False).model
    assert isinstance(features, ContraFeat) and isinstance(features.net.encoder, MobileNetEncoder)


def _metadata(path: Path) -> ModelMetadata:
    props = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
    return ModelMetadata.from_props(props, str(path))


def _fit_and_export(model: str, data: Path, root: Path, graphs: str, *extra: str) -> Path:
    """A 2-step CPU fit of configs/MODEL/small.yaml + mobilenet.yaml at 48x48, then ``export`` of
    ``graphs`` with the run's saved config; returns the export folder."""
    configs = ["configs/trainer/cpu_smoke.yaml", f"configs/{model}/small.yaml", f"configs/{model}/mobilenet.yaml"]
    main(["fit", *(a for c in configs for a in ("--config", str(ROOT / c))),
          "--data.data_dir", str(data), "--data.frames.size", "[48, 48]", "--data.loader.batch_size", "2",
          "--trainer.max_steps", "2", "--trainer.limit_val_batches", "1", "--trainer.enable_progress_bar", "false",
          "--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root), *extra])
    run = root / "tb" / "version_0"
    saved = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert saved["global_step"] == 2
    assert any(".encoder.features.0.0.weight" in k or k == "net.features.0.0.weight" for k in saved["state_dict"])
    main(["export", "--config", str(run / "config.yaml"), "--ckpt_path", str(run / "checkpoints" / "last.ckpt"),
          "--output_dir", str(root / "onnx"), "--graphs", graphs])
    return root / "onnx"


@pytest.mark.e2e
def test_mobilenet_fits_exports_and_runs_in_the_runtime(sim_dataset, tiny_sequence, tmp_path, monkeypatch):
    """Both models with MobileNetV3-Small from the YAML override: fit, export (parity checked), SLAM."""
    from c3f_slam.cli.main import main as slam

    monkeypatch.setattr(sys, "argv", ["c3f_models"])
    depth_dir = _fit_and_export("depthnet", sim_dataset, tmp_path / "depth", "[depth, pose]")
    feature_dir = _fit_and_export("contrafeat", sim_dataset, tmp_path / "features", "[descriptors]",
                                  "--data.sampling.gaps", "[1, 2]")
    for path in (depth_dir / "depthnet.onnx", depth_dir / "posenet.onnx", feature_dir / "contrafeat.onnx"):
        meta = _metadata(path)
        assert meta.parity["max_abs_diff"] <= meta.parity["tolerance"] and meta.preprocessing.size == (48, 48)
        network = meta.training_config["model"]["init_args"]["network"]
        assert MOBILENET in (network.get("encoder"), network.get("backbone"))
    out = tmp_path / "slam"
    assert slam(["run", str(tiny_sequence), "--depth-model", str(depth_dir / "depthnet.onnx"), "--feature-model",
                 str(feature_dir / "contrafeat.onnx"), "--out", str(out), "--set", "frames.max_frames=5",
                 "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["frames"] == 5
    assert (summary["depth_source"], summary["descriptors"]) == ("model", "contrafeat")
