"""Images for TensorBoard: coloured depth maps and mask panels (all (B, 3, H, W) in [0, 1])."""

from __future__ import annotations

import torch
from matplotlib import colormaps
from torchvision.utils import make_grid


def colorize_depth(depth: torch.Tensor, valid: torch.Tensor | None = None, cmap: str = "magma") -> torch.Tensor:
    """(B, 1, H, W) depth (metres) -> (B, 3, H, W) colours of inverse depth.

    Per image, inverse depth is divided by its 95th percentile (Monodepth2's display), so
    near is bright, far is dark and a flat depth map stays nearly uniform. Invalid pixels
    (``valid`` False or depth <= 0) are black.
    """
    depth = depth.detach().float()
    ok = depth > 0 if valid is None else valid & (depth > 0)
    inv = torch.where(ok, 1.0 / depth.clamp(min=1e-9), torch.zeros_like(depth))
    flat = torch.where(ok, inv, torch.full_like(inv, float("nan"))).flatten(1)
    vmax = torch.nan_to_num(torch.nanquantile(flat, 0.95, dim=1), nan=1.0).view(-1, 1, 1, 1)
    norm = (inv / vmax.clamp(min=1e-12)).clamp(0, 1)
    colours = colormaps[cmap](torch.linspace(0, 1, 256).numpy())[:, :3]
    lut = torch.tensor(colours, dtype=torch.float32, device=depth.device)
    rgb = lut[(norm[:, 0] * 255).round().long()].permute(0, 3, 1, 2)
    return rgb * ok.float()


def mask_to_rgb(mask: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) bool -> (B, 3, H, W) white where True."""
    return mask.detach().float().expand(-1, 3, -1, -1)


def panel(columns: list[torch.Tensor]) -> torch.Tensor:
    """One row per sample, one column per (B, 3, H, W) entry of ``columns``: (3, H', W')."""
    rows = torch.stack([c.detach().float().cpu().clamp(0, 1) for c in columns], dim=1)  # (B, C, 3, H, W)
    return make_grid(rows.flatten(0, 1), nrow=len(columns), padding=2, pad_value=1.0)
