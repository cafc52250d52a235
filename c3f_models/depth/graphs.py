"""DepthNet's exported graphs: thin wrappers that fix the ONNX inputs and outputs (see
:mod:`export.graphs` for the conventions every graph follows)."""

from __future__ import annotations

import torch
from torch import nn

from c3f_models.depth.networks import DepthNetwork, PoseNetwork


class DepthGraph(nn.Module):
    """Depth in metres at the finest decoder scale (sigmoid disparity -> depth inside)."""

    def __init__(self, net: DepthNetwork) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net.to_depth(self.net(image)[0])


class PoseGraph(nn.Module):
    """``T_ba`` (B, 4, 4): camera-a coordinates into camera b; frames in temporal order."""

    def __init__(self, net: PoseNetwork) -> None:
        super().__init__()
        self.net = net

    def forward(self, image_a: torch.Tensor, image_b: torch.Tensor) -> torch.Tensor:
        return self.net(image_a, image_b)


__all__ = ["DepthGraph", "PoseGraph"]
