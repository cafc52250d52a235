"""DepthNet's networks: disparity mapping, decoder scales, deformable encoder, PoseNet, pretrained loading."""

from __future__ import annotations

import pytest
import torch
import torchvision
from torch import nn

from c3f_core.errors import InputError
from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_models.contrafeat.network import ContraFeatNet
from c3f_models.depth.config import DepthNetworkConfig
from c3f_models.depth.decoder import depth_to_disp, disp_to_depth
from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from c3f_models.encoders import ResnetConfig, ResnetEncoder
from c3f_models.encoders.dcn import DeformConv, deformable_stages


def test_disp_depth_conversion_bounds_and_inverse():
    disp = torch.tensor([0.0, 0.25, 0.5, 1.0])
    depth = disp_to_depth(disp, 0.001, 0.3)
    assert depth[0] == pytest.approx(0.3) and depth[-1] == pytest.approx(0.001)
    assert bool((depth[1:] < depth[:-1]).all())  # larger disparity = nearer
    assert torch.allclose(depth_to_disp(depth, 0.001, 0.3), disp, atol=1e-6)
    # colon depths 1-6 cm sit well inside the sigmoid's range
    d = depth_to_disp(torch.tensor([0.01, 0.06]), 0.001, 0.3)
    assert bool(((d > 0.005) & (d < 0.2)).all())


@pytest.mark.parametrize("size", [(32, 32), (48, 40)])
def test_depth_network_scales_and_range(size):
    net = DepthNetwork(DepthNetworkConfig(num_scales=4, min_depth=0.001, max_depth=0.3))
    x = torch.rand(2, 3, *size)
    disps = net(x)
    assert [tuple(d.shape[-2:]) for d in disps][0] == size
    assert len(disps) == 4 and all(d.shape[:2] == (2, 1) for d in disps)
    assert disps[1].shape[-1] == (size[1] + 1) // 2
    depth = net.to_depth(disps[0])
    assert bool(((depth >= 0.001 - 1e-9) & (depth <= 0.3 + 1e-9)).all())


def test_deformable_encoder_shapes_and_offset_gradient():
    enc = ResnetEncoder(ResnetConfig(dcn=True))
    dcn = [m for m in enc.modules() if isinstance(m, DeformConv)]
    assert len(dcn) == 2 * 2 * 3  # BasicBlocks: two 3x3 convs x two blocks x conv3-conv5
    assert not any(isinstance(m, DeformConv) for m in enc.layer1.modules())
    feats = enc(torch.rand(1, 3, 64, 32))
    assert [f.shape[1] for f in feats] == enc.num_ch_enc == [64, 64, 128, 256, 512]
    assert [tuple(f.shape[-2:]) for f in feats] == [(32, 16), (16, 8), (8, 4), (4, 2), (2, 1)]
    sum(f.square().mean() for f in feats).backward()
    for m in dcn:
        assert m.offset.weight.grad is not None and m.offset.weight.grad.abs().sum() > 0
        assert m.conv.weight.grad.abs().sum() > 0


def test_resnet50_deformable_stages_replace_bottleneck_conv2():
    net = torchvision.models.resnet50(weights=None)
    assert deformable_stages(net) == 4 + 6 + 3
    assert isinstance(net.layer3[0].conv2, DeformConv) and isinstance(net.layer3[0].conv1, nn.Conv2d)
    assert net.layer2[0].conv2.conv.stride == (2, 2)


def test_zero_offsets_reproduce_the_plain_conv():
    conv = nn.Conv2d(8, 16, 3, stride=2, padding=1, bias=False)
    x = torch.rand(1, 8, 12, 12)
    assert torch.allclose(DeformConv.from_conv(conv)(x), conv(x), atol=1e-5)


def test_deformable_conv_under_mixed_precision():
    """torchvision's CPU deformable kernel has no bfloat16: the module runs it in float32."""
    conv = DeformConv(8, 8)
    x = torch.rand(1, 8, 10, 10)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = conv(x)
    assert y.dtype == torch.float32 and torch.allclose(y, conv(x), atol=1e-2)


def test_posenet_outputs_small_rigid_transforms():
    pose = PoseNetwork(DepthNetworkConfig(pose_translation_scale=0.01))
    a, b = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    T = pose(a, b)
    assert T.shape == (2, 4, 4)
    R = T[:, :3, :3]
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3).expand(2, 3, 3), atol=1e-5)
    assert torch.equal(T[:, 3], torch.tensor([0.0, 0, 0, 1]).expand(2, 4))
    assert float(T[:, :3, 3].detach().abs().max()) < 0.1  # Monodepth2's 0.01 output scaling
    small = PoseNetwork(DepthNetworkConfig(pose_translation_scale=1e-3))
    small.load_state_dict(pose.state_dict())
    assert torch.allclose(small(a, b)[:, :3, 3], T[:, :3, 3] / 10, atol=1e-7)


