"""The exported graphs: thin wrappers that fix each net's ONNX inputs and outputs.

Every graph takes NCHW float32 RGB in [0, 1] (ImageNet normalisation happens inside the
nets, so inside the graph) and returns what the runtime consumes directly:

============ ====================== ============================== ====================
graph        inputs                 output                         units
============ ====================== ============================== ====================
depth        image (B,3,H,W)        depth (B,1,H,W)                metres
pose         image_a, image_b       T_ba (B,4,4), a -> b           metres, rigid
descriptors  image (B,3,H,W)        descriptors (B,C,H,W)          unit L2 norm per pixel
============ ====================== ============================== ====================
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from c3f_models.contrafeat.network import ContraFeatNet
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


class DescriptorGraph(nn.Module):
    """Unit-norm dense descriptors at the input resolution."""

    def __init__(self, net: ContraFeatNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net(image)


@dataclass
class GraphSpec:
    """One graph to export: its module, ONNX names, file name and output description."""

    kind: str  # "depth" | "pose" | "descriptors" (c3f_slam.models.metadata.KINDS)
    module: nn.Module
    input_names: tuple[str, ...]
    output_name: str
    output_units: str
    output_meaning: str
    file_name: str
    opset: int
    output_channels: int | None = None  # C of (B, C, H, W) outputs; None for T_ba

    def example_inputs(self, frames: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Graph inputs built from (N, 3, H, W) frames: the frames, or consecutive pairs."""
        if len(self.input_names) == 1:
            return (frames,)
        if frames.shape[0] < 2:
            raise ValueError("a pose graph needs at least two frames")
        return frames[:-1], frames[1:]
