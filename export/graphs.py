"""What a model exports: :class:`GraphSpec` (one ONNX graph) and the :class:`Exportable`
protocol a LightningModule follows so that :func:`export.export_model` can export it without
knowing its class (each model builds its own graph wrappers, e.g. ``c3f_models.depth.graphs``).

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
from pathlib import Path
from typing import Protocol, runtime_checkable

import torch
from torch import nn

#: the ONNX opset of every graph, and of graphs with deformable convolutions
OPSET = 18
OPSET_DEFORM = 19


def has_deform_conv(module: nn.Module) -> bool:
    """True when the module contains torchvision's DeformConv2d (it needs opset 19)."""
    from torchvision.ops import DeformConv2d

    return any(isinstance(m, DeformConv2d) for m in module.modules())


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
    depth_range: tuple[float, float] | None = None  # (min, max) metres of a depth graph's output

    def example_inputs(self, frames: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Graph inputs built from (N, 3, H, W) frames: the frames, or consecutive pairs."""
        if len(self.input_names) == 1:
            return (frames,)
        if frames.shape[0] < 2:
            raise ValueError("a pose graph needs at least two frames")
        return frames[:-1], frames[1:]


@runtime_checkable
class Exportable(Protocol):
    """A model :func:`export.export_model` can export: it says which graphs it has and loads a
    checkpoint of its own kind (refusing another kind in one line that names ``option``)."""

    hparams: dict

    def export_graphs(self) -> list[GraphSpec]:
        """The graphs this model exports, wrapping its current networks."""
        ...

    def load_export_checkpoint(self, path: Path, option: str = "--ckpt_path") -> None:
        """Load ``path``'s weights (safe unpickler only) and switch to evaluation mode."""
        ...


__all__ = ["OPSET", "OPSET_DEFORM", "Exportable", "GraphSpec", "has_deform_conv"]