# ---------------------------------------------------------------- pretrained weights from a local file
@pytest.fixture(scope="module")
def resnet18_file(tmp_path_factory):
    torch.manual_seed(0)
    net = torchvision.models.resnet18(weights=None)
    path = tmp_path_factory.mktemp("weights") / "resnet18.pth"
    torch.save(net.state_dict(), path)
    return path, net.state_dict()


def test_pretrained_weights_load_into_depth_encoder(resnet18_file):
    path, state = resnet18_file
    enc = ResnetEncoder(ResnetConfig(pretrained_path=path))
    assert torch.equal(enc.layer3[1].conv2.weight, state["layer3.1.conv2.weight"])
    assert torch.equal(enc.bn1.running_mean, state["bn1.running_mean"])
    # with DCN the weights land in the deformable convs, offsets start at zero
    enc = ResnetEncoder(ResnetConfig(dcn=True, pretrained_path=path))
    assert torch.equal(enc.layer4[0].conv1.conv.weight, state["layer4.0.conv1.weight"])
    assert not enc.layer4[0].conv1.offset.weight.detach().any()


def test_pretrained_weights_for_two_frame_posenet(resnet18_file):
    path, state = resnet18_file
    pose = PoseNetwork(DepthNetworkConfig(pose_pretrained_path=str(path)))
    w = pose.encoder.conv1.weight
    assert w.shape == (64, 6, 7, 7)
    assert torch.allclose(w[:, :3], state["conv1.weight"] / 2) and torch.allclose(w[:, 3:], state["conv1.weight"] / 2)
    assert torch.equal(pose.encoder.layer1[0].conv1.weight, state["layer1.0.conv1.weight"])


def test_pretrained_errors_are_clear(tmp_path, resnet18_file):
    path, _ = resnet18_file
    with pytest.raises(InputError, match="file not found"):
        ResnetEncoder(ResnetConfig(pretrained_path=tmp_path / "missing.pth"))
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a weights file")
    with pytest.raises(InputError, match="junk.pth is not a torch weights file"):
        ResnetEncoder(ResnetConfig(pretrained_path=junk))
    with pytest.raises(InputError, match=r"does not fit this ResNet.*missing keys"):
        ResnetEncoder(ResnetConfig(50, pretrained_path=path))  # ResNet18 weights into a ResNet50
    other = tmp_path / "other.pth"
    torch.save({"weight": torch.zeros(3)}, other)
    with pytest.raises(InputError, match="model.network.pretrained_path: .*other.pth does not fit"):
        DepthNetwork(DepthNetworkConfig(pretrained_path=str(other)))
    with pytest.raises(InputError, match="model.network.encoder_layers must be one of"):
        DepthNetwork(DepthNetworkConfig(encoder_layers=20))


@pytest.mark.parametrize("layers", [18, 50])
def test_narrow_encoder_widths_and_weights(layers):
    wide, narrow = ResnetEncoder(ResnetConfig(layers)), ResnetEncoder(ResnetConfig(layers, width=32))
    feats = narrow(torch.rand(1, 3, 64, 64))
    assert [f.shape[1] for f in feats] == narrow.num_ch_enc == [c // 2 for c in wide.num_ch_enc]
    assert [f.shape[-1] for f in feats] == [32, 16, 8, 4, 2]
    ratio = sum(p.numel() for p in narrow.parameters()) / sum(p.numel() for p in wide.parameters())
    assert 0.2 < ratio < 0.3  # a quarter of the weights


def test_narrow_networks_and_their_errors(resnet18_file):
    depth = DepthNetwork(DepthNetworkConfig(num_scales=2, encoder_width=16))
    assert depth(torch.rand(1, 3, 64, 64))[0].shape == (1, 1, 64, 64)
    pose = PoseNetwork(DepthNetworkConfig(pose_encoder_width=16))
    assert pose.encoder.conv1.weight.shape == (16, 6, 7, 7)
    assert pose(torch.rand(2, 3, 64, 64), torch.rand(2, 3, 64, 64)).shape == (2, 4, 4)
    desc = ContraFeatNet(ContraFeatNetworkConfig(descriptor_dim=8, fpn_channels=16, stem_channels=8, backbone_width=16))
    assert desc(torch.rand(1, 3, 64, 64)).shape == (1, 8, 64, 64)
    path, _ = resnet18_file
    with pytest.raises(InputError, match="does not fit this ResNet.*wrong-shaped"):
        ResnetEncoder(ResnetConfig(width=32, pretrained_path=path))  # ImageNet weights are for width 64
    with pytest.raises(InputError, match="model.network.encoder_width must be a multiple of 8"):
        DepthNetworkConfig(encoder_width=20)
    with pytest.raises(InputError, match="model.network.backbone_width: a ResNet's width must be a multiple of 8"):
        ContraFeatNet(ContraFeatNetworkConfig(backbone_width=12))
