"""What a model exports: :class:`GraphSpec` (one ONNX graph) and the :class:`Exportable`
protocol a LightningModule follows so that :func:`export.export_model` can export it without
knowing its class (each model builds its own graph wrappers, e.g. ``c3f_models.depth.graphs``).

Every graph takes NCHW float32 RGB in [0, 1] (ImageNet normalisation happens inside the
nets, so inside the graph) and returns what the runtime consumes directly:

============== ====================== ============================== ==========================
graph          inputs                 output                         units
============== ====================== ============================== ==========================
depth          image (B,3,H,W)        depth (B,1,H,W)                metres
pose           image_a, image_b       T_ba (B,4,4), a -> b           metres, rigid
descriptors    image (B,3,H,W)        descriptors (B,C,H,W)          unit L2 norm per pixel
descriptors_kp image (B,3,H,W),       descriptors (B,N,C)            unit L2 norm per keypoint
               keypoints (B,N,2)
============== ====================== ============================== ==========================

``keypoints`` are float32 (u, v) in the input's pixels, pixel centres at integer coordinates
(N is a dynamic axis); the keypoint graph gives the dense map sampled there by the runtime's rule
(bilinear, clamped at the border, re-normalised: :func:`c3f_slam.matching.sample_descriptor_map`),
computing the descriptors of the four pixels around each keypoint only.
A graph is selected by its name (``--graphs``); both descriptor graphs are of kind ``descriptors``.
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
#: keypoints per frame in the parity check of a keypoint graph
PARITY_KEYPOINTS = 64


def parity_keypoints(batch: int, height: int, width: int, count: int = PARITY_KEYPOINTS,
                     seed: int = 0) -> torch.Tensor:
    """(batch, count, 2) float32 (u, v) pixel positions for checking a keypoint graph: the four
    corner pixels, points on each border, points outside the image (clamped by the sampler), a
    point at a half pixel, and the rest uniform sub-pixel positions inside."""
    w, h = float(width - 1), float(height - 1)
    fixed = torch.tensor([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h], [w / 2 + 0.5, 0.0], [0.0, h / 3],
                          [w, h / 2 + 0.25], [w / 3, h], [-3.0, h / 2], [w + 2.5, -1.5], [w / 2, h + 4.0],
                          [12.5, 7.5]])
    gen = torch.Generator().manual_seed(seed)
    rest = torch.rand((batch, max(count - len(fixed), 0), 2), generator=gen) * torch.tensor([w, h])
    return torch.cat([fixed.expand(batch, -1, -1), rest], dim=1)[:, :count].contiguous()


def has_deform_conv(module: nn.Module) -> bool:
    """True when the module contains torchvision's DeformConv2d (it needs opset 19)."""
    from torchvision.ops import DeformConv2d

    return any(isinstance(m, DeformConv2d) for m in module.modules())


@dataclass(kw_only=True)
class GraphSpec:
    """One graph to export: its module, ONNX names, file name and output description.

    ``name`` selects it (``--graphs``; default: its kind). ``sampling`` (descriptor graphs):
    ``dense`` (the map) or ``keypoints`` (its second input is ``keypoints`` (B, N, 2)).
    """

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
    name: str = ""  # what --graphs calls it; "" = the kind
    sampling: str | None = None  # descriptor graphs: "dense" | "keypoints"

    def __post_init__(self) -> None:
        self.name = self.name or self.kind

    @property
    def point_inputs(self) -> tuple[str, ...]:
        """The inputs that are (B, N, 2) keypoints rather than images."""
        return ("keypoints",) if self.sampling == "keypoints" else ()

    def example_inputs(self, frames: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Graph inputs built from (N, 3, H, W) frames: the frames, consecutive pairs, or the
        frames and :func:`parity_keypoints`."""
        if self.sampling == "keypoints":
            return frames, parity_keypoints(frames.shape[0], frames.shape[2], frames.shape[3])
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


__all__ = ["OPSET", "OPSET_DEFORM", "PARITY_KEYPOINTS", "Exportable", "GraphSpec", "has_deform_conv",
           "parity_keypoints"]
