"""ContraFeat's exported graphs (see :mod:`export.graphs` for the conventions): the dense map,
and the descriptors at given keypoints only."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from c3f_models.contrafeat.network import ContraFeatNet


class DescriptorGraph(nn.Module):
    """Unit-norm dense descriptors at the input resolution."""

    def __init__(self, net: ContraFeatNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net(image)


def _corners(keypoints: torch.Tensor, h, w) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 4, N) int64 flat indices of the four pixels around each (u, v) keypoint (clamped into
    the H x W grid, as :func:`c3f_slam.matching.sample_descriptor_map` picks them) and their
    (B, 4, N) bilinear weights; order (x0, y0), (x1, y0), (x0, y1), (x1, y1)."""
    u, v = keypoints[..., 0], keypoints[..., 1]
    one = torch.ones_like(u)
    u = torch.minimum(torch.clamp(u, min=0.0), one * (w - 1))
    v = torch.minimum(torch.clamp(v, min=0.0), one * (h - 1))
    x0 = torch.minimum(torch.floor(u), torch.clamp(one * (w - 2), min=0.0))
    y0 = torch.minimum(torch.floor(v), torch.clamp(one * (h - 2), min=0.0))
    x1, y1 = torch.minimum(x0 + 1, one * (w - 1)), torch.minimum(y0 + 1, one * (h - 1))
    ax, ay = u - x0, v - y0
    xs, ys = (x0.long(), x1.long()), (y0.long() * w, y1.long() * w)
    index = torch.stack([ys[0] + xs[0], ys[0] + xs[1], ys[1] + xs[0], ys[1] + xs[1]], dim=1)
    weights = torch.stack([(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay], dim=1)
    return index, weights


def sample_keypoints(maps: torch.Tensor, keypoints: torch.Tensor, per_pixel: nn.Module | None = None) -> torch.Tensor:
    """(B, N, C) unit descriptors at (B, N, 2) keypoints (u, v), pixels, of (B, C', H, W) ``maps``.

    The rule of the training sampler (:func:`c3f_models.contrafeat.network.sample_descriptors`,
    ``grid_sample(align_corners=True, padding_mode="border")``) and of the runtime's
    :func:`c3f_slam.matching.sample_descriptor_map`, batched: bilinear between the four pixels
    around each keypoint (pixel centres at integer coordinates, positions clamped into the map),
    each pixel's descriptor unit length, the result normalised again. ``per_pixel`` (a module on
    (B, C', M, 1), e.g. ContraFeat's 1x1 head) turns the gathered pixels of ``maps`` into
    descriptors first, so that it runs at 4 N pixels instead of H x W; None: ``maps`` are the
    descriptors.
    """
    b, c, h, w = maps.shape
    index, weights = _corners(keypoints, h, w)
    flat = index.flatten(1)  # (B, 4N)
    pixels = torch.gather(maps.flatten(2), 2, flat[:, None, :].expand(-1, c, -1))[..., None]  # (B, C', 4N, 1)
    if per_pixel is not None:
        pixels = per_pixel(pixels)
    desc = F.normalize(pixels[..., 0], dim=1)  # (B, C, 4N)
    desc = desc.reshape(b, desc.shape[1], 4, -1)
    return F.normalize((desc * weights[:, None]).sum(dim=2).transpose(1, 2), dim=2)


class KeypointDescriptorGraph(nn.Module):
    """Unit-norm descriptors at given keypoints: ``image`` (B, 3, H, W) and ``keypoints``
    (B, N, 2) float32 (u, v) in the input's pixels -> (B, N, C): the dense graph's map at those
    positions by :func:`sample_keypoints`, with the net's 1x1 head run at the four pixels around
    each keypoint only."""

    def __init__(self, net: ContraFeatNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor, keypoints: torch.Tensor) -> torch.Tensor:
        return sample_keypoints(self.net.features(image), keypoints, self.net.head)


__all__ = ["DescriptorGraph", "KeypointDescriptorGraph", "sample_keypoints"]
