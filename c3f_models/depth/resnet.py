"""ResNet encoders for DepthNet and PoseNet (torchvision architectures, built with ``weights=None``).

Nothing is downloaded: ImageNet weights come only from a local file holding a torchvision
ResNet ``state_dict`` (``torch.save(torchvision.models.resnet18(weights=...).state_dict(), path)``).
A DepthNet checkpoint (``.ckpt`` of :class:`c3f_models.depthnet.DepthNet`) is accepted too: its
depth encoder (keys ``depth_net.encoder.*``) is the ResNet that gets loaded, e.g. to start
ContraFeat from an encoder trained self-supervised on colon video.
Inputs are RGB in [0, 1]; the encoder applies the ImageNet normalisation itself.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn
from torchvision import models

from c3f_models.depth.dcn import deformable_stages
from c3f_slam.errors import InputError
from c3f_slam.preprocess import IMAGENET_MEAN, IMAGENET_STD

RESNETS = {18: models.resnet18, 34: models.resnet34, 50: models.resnet50}
STANDARD_WIDTH = 64  #: channels of a torchvision ResNet's stem and first stage


def build_resnet(num_layers: int, option: str = "encoder_layers", width: int = STANDARD_WIDTH,
                 width_option: str = "encoder_width") -> models.ResNet:
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


def read_state_dict(path: str | Path, option: str) -> dict[str, torch.Tensor]:
    """Read a state dict (plain, or under a ``state_dict`` key) from a local file; InputError if unusable."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{option}: file not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle, zip or format errors all mean "not a weights file"
        raise InputError(f"{option}: {path} is not a torch weights file ({type(exc).__name__})") from None
    if isinstance(state, dict) and isinstance(state.get("state_dict"), dict):
        state = state["state_dict"]
    if not isinstance(state, dict) or not state or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{option}: {path} does not hold a state dict (name -> tensor)")
    return dict(state)


DEPTH_ENCODER_PREFIX = "depth_net.encoder."  # DepthNet's depth encoder inside its LightningModule state


def encoder_weights(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The ResNet part of a state dict: a torchvision state dict as is, or a DepthNet checkpoint's depth encoder."""
    if "conv1.weight" not in state and DEPTH_ENCODER_PREFIX + "conv1.weight" in state:
        n = len(DEPTH_ENCODER_PREFIX)
        return {k[n:]: v for k, v in state.items() if k.startswith(DEPTH_ENCODER_PREFIX)}
    return state


def load_pretrained(resnet: models.ResNet, path: str | Path, num_input_images: int = 1,
                    option: str = "pretrained_path") -> None:
    """Load a torchvision ResNet state dict (or a DepthNet checkpoint's depth encoder) into ``resnet``.

    Called before any DCN swap; a DepthNet encoder with DCN does not fit a plain ResNet (an
    InputError lists the unexpected keys).

    For a multi-frame input (PoseNet) the first conv's RGB filters are repeated for every
    frame and divided by the number of frames (Monodepth2). The classifier (``fc.*``) is
    ignored. Missing, unexpected or mis-shaped keys raise an InputError naming the file.
    """
    state = encoder_weights(read_state_dict(path, option))
    state = {k: v for k, v in state.items() if not k.startswith("fc.")}
    if num_input_images > 1 and "conv1.weight" in state and state["conv1.weight"].shape[1] == 3:
        w = state["conv1.weight"]
        state["conv1.weight"] = torch.cat([w] * num_input_images, dim=1) / num_input_images
    target = {k: v for k, v in resnet.state_dict().items() if not k.startswith("fc.")}
    missing = [k for k in target if k not in state]
    unexpected = [k for k in state if k not in target]
    wrong = [k for k in target if k in state and state[k].shape != target[k].shape]
    if missing or unexpected or wrong:
        problems = []
        for label, keys in (("missing", missing), ("unexpected", unexpected), ("wrong-shaped", wrong)):
            if keys:
                problems.append(f"{len(keys)} {label} keys (e.g. {keys[0]})")
        layers = sum(len(getattr(resnet, f"layer{i}")) for i in range(1, 5))
        raise InputError(
            f"{option}: {path} does not fit this ResNet ({layers} residual blocks): " + ", ".join(problems)
        )
    resnet.load_state_dict(state, strict=False)


class ResnetEncoder(nn.Module):
    """ResNet feature pyramid: 5 maps at strides 2, 4, 8, 16, 32.

    Args:
        num_layers: 18, 34 or 50.
        dcn: deformable 3x3 convs in stages conv3-conv5 (``layer2``-``layer4``).
        num_input_images: frames stacked along channels (2 for PoseNet).
        pretrained_path: local torchvision ResNet state dict (ImageNet), or None (from scratch).
        option: the config option named in error messages.
        width: channels of the first stage (64: torchvision's ResNet; see :func:`build_resnet`).
    """

    def __init__(
        self,
        num_layers: int = 18,
        dcn: bool = False,
        num_input_images: int = 1,
        pretrained_path: str | Path | None = None,
        option: str = "pretrained_path",
        width: int = STANDARD_WIDTH,
    ) -> None:
        super().__init__()
        net = build_resnet(num_layers, width=width)
        if num_input_images > 1:
            net.conv1 = nn.Conv2d(3 * num_input_images, width, kernel_size=7, stride=2, padding=3, bias=False)
            nn.init.kaiming_normal_(net.conv1.weight, mode="fan_out", nonlinearity="relu")
        if pretrained_path:
            load_pretrained(net, pretrained_path, num_input_images, option)
        if dcn:
            deformable_stages(net)
        self.conv1, self.bn1, self.relu, self.maxpool = net.conv1, net.bn1, net.relu, net.maxpool
        self.layer1, self.layer2, self.layer3, self.layer4 = net.layer1, net.layer2, net.layer3, net.layer4
        expansion = 4 if num_layers >= 50 else 1
        self.num_ch_enc = [width, *(width * 2**i * expansion for i in range(4))]
        mean = torch.tensor(IMAGENET_MEAN * num_input_images).view(1, -1, 1, 1)
        std = torch.tensor(IMAGENET_STD * num_input_images).view(1, -1, 1, 1)
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3*n, H, W) RGB in [0, 1] -> list of 5 feature maps (fine to coarse)."""
        x = (x - self.mean) / self.std
        f0 = self.relu(self.bn1(self.conv1(x)))
        f1 = self.layer1(self.maxpool(f0))
        f2 = self.layer2(f1)
        f3 = self.layer3(f2)
        f4 = self.layer4(f3)
        return [f0, f1, f2, f3, f4]
