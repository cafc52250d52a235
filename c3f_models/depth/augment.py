"""Colour augmentation of DepthNet's network inputs (Monodepth2's recipe, beyond the paper).

During training, with probability ``p`` a sample's three frames get one random brightness,
contrast, saturation and hue change, the same for the three (the photometric losses compare
frames with each other, so they must stay consistent). Only the networks see the changed
frames; the losses are computed on the original ones, as in Monodepth2. It makes the depth
network less sensitive to the mucosa's colour and the light's strength, which vary between
patients, scopes and simulator presets. Optional sensor noise (``noise``) is drawn for every
frame on its own, as a camera's is. ContraFeat uses the same change, drawn for each frame of a
pair on its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from c3f_core.errors import InputError

#: RGB -> YIQ; hue rotates the (I, Q) plane
_RGB_TO_YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
_LUMA = torch.tensor([0.299, 0.587, 0.114])


@dataclass(frozen=True)
class ColorAugmentConfig:
    """Random colour changes of the training inputs (off by default: the paper has none).

    Attributes:
        p: probability that a sample is changed (0 = off; Monodepth2: 0.5).
        brightness: factor drawn from [1 - b, 1 + b] (Monodepth2: 0.2).
        contrast: blend with the frames' mean luma, factor from [1 - c, 1 + c] (0.2).
        saturation: blend with the luma image, factor from [1 - s, 1 + s] (0.2).
        hue: rotation of the chroma plane by up to +-hue of a full turn (0.1).
        noise: sensor noise (0 = none; not in Monodepth2): a chosen sample gets zero-mean
            Gaussian noise, independent per pixel, channel and frame, of a standard deviation
            drawn from [0, noise] (fraction of the full range), added after the colour change.
    """

    p: float = 0.0
    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    hue: float = 0.1
    noise: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.p <= 1.0:
            raise InputError(f"model.augment.p must be in [0, 1], got {self.p}")
        for name in ("brightness", "contrast", "saturation"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InputError(f"model.augment.{name} must be in [0, 1), got {getattr(self, name)}")
        if not 0.0 <= self.hue <= 0.5:
            raise InputError(f"model.augment.hue must be in [0, 0.5], got {self.hue}")
        if not 0.0 <= self.noise <= 0.5:
            raise InputError(f"model.augment.noise must be in [0, 0.5], got {self.noise}")


def _factor(n: int, spread: float, device: torch.device) -> torch.Tensor:
    return 1.0 + (2.0 * torch.rand(n, device=device) - 1.0) * spread


def color_augment(frames: list[torch.Tensor], cfg: ColorAugmentConfig) -> list[torch.Tensor]:
    """``frames``: (B, 3, H, W) RGB in [0, 1] each, the frames of the same samples. Returns new
    tensors (the inputs are untouched), every sample's frames changed alike, clamped to [0, 1].
    Random numbers come from torch's global generator (so a resumed run repeats them)."""
    if cfg.p <= 0 or not frames:
        return frames
    b, device = frames[0].shape[0], frames[0].device
    chosen = (torch.rand(b, device=device) < cfg.p).view(b, 1, 1, 1)
    bright = _factor(b, cfg.brightness, device).view(b, 1, 1, 1)
    contrast = _factor(b, cfg.contrast, device).view(b, 1, 1, 1)
    sat = _factor(b, cfg.saturation, device).view(b, 1, 1, 1)
    angle = (2.0 * torch.rand(b, device=device) - 1.0) * cfg.hue * 2.0 * torch.pi
    to_yiq = _RGB_TO_YIQ.to(device)
    to_rgb = torch.linalg.inv(to_yiq)
    cos, sin = torch.cos(angle), torch.sin(angle)
    rot = torch.zeros(b, 3, 3, device=device)
    rot[:, 0, 0] = 1.0
    rot[:, 1, 1], rot[:, 1, 2], rot[:, 2, 1], rot[:, 2, 2] = cos, -sin, sin, cos
    hue_matrix = to_rgb @ rot @ to_yiq  # (B, 3, 3)
    luma_w = _LUMA.to(device).view(1, 3, 1, 1)
    mean_luma = torch.stack([(f * luma_w).sum(1).mean(dim=(1, 2)) for f in frames]).mean(0).view(b, 1, 1, 1)
    # drawn only when on, so that configurations without noise keep their random stream
    sigma = (torch.rand(b, device=device) * cfg.noise).view(b, 1, 1, 1) if cfg.noise > 0 else None
    out = []
    for f in frames:
        x = f * bright
        x = (x - mean_luma) * contrast + mean_luma
        luma = (x * luma_w).sum(1, keepdim=True)
        x = (x - luma) * sat + luma
        x = torch.einsum("bij,bjhw->bihw", hue_matrix, x)
        if sigma is not None:
            x = x + sigma * torch.randn_like(x)
        out.append(torch.where(chosen, x.clamp(0.0, 1.0), f))
    return out


__all__ = ["ColorAugmentConfig", "color_augment"]
