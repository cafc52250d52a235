"""DepthNet's networks: the depth network (encoder + decoder) and the two-frame PoseNet."""

from __future__ import annotations

import torch
from torch import nn

from c3f_models.depth.config import DepthNetworkConfig
from c3f_models.depth.decoder import DepthDecoder, disp_to_depth
from c3f_models.geometry import pose_from_axis_angle


class DepthNetwork(nn.Module):
    """Single-frame depth: an encoder (default a ResNet, optionally deformable) + multi-scale disparity decoder.

    Args:
        config: the encoder (``encoder`` and its settings: for the ResNet ``encoder_layers``,
            ``dcn`` in conv3-conv5, ``encoder_width``; ``pretrained_path``), the disparity heads at
            scales 0..``num_scales``-1 and the depth range ``min_depth``..``max_depth`` (metres)
            that the sigmoid maps onto.
    """

    def __init__(self, config: DepthNetworkConfig) -> None:
        super().__init__()
        self.encoder = config.depth_encoder().build()
        self.decoder = DepthDecoder(self.encoder.num_ch_enc, scales=range(config.num_scales))
        self.min_depth, self.max_depth = float(config.min_depth), float(config.max_depth)

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, H, W) RGB in [0, 1] -> disparities (sigmoid) per scale, finest first."""
        return self.decoder(self.encoder(image), tuple(image.shape[-2:]))

    def to_depth(self, disp: torch.Tensor) -> torch.Tensor:
        """Sigmoid disparity to depth (metres) in [min_depth, max_depth]."""
        return disp_to_depth(disp, self.min_depth, self.max_depth)


class PoseDecoder(nn.Module):
    """Monodepth2 pose head: 1x1 squeeze, two 3x3 convs, 1x1 to 6 numbers, spatial mean.

    The raw outputs are multiplied by ``rotation_scale`` (radians) and ``translation_scale``
    (metres); Monodepth2 uses 0.01 for both.
    """

    def __init__(self, num_ch_enc: int, translation_scale: float, rotation_scale: float = 0.01) -> None:
        super().__init__()
        self.squeeze = nn.Conv2d(num_ch_enc, 256, 1)
        self.convs = nn.Sequential(
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 256, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 256, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 6, 1),
        )
        self.rotation_scale, self.translation_scale = rotation_scale, translation_scale

    def forward(self, feature: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Coarsest feature map -> axis-angle (B, 3) radians and translation (B, 3) metres."""
        out = self.convs(self.squeeze(feature)).mean(dim=(2, 3))
        return self.rotation_scale * out[:, :3], self.translation_scale * out[:, 3:]


class PoseNetwork(nn.Module):
    """Two-frame PoseNet: ``forward(a, b)`` returns ``T_ba`` (frame-a coordinates into frame b).

    Call it with the frames in temporal order (earlier first), as Monodepth2 does.

    Args:
        config: the encoder (``pose_encoder`` and its settings: for the ResNet
            ``pose_encoder_layers``, ``pose_encoder_width``; ``pose_pretrained_path``: a local state
            dict whose first conv is repeated for the 6-channel input and halved) and
            ``pose_translation_scale``, metres per unit of the raw translation output.
    """

    def __init__(self, config: DepthNetworkConfig) -> None:
        super().__init__()
        self.encoder = config.posenet_encoder().build()
        self.decoder = PoseDecoder(self.encoder.num_ch_enc[-1], config.pose_translation_scale)

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) frames a and b -> (B, 4, 4) rigid transform T_ba."""
        axis_angle, translation = self.decoder(self.encoder(torch.cat([a, b], dim=1))[-1])
        with torch.autocast(a.device.type, enabled=False):  # rotations in float32 under mixed precision
            return pose_from_axis_angle(axis_angle.float(), translation.float())
