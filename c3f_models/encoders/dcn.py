"""Deformable 3x3 convolutions for the ResNet encoder (docs/design.md, DepthNet: stages conv3-conv5).

A :class:`DeformConv` is a drop-in for a ``nn.Conv2d``: a plain conv with a zero-initialised
weight predicts the sampling offsets (2 per kernel tap, in pixels), and
``torchvision.ops.DeformConv2d`` convolves at the shifted positions. With zero offsets it is
exactly the conv it replaces, so pretrained weights stay meaningful after the swap.
"""

from __future__ import annotations

import torch
from torch import nn
from torchvision.ops import DeformConv2d


class DeformConv(nn.Module):
    """Deformable convolution with its own offset branch (DCNv1, one offset group)."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int = 3,
        stride: int = 1,
        padding: int = 1,
        dilation: int = 1,
        groups: int = 1,
        bias: bool = False,
    ) -> None:
        super().__init__()
        k = kernel_size
        self.offset = nn.Conv2d(in_channels, 2 * k * k, k, stride=stride, padding=padding, dilation=dilation)
        nn.init.zeros_(self.offset.weight)
        nn.init.zeros_(self.offset.bias)
        self.conv = DeformConv2d(
            in_channels, out_channels, k, stride=stride, padding=padding, dilation=dilation, groups=groups, bias=bias
        )

    @classmethod
    def from_conv(cls, conv: nn.Conv2d) -> DeformConv:
        """A deformable conv with the weights (and bias) of ``conv`` and zero offsets."""
        k = conv.kernel_size[0]
        out = cls(
            conv.in_channels,
            conv.out_channels,
            k,
            stride=conv.stride[0],
            padding=conv.padding[0],
            dilation=conv.dilation[0],
            groups=conv.groups,
            bias=conv.bias is not None,
        )
        with torch.no_grad():
            out.conv.weight.copy_(conv.weight)
            if conv.bias is not None:
                out.conv.bias.copy_(conv.bias)
        return out.to(conv.weight.device, conv.weight.dtype)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        offset = self.offset(x)
        if torch.is_autocast_enabled(x.device.type):
            # torchvision's CPU kernel has no half/bfloat16 version: run it in float32
            with torch.autocast(x.device.type, enabled=False):
                return self.conv(x.float(), offset.float())
        return self.conv(x, offset)


def _is_square3x3(m: nn.Module) -> bool:
    return isinstance(m, nn.Conv2d) and tuple(m.kernel_size) == (3, 3)


def deformable_stages(resnet: nn.Module, stages: tuple[str, ...] = ("layer2", "layer3", "layer4")) -> int:
    """Replace every 3x3 conv in the given residual stages by a :class:`DeformConv`, in place.

    torchvision's ``layer2``-``layer4`` are the paper's conv3-conv5. For Bottleneck blocks
    (ResNet50) that is ``conv2``; for BasicBlocks (ResNet18/34) ``conv1`` and ``conv2``.
    Returns the number of convolutions replaced.
    """
    n = 0
    for stage in stages:
        for block in getattr(resnet, stage):
            for name, child in list(block.named_children()):
                if _is_square3x3(child):
                    setattr(block, name, DeformConv.from_conv(child))
                    n += 1
    return n
