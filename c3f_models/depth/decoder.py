"""Monodepth2-style multi-scale disparity decoder and the disparity <-> depth mapping.

The decoder outputs a sigmoid "disparity" in (0, 1) at scales 0..3 (scale s has 1/2^s of
the input resolution). :func:`disp_to_depth` maps it linearly to inverse depth between
1/max_depth and 1/min_depth, so depth always lies in [min_depth, max_depth] (metres).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn


def disp_to_depth(disp: torch.Tensor, min_depth: float, max_depth: float) -> torch.Tensor:
    """Sigmoid output in [0, 1] to depth in [min_depth, max_depth] (0 -> max_depth, 1 -> min_depth)."""
    min_disp, max_disp = 1.0 / max_depth, 1.0 / min_depth
    return 1.0 / (min_disp + (max_disp - min_disp) * disp)


def depth_to_disp(depth: torch.Tensor, min_depth: float, max_depth: float) -> torch.Tensor:
    """Inverse of :func:`disp_to_depth` (depth in metres to the sigmoid value)."""
    min_disp, max_disp = 1.0 / max_depth, 1.0 / min_depth
    return (1.0 / depth - min_disp) / (max_disp - min_disp)


class ConvBlock(nn.Module):
    """3x3 conv with reflection padding (replicate on 1-pixel maps) followed by ELU."""

    def __init__(self, in_channels: int, out_channels: int, activation: bool = True) -> None:
        super().__init__()
        self.conv = nn.Conv2d(in_channels, out_channels, 3)
        self.act = nn.ELU(inplace=True) if activation else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mode = "reflect" if min(x.shape[-2:]) > 1 else "replicate"
        return self.act(self.conv(F.pad(x, (1, 1, 1, 1), mode=mode)))


class DepthDecoder(nn.Module):
    """U-Net decoder over the 5 encoder maps with disparity heads at ``scales``.

    Upsampling goes to the size of the next skip feature (and to ``out_size`` at the end),
    so inputs need not be multiples of 32.
    """

    def __init__(
        self,
        num_ch_enc: Sequence[int],
        scales: Sequence[int] = (0, 1, 2, 3),
        num_ch_dec: Sequence[int] = (16, 32, 64, 128, 256),
    ) -> None:
        super().__init__()
        self.scales = tuple(sorted(scales))
        if not self.scales or min(self.scales) < 0 or max(self.scales) > 3:
            raise ValueError(f"decoder scales must lie in 0..3, got {list(scales)}")
        up0, up1 = [], []
        for i in range(5):
            cin = num_ch_enc[4] if i == 4 else num_ch_dec[i + 1]
            up0.append(ConvBlock(cin, num_ch_dec[i]))
            skip = num_ch_enc[i - 1] if i > 0 else 0
            up1.append(ConvBlock(num_ch_dec[i] + skip, num_ch_dec[i]))
        self.upconv0 = nn.ModuleList(up0)
        self.upconv1 = nn.ModuleList(up1)
        self.dispconv = nn.ModuleList(ConvBlock(num_ch_dec[s], 1, activation=False) for s in self.scales)

    def forward(self, features: list[torch.Tensor], out_size: tuple[int, int]) -> list[torch.Tensor]:
        """Disparities in (0, 1), one (B, 1, H/2^s, W/2^s) map per scale, finest first."""
        x = features[4]
        out: dict[int, torch.Tensor] = {}
        for i in range(4, -1, -1):
            x = self.upconv0[i](x)
            size = tuple(features[i - 1].shape[-2:]) if i > 0 else tuple(out_size)
            x = F.interpolate(x, size=size, mode="nearest")
            if i > 0:
                x = torch.cat([x, features[i - 1]], dim=1)
            x = self.upconv1[i](x)
            if i in self.scales:
                out[i] = torch.sigmoid(self.dispconv[self.scales.index(i)](x))
        return [out[s] for s in self.scales]
