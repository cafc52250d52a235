"""MobileNetV3-Small (torchvision, built with ``weights=None``) as an encoder: a light second
choice beside the ResNet (0.87 M weights at ``width_mult`` 1 against ResNet18's 11.2 M).

Its ``features`` cut at the strides (:class:`~c3f_models.encoders.features.FeaturesEncoder`):
channels 16, 16, 24, 48, 96 at ``width_mult`` 1 (the final 96 -> 576 expansion of the classifier
left out). A local torchvision ``mobilenet_v3_small`` state dict (same ``width_mult``) loads as it is.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from torch import nn
from torchvision import models

from c3f_core.errors import InputError
from c3f_models.encoders.base import option_of
from c3f_models.encoders.features import FeaturesEncoder


@dataclass(frozen=True)
class MobileNetConfig:
    """MobileNetV3-Small as an encoder (checked when it is built).

    Attributes:
        width_mult: multiplier of every layer's channels (1.0: torchvision's network; channels
            are rounded to multiples of 8, so 0.5 gives 8, 8, 16, 24, 48).
        in_channels: 3 x the frames stacked along channels (6 for PoseNet).
        pretrained_path: local torchvision ``mobilenet_v3_small`` state dict, or a DepthNet
            checkpoint whose depth encoder is this MobileNet; None = from scratch.
    """

    width_mult: float = 1.0
    in_channels: int = 3
    pretrained_path: str | None = None


class MobileNetEncoder(FeaturesEncoder):
    """MobileNetV3-Small features as a 5-map pyramid (strides 2-32)."""

    config_class = MobileNetConfig
    label = "MobileNetV3-Small"

    def make_features(self, config: MobileNetConfig, names: Mapping[str, str] | None) -> nn.Sequential:
        if not config.width_mult > 0:
            raise InputError(f"{option_of(names, 'width_mult')} must be positive, got {config.width_mult}")
        return models.mobilenet_v3_small(weights=None, width_mult=config.width_mult).features


__all__ = ["MobileNetConfig", "MobileNetEncoder"]
