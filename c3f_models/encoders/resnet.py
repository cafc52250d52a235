"""The ResNet encoder (torchvision architectures built with ``weights=None``), optionally deformable.

Nothing is downloaded: ImageNet weights come only from a local file holding a torchvision
ResNet ``state_dict``, or a DepthNet checkpoint's depth encoder (:mod:`c3f_models.encoders.weights`).
Its state-dict keys are torchvision's (``conv1.*``, ``bn1.*``, ``layer1.*`` ... ``layer4.*``), so
such files load as they are.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn
from torchvision import models

from c3f_core.errors import InputError
from c3f_models.encoders.base import Encoder, option_of
from c3f_models.encoders.dcn import deformable_stages
from c3f_models.encoders.weights import load_pretrained

RESNETS = {18: models.resnet18, 34: models.resnet34, 50: models.resnet50}
STANDARD_WIDTH = 64  #: channels of a torchvision ResNet's stem and first stage


@dataclass(frozen=True)
class ResnetConfig:
    """A torchvision ResNet as an encoder (checked when it is built).

    Attributes:
        layers: 18, 34 or 50.
        width: channels of the stem and the first stage (64: torchvision's ResNet; 32: a lighter
            encoder with a quarter of the weights; only 64 fits an ImageNet file).
        dcn: deformable 3x3 convolutions in conv3-conv5 (``layer2``-``layer4``); a ResNet-only option.
        in_channels: 3 x the frames stacked along channels (6 for PoseNet).
        pretrained_path: local torchvision ResNet state dict (ImageNet) or DepthNet checkpoint; None = from scratch.
    """

    layers: int = 18
    width: int = STANDARD_WIDTH
    dcn: bool = False
    in_channels: int = 3
    pretrained_path: str | None = None


def build_resnet(num_layers: int, option: str = "layers", width: int = STANDARD_WIDTH,
                 width_option: str = "width") -> models.ResNet:
    """An untrained torchvision ResNet with 18, 34 or 50 layers.

    ``width``: channels of the stem and the first stage (the stages have width, 2, 4 and 8 times
    it, times the block expansion); 64 is torchvision's architecture, a smaller width gives a
    lighter encoder (32: a quarter of the weights and of the multiply-adds) that no ImageNet
    file fits.
    """
    if num_layers not in RESNETS:
        raise InputError(f"{option} must be one of {sorted(RESNETS)}, got {num_layers}")
    if width < 8 or width % 8:
        raise InputError(f"{width_option}: a ResNet's width must be a multiple of 8 (>= 8), got {width}")
    net = RESNETS[num_layers](weights=None)
    if width != STANDARD_WIDTH:
        _narrow(net, width)
    return net


def _narrow(net: models.ResNet, width: int) -> None:
    """Rebuild ``net``'s stem and four stages with ``width`` channels in the first stage (same
    blocks and strides as torchvision; weights initialised as torchvision initialises them)."""
    block = type(net.layer1[0])
    counts = [len(getattr(net, f"layer{i}")) for i in range(1, 5)]
    net.inplanes = width
    net.conv1 = nn.Conv2d(3, width, kernel_size=7, stride=2, padding=3, bias=False)
    net.bn1 = nn.BatchNorm2d(width)
    for i, n in enumerate(counts):
        setattr(net, f"layer{i + 1}", net._make_layer(block, width * 2**i, n, stride=1 if i == 0 else 2))
    net.fc = nn.Linear(8 * width * block.expansion, net.fc.out_features)
    for m in net.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)


def load_resnet_weights(resnet: models.ResNet, path: str | Path, frames: int = 1,
                        option: str = "pretrained_path") -> None:
    """Load a torchvision ResNet state dict (or a DepthNet checkpoint's depth encoder) into ``resnet``.

    Called before any DCN swap; a DepthNet encoder with DCN does not fit a plain ResNet (an
    InputError lists the unexpected keys). The classifier (``fc.*``) is ignored; for ``frames``
    stacked frames the first conv's RGB filters are repeated (:func:`~c3f_models.encoders.weights.load_pretrained`).
    """
    blocks = sum(len(getattr(resnet, f"layer{i}")) for i in range(1, 5))
    load_pretrained(resnet, path, option, what=f"this ResNet ({blocks} residual blocks)", first_conv="conv1.weight",
                    frames=frames, ignored=("fc.",))


class ResnetEncoder(Encoder):
    """ResNet feature pyramid: the stem (stride 2) and ``layer1``-``layer4`` (strides 4-32).

    Channels: width, then width x 1, 2, 4, 8 x the block expansion (4 for ResNet50).

    Args:
        config: layers, width, DCN, input channels and pretrained weights.
        names: the config option behind each field of ``config``, for error messages.
    """

    config_class = ResnetConfig

    def __init__(self, config: ResnetConfig, names: Mapping[str, str] | None = None) -> None:
        super().__init__(config.in_channels)
        width = config.width
        net = build_resnet(config.layers, option_of(names, "layers"), width, option_of(names, "width"))
        if self.frames > 1:
            net.conv1 = nn.Conv2d(config.in_channels, width, kernel_size=7, stride=2, padding=3, bias=False)
            nn.init.kaiming_normal_(net.conv1.weight, mode="fan_out", nonlinearity="relu")
        if config.pretrained_path:
            load_resnet_weights(net, config.pretrained_path, self.frames, option_of(names, "pretrained_path"))
        if config.dcn:
            deformable_stages(net)
        self.conv1, self.bn1, self.relu, self.maxpool = net.conv1, net.bn1, net.relu, net.maxpool
        self.layer1, self.layer2, self.layer3, self.layer4 = net.layer1, net.layer2, net.layer3, net.layer4
        expansion = 4 if config.layers >= 50 else 1
        self.num_ch_enc = [width, *(width * 2**i * expansion for i in range(4))]

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3 x frames, H, W) RGB in [0, 1] -> list of 5 feature maps (fine to coarse)."""
        f0 = self.relu(self.bn1(self.conv1(self.normalise(x))))
        f1 = self.layer1(self.maxpool(f0))
        f2 = self.layer2(f1)
        f3 = self.layer3(f2)
        f4 = self.layer4(f3)
        return [f0, f1, f2, f3, f4]


__all__ = ["RESNETS", "ResnetConfig", "ResnetEncoder", "build_resnet", "load_resnet_weights"]
