"""ContraFeat descriptor network: FPN over an encoder's bottom-up stream, full-resolution output.

Input: (B, 3, H, W) RGB in [0, 1] (ImageNet normalisation is applied inside). Output:
(B, C, H, W) descriptors (C = 128 by default), unit L2 norm per pixel. The finest FPN level
(stride 2) is upsampled bilinearly to the input size and fused with a shallow full-resolution
convolutional stem by two 1x1 convolutions, so that descriptors keep pixel accuracy.

The bottom-up stream is any :class:`c3f_models.encoders.Encoder` (``backbone``; ResNet18 in the
paper). Its state-dict keys sit at the network's top level (``conv1.*``, ``layer1.*`` of the
ResNet, as before encoders could be chosen), so trained weights load unchanged.

Descriptors are read at keypoints with :func:`sample_descriptors` (bilinear, pixel centres at
integer coordinates: ``grid_sample(..., align_corners=True)``).

Pretrained ImageNet weights are never downloaded: ``pretrained_path`` is a local file holding
the backbone's torchvision ``state_dict`` (``torch.save(resnet18(weights=...).state_dict(), path)``),
or a DepthNet checkpoint whose depth encoder is the same network (for the ResNet: without DCN).
"""

from __future__ import annotations

from collections import OrderedDict

import torch
import torch.nn.functional as F
from torch import nn
from torchvision.ops import FeaturePyramidNetwork

from c3f_core.errors import InputError
from c3f_models.contrafeat.config import ContraFeatNetworkConfig

ENCODER = "encoder"  # the encoder's attribute, left out of the state-dict keys


def head_channels(config: ContraFeatNetworkConfig) -> int:
    """The hidden channels of the 1x1 head (``head_channels``, null: ``descriptor_dim``); InputError
    for a channel count the network cannot take."""
    head = config.head_channels or config.descriptor_dim
    if min(config.descriptor_dim, config.fpn_channels, config.stem_channels, head) < 1:
        raise InputError("model.network.descriptor_dim, fpn_channels, stem_channels and head_channels must be "
                         "positive")
    return head


class ContraFeatNet(nn.Module):
    """Dense descriptor network (FPN on an encoder, full resolution, unit-norm descriptors).

    Args:
        config: the encoder (``backbone`` and its settings: for the ResNet ``backbone_layers``,
            ``backbone_width``), the channels of the descriptors (c), the FPN levels, the
            full-resolution stem and 1x1 head (null: ``descriptor_dim``), and ``pretrained_path``:
            a local torchvision state dict of the backbone, a DepthNet checkpoint (its depth
            encoder, the same network, no DCN), or None (from scratch).
    """

    def __init__(self, config: ContraFeatNetworkConfig) -> None:
        super().__init__()
        head, stem = head_channels(config), config.stem_channels
        self.encoder = config.backbone_encoder().build()
        self.fpn = FeaturePyramidNetwork(list(self.encoder.num_ch_enc), config.fpn_channels)
        self.stem = nn.Sequential(
            nn.Conv2d(3, stem, 3, padding=1), nn.ReLU(inplace=True),
            nn.Conv2d(stem, stem, 3, padding=1), nn.ReLU(inplace=True),
        )
        self.head = nn.Sequential(
            nn.Conv2d(config.fpn_channels + stem, head, 1), nn.ReLU(inplace=True),
            nn.Conv2d(head, config.descriptor_dim, 1),
        )
        self.descriptor_dim = config.descriptor_dim
        clash = {k.split(".")[0] for k in self.encoder.state_dict()} & set(self._modules)
        if clash:
            raise InputError(f"model.network.backbone: the encoder's {sorted(clash)} would share state-dict keys "
                             "with the descriptor network's own layers; rename them in the encoder")
        self.register_state_dict_post_hook(_flatten_encoder_keys)
        self.register_load_state_dict_pre_hook(_nest_encoder_keys)

    def features(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, F + S, H, W) input of the 1x1 head: the finest FPN
        level upsampled to the input size, beside the full-resolution stem."""
        if image.ndim != 4 or image.shape[1] != 3:
            raise InputError(f"ContraFeatNet expects (B, 3, H, W) images, got {tuple(image.shape)}")
        h, w = image.shape[-2:]
        pyramid = self.fpn(OrderedDict((f"p{i}", f) for i, f in enumerate(self.encoder(image))))
        fine = F.interpolate(pyramid["p0"], size=(h, w), mode="bilinear", align_corners=False)
        return torch.cat([fine, self.stem(self.encoder.normalise(image))], dim=1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, C, H, W) unit-norm descriptors: the head, pixel by
        pixel, on :meth:`features`."""
        return F.normalize(self.head(self.features(image)), dim=1)


def _flatten_encoder_keys(module: ContraFeatNet, state: dict, prefix: str, local_metadata) -> None:
    """State-dict hook: ``{prefix}encoder.K`` -> ``{prefix}K`` (the layout of trained weights),
    this network's keys kept in their order (they are the last ones written)."""
    nested = f"{prefix}{ENCODER}."
    for key in [k for k in state if k.startswith(prefix)]:
        state[prefix + key[len(nested):] if key.startswith(nested) else key] = state.pop(key)


def _nest_encoder_keys(module: ContraFeatNet, state: dict, prefix: str, *args) -> None:
    """Load hook, the inverse of :func:`_flatten_encoder_keys`: a key of this network whose first
    part is none of its own layers belongs to the encoder."""
    own = set(module._modules)
    for key in [k for k in state if k.startswith(prefix) and k[len(prefix):].split(".")[0] not in own]:
        state[f"{prefix}{ENCODER}.{key[len(prefix):]}"] = state.pop(key)


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
