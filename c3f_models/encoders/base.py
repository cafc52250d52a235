"""The interface every encoder follows (docs/add_network.md): an ``nn.Module`` that maps
(B, C_in, H, W) RGB in [0, 1] to 5 feature maps at strides 2, 4, 8, 16 and 32, and says their
channels in ``num_ch_enc``. The depth decoder, the pose head and the descriptor FPN read nothing else.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import torch
from torch import nn

from c3f_core.errors import InputError
from c3f_slam.frames.preprocess import IMAGENET_MEAN, IMAGENET_STD

#: the strides (input pixels per feature pixel) of the 5 maps, finest first
STRIDES = (2, 4, 8, 16, 32)


def option_of(names: Mapping[str, str] | None, field: str) -> str:
    """The config option that sets an encoder settings ``field`` (for error messages): its entry
    in ``names``, else the field's own name."""
    return (names or {}).get(field, field)


class Encoder(nn.Module):
    """Base of the encoders: ImageNet normalisation of stacked RGB frames, and the contract.

    A subclass sets ``config_class`` (its frozen settings dataclass, which has the fields
    ``in_channels``, 3 x stacked frames, and ``pretrained_path``, a local weights file or None),
    takes ``(config, names)`` (``names``: the config option behind each field, for error
    messages; see :func:`option_of`), sets ``num_ch_enc`` (channels of the 5 maps) and returns
    the maps from ``forward``, finest first. Inputs are RGB in [0, 1]; :meth:`normalise` applies
    the ImageNet mean and standard deviation (in the module, so in its ONNX graph too).

    Args:
        in_channels: 3 x the frames stacked along channels (6 for PoseNet).
    """

    config_class: ClassVar[type]
    num_ch_enc: list[int]

    def __init__(self, in_channels: int) -> None:
        super().__init__()
        if in_channels < 3 or in_channels % 3:
            raise InputError(f"an encoder takes 3 x frames input channels, got {in_channels}")
        frames = in_channels // 3
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN * frames).view(1, -1, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD * frames).view(1, -1, 1, 1), persistent=False)

    @property
    def frames(self) -> int:
        """RGB frames stacked along the input channels."""
        return self.mean.shape[1] // 3

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C_in, H, W) RGB in [0, 1] -> ImageNet-normalised input of the first layer."""
        return (x - self.mean) / self.std

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, C_in, H, W) RGB in [0, 1] -> 5 feature maps at :data:`STRIDES` (fine to coarse);
        a map has ceil(H / stride) x ceil(W / stride) pixels."""
        raise NotImplementedError


__all__ = ["STRIDES", "Encoder", "option_of"]
