"""Encoders made from a torchvision classifier's ``features`` (an ``nn.Sequential`` of blocks, as in
MobileNet and EfficientNet): the blocks cut at the 5 strides, the classifier left out.

Each map is the output of the last block before the next stride-2 block; the last block of
``features`` (a 1x1 expansion that feeds the classifier) is left out. The module keeps
torchvision's key names (``features.0.0.weight``, ...), so a local torchvision state dict of the
same architecture loads as it is (nothing is downloaded).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import torch
from torch import nn

from c3f_core.errors import InputError
from c3f_models.encoders.base import STRIDES, Encoder, option_of
from c3f_models.encoders.weights import load_pretrained


def _is_strided(block: nn.Module) -> bool:
    """Whether a block halves the resolution (one of its convolutions has stride 2)."""
    return any(isinstance(m, nn.Conv2d) and max(m.stride) > 1 for m in block.modules())


def _out_channels(block: nn.Module) -> int:
    """Channels a block puts out: those of its last convolution."""
    return [m for m in block.modules() if isinstance(m, nn.Conv2d)][-1].out_channels


def stage_ends(features: nn.Sequential) -> tuple[int, ...]:
    """The block count up to the end of each of the 5 stages: before each stride-2 block after the
    first, and before the final 1x1 expansion."""
    strided = [i for i, block in enumerate(features) if _is_strided(block)]
    if len(strided) != len(STRIDES) or strided[0] != 0:
        raise InputError(f"the features have stride-2 blocks {strided}; an encoder needs {len(STRIDES)}, "
                         "the first at block 0")
    return (*strided[1:], len(features) - 1)


class FeaturesEncoder(Encoder):
    """Base of the encoders cut from a torchvision ``features``: a subclass sets ``config_class``
    (fields ``in_channels``, ``pretrained_path`` and its own) and ``label``, and returns the
    untrained ``features`` from :meth:`make_features`. For stacked frames (PoseNet) the first
    convolution (``features[0][0]``) is rebuilt with 3 x frames input channels.

    Args:
        config: an instance of ``config_class``.
        names: the config option behind each field of ``config``, for error messages.
    """

    label: ClassVar[str] = "network"  #: what error messages call the network

    def __init__(self, config: Any, names: Mapping[str, str] | None = None) -> None:
        super().__init__(config.in_channels)
        features = self.make_features(config, names)
        if self.frames > 1:
            first = features[0][0]
            features[0][0] = nn.Conv2d(config.in_channels, first.out_channels, first.kernel_size, first.stride,
                                       first.padding, bias=False)
            nn.init.kaiming_normal_(features[0][0].weight, mode="fan_out")
        self.ends = stage_ends(features)
        self.features = features[:self.ends[-1]]
        self.num_ch_enc = [_out_channels(self.features[end - 1]) for end in self.ends]
        if config.pretrained_path:
            ignored = ("classifier.", *(f"features.{i}." for i in range(self.ends[-1], len(features))))
            load_pretrained(self, config.pretrained_path, option_of(names, "pretrained_path"),
                            what=f"this {self.label}",
                            first_conv="features.0.0.weight", frames=self.frames, ignored=ignored)

    def make_features(self, config: Any, names: Mapping[str, str] | None) -> nn.Sequential:
        """The untrained torchvision ``features`` for ``config`` (InputError for a value it cannot take)."""
        raise NotImplementedError

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3 x frames, H, W) RGB in [0, 1] -> list of 5 feature maps (fine to coarse)."""
        x, maps = self.normalise(x), []
        for i, block in enumerate(self.features):
            x = block(x)
            if i + 1 in self.ends:
                maps.append(x)
        return maps


__all__ = ["FeaturesEncoder", "stage_ends"]
