"""ContraFeat descriptor network: FPN over a ResNet bottom-up stream, full-resolution output.

Input: (B, 3, H, W) RGB in [0, 1] (ImageNet normalisation is applied inside). Output:
(B, C, H, W) descriptors (C = 128 by default), unit L2 norm per pixel. The finest FPN level
(stride 2) is upsampled bilinearly to the input size and fused with a shallow full-resolution
convolutional stem by two 1x1 convolutions, so that descriptors keep pixel accuracy.

Descriptors are read at keypoints with :func:`sample_descriptors` (bilinear, pixel centres at
integer coordinates: ``grid_sample(..., align_corners=True)``).

Pretrained ImageNet weights are never downloaded: ``pretrained_path`` is a local file holding
a torchvision ResNet ``state_dict`` (``torch.save(resnet18(weights=...).state_dict(), path)``),
or a DepthNet checkpoint whose depth encoder is the same ResNet without DCN.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
import torch.nn.functional as F
from torch import nn
from torchvision.ops import FeaturePyramidNetwork

from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_models.depth.resnet import IMAGENET_MEAN, IMAGENET_STD, build_resnet, load_pretrained
from c3f_slam.errors import InputError

BACKBONES = (18, 34)  # basic-block ResNets: the FPN takes their layer1..layer4 widths


def head_channels(config: ContraFeatNetworkConfig) -> int:
    """The hidden channels of the 1x1 head (``head_channels``, null: ``descriptor_dim``); InputError
    for a backbone depth or a channel count the network cannot take."""
    if config.backbone_layers not in BACKBONES:
        raise InputError(f"model.network.backbone_layers must be one of {list(BACKBONES)}, got "
                         f"{config.backbone_layers}")
    head = config.head_channels or config.descriptor_dim
    if min(config.descriptor_dim, config.fpn_channels, config.stem_channels, head) < 1:
        raise InputError("model.network.descriptor_dim, fpn_channels, stem_channels and head_channels must be "
                         "positive")
    return head


class ContraFeatNet(nn.Module):
    """Dense descriptor network (FPN on ResNet, full resolution, unit-norm descriptors).

    Args:
        config: the ResNet (``backbone_layers`` 18 or 34, ``backbone_width``), the channels of the
            descriptors (c), the FPN levels, the full-resolution stem and 1x1 head (null:
            ``descriptor_dim``), and ``pretrained_path``: a local torchvision ResNet state dict, a
            DepthNet checkpoint (its depth encoder, same depth, no DCN), or None (from scratch).
    """

    def __init__(self, config: ContraFeatNetworkConfig) -> None:
        super().__init__()
        head, stem, w = head_channels(config), config.stem_channels, config.backbone_width
        net = build_resnet(config.backbone_layers, "model.network.backbone_layers", w, "model.network.backbone_width")
        if config.pretrained_path:
            load_pretrained(net, config.pretrained_path, option="model.network.pretrained_path")
        self.conv1, self.bn1, self.relu, self.maxpool = net.conv1, net.bn1, net.relu, net.maxpool
        self.layer1, self.layer2, self.layer3, self.layer4 = net.layer1, net.layer2, net.layer3, net.layer4
        self.fpn = FeaturePyramidNetwork([w, w, 2 * w, 4 * w, 8 * w], config.fpn_channels)
        self.stem = nn.Sequential(
            nn.Conv2d(3, stem, 3, padding=1), nn.ReLU(inplace=True),
            nn.Conv2d(stem, stem, 3, padding=1), nn.ReLU(inplace=True),
        )
        self.head = nn.Sequential(
            nn.Conv2d(config.fpn_channels + stem, head, 1), nn.ReLU(inplace=True),
            nn.Conv2d(head, config.descriptor_dim, 1),
        )
        self.descriptor_dim = config.descriptor_dim
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def features(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, F + S, H, W) input of the 1x1 head: the finest FPN
        level upsampled to the input size, beside the full-resolution stem."""
        if image.ndim != 4 or image.shape[1] != 3:
            raise InputError(f"ContraFeatNet expects (B, 3, H, W) images, got {tuple(image.shape)}")
        h, w = image.shape[-2:]
        x = (image - self.mean) / self.std
        f0 = self.relu(self.bn1(self.conv1(x)))
        f1 = self.layer1(self.maxpool(f0))
        f2 = self.layer2(f1)
        f3 = self.layer3(f2)
        f4 = self.layer4(f3)
        pyramid = self.fpn(OrderedDict([("p0", f0), ("p1", f1), ("p2", f2), ("p3", f3), ("p4", f4)]))
        fine = F.interpolate(pyramid["p0"], size=(h, w), mode="bilinear", align_corners=False)
        return torch.cat([fine, self.stem(x)], dim=1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, C, H, W) unit-norm descriptors: the head, pixel by
        pixel, on :meth:`features`."""
        return F.normalize(self.head(self.features(image)), dim=1)


def sample_descriptors(descriptors: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """(N, C) unit descriptors at (N, 2) pixel coordinates (u, v) of a (C, H, W) map.

    Bilinear with pixel centres at integer coordinates (``align_corners=True``), then
    re-normalised (an interpolated unit vector is not unit).
    """
    c, h, w = descriptors.shape
    if xy.numel() == 0:
        return descriptors.new_zeros((0, c))
    grid = torch.empty((1, 1, xy.shape[0], 2), dtype=descriptors.dtype, device=descriptors.device)
    grid[0, 0, :, 0] = 2.0 * xy[:, 0].to(descriptors.dtype) / max(w - 1, 1) - 1.0
    grid[0, 0, :, 1] = 2.0 * xy[:, 1].to(descriptors.dtype) / max(h - 1, 1) - 1.0
    out = F.grid_sample(descriptors[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
    return F.normalize(out[0, :, 0].transpose(0, 1), dim=1)
