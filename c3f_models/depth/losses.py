"""Loss building blocks of DepthNet (docs/design.md, Depth network losses), each a small pure function.

Shapes: images (B, 3, H, W) in [0, 1]; per-pixel errors and masks (B, 1, H, W);
depths in metres. Masks are bool, True = the pixel counts.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def ssim_dissimilarity(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """(1 - SSIM) / 2 per pixel and channel, in [0, 1], over 3x3 windows (reflection padded).

    Monodepth2's SSIM: local means and (co)variances from a 3x3 average pool, C1 = 0.01^2,
    C2 = 0.03^2 (for images in [0, 1]).
    """
    x = F.pad(x, (1, 1, 1, 1), mode="reflect")
    y = F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x, mu_y = F.avg_pool2d(x, 3, 1), F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x**2
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y**2
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    num = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    den = (mu_x**2 + mu_y**2 + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return torch.clamp((1 - num / den) / 2, 0, 1)


def photometric_error(pred: torch.Tensor, target: torch.Tensor, alpha: float = 0.85) -> torch.Tensor:
    """pe = alpha * (1 - SSIM) / 2 + (1 - alpha) * L1, averaged over channels: (B, 1, H, W)."""
    l1 = (pred - target).abs().mean(dim=1, keepdim=True)
    ssim = ssim_dissimilarity(pred, target).mean(dim=1, keepdim=True)
    return alpha * ssim + (1 - alpha) * l1


def min_over_sources(errors: torch.Tensor, valid: torch.Tensor, fill: float = 1e4) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-pixel minimum over sources (dim 0 of (N, B, 1, H, W)) among valid ones.

    Returns the minimum error (``fill`` where no source is valid) and whether any source was.
    """
    masked = torch.where(valid, errors, torch.full_like(errors, fill))
    return masked.min(dim=0).values, valid.any(dim=0)


def automask(reprojection_error: torch.Tensor, identity_error: torch.Tensor) -> torch.Tensor:
    """Monodepth2 auto-mask: keep pixels whose warped error beats the unwarped source's error.

    Pixels that look the same without warping (static scene, camera at rest, objects moving
    with the camera) have ``identity_error <= reprojection_error`` and are dropped.
    """
    return reprojection_error < identity_error


def percentile_mask(error: torch.Tensor, valid: torch.Tensor, q: float = 0.8) -> torch.Tensor:
    """Drop outliers: keep valid pixels whose error is at most the q-quantile of each image's valid errors.

    The quantile is taken per image (dim 0) over its valid pixels only (linear interpolation),
    and is not differentiated through.
    """
    flat = torch.where(valid, error, torch.full_like(error, float("nan"))).flatten(1).detach()
    threshold = torch.nanquantile(flat.float(), q, dim=1).to(error.dtype)
    return valid & (error <= threshold.view(-1, *([1] * (error.dim() - 1))))


def depth_consistency_error(
    projected_depth: torch.Tensor, sampled_depth: torch.Tensor, eps: float = 1e-12
) -> torch.Tensor:
    """SC-SfMLearner depth inconsistency |D_a - D_b| / (D_a + D_b), in [0, 1].

    ``projected_depth``: the target's predicted depth carried into the source camera;
    ``sampled_depth``: the source's predicted depth interpolated at the projected pixels.
    """
    return (projected_depth - sampled_depth).abs() / (projected_depth + sampled_depth).clamp(min=eps)


def masked_mean(values: torch.Tensor, mask: torch.Tensor, dims: tuple[int, ...] | None = None) -> torch.Tensor:
    """Mean of ``values`` over the True pixels of ``mask`` (0 where the mask is empty).

    ``dims``: dimensions to reduce (all by default).
    """
    m = mask.to(values.dtype)
    vals = torch.where(mask, values, torch.zeros_like(values))
    if dims is None:
        return vals.sum() / m.sum().clamp(min=1)
    return vals.sum(dim=dims) / m.sum(dim=dims).clamp(min=1)


def log_depth_l1(pred: torch.Tensor, gt: torch.Tensor, min_depth: float = 1e-6) -> torch.Tensor:
    """Mean |log pred - log gt| over the pixels with ground truth (gt > ``min_depth``), depths in metres.

    A supervised term on the simulator's true depth (not in the paper): scale-aware, so it fixes
    the metric scale too. Returns 0 (with gradient) when no pixel has ground truth.
    """
    valid = gt > min_depth
    err = (torch.log(pred.clamp(min=min_depth)) - torch.log(gt.clamp(min=min_depth))).abs()
    return masked_mean(err, valid)


def log_gradient_matching(
    pred: torch.Tensor, gt: torch.Tensor, scales: int = 4, min_depth: float = 1e-6, edge: float = 0.0
) -> torch.Tensor:
    """Gradient matching of log depth (MegaDepth's / MiDaS's term, on log depth): with
    R = log pred - log gt, the mean |R(x+1) - R(x)| over horizontal and vertical neighbours that
    both have ground truth, averaged over ``scales`` resolutions (stride 1, 2, 4, ...).

    Blind to a global scale (R's constant part cancels), it asks the depth to step where the
    truth steps, e.g. at a fold's crest in front of the wall behind it, which the per-pixel
    :func:`log_depth_l1` lets the network blur. ``edge`` > 0 keeps only the neighbour pairs whose
    true log depth differs by more than ``edge`` (0.05 = a 5 % step): the mean is then over the
    true edges alone, which a mean over every pair drowns. Depths in metres, (B, 1, H, W); 0
    (with gradient) when no neighbour pair qualifies.
    """
    valid = gt > min_depth
    log_gt = torch.log(gt.clamp(min=min_depth))
    r = torch.log(pred.clamp(min=min_depth)) - log_gt
    r = torch.where(valid, r, torch.zeros_like(r))
    terms = []
    for k in range(scales):
        step = 2**k
        rs, vs, ls = r[..., ::step, ::step], valid[..., ::step, ::step], log_gt[..., ::step, ::step]
        if rs.shape[-1] < 2 or rs.shape[-2] < 2:
            break
        gx = (rs[..., :, 1:] - rs[..., :, :-1]).abs()
        gy = (rs[..., 1:, :] - rs[..., :-1, :]).abs()
        mx, my = vs[..., :, 1:] & vs[..., :, :-1], vs[..., 1:, :] & vs[..., :-1, :]
        if edge > 0:
            mx = mx & ((ls[..., :, 1:] - ls[..., :, :-1]).abs() > edge)
            my = my & ((ls[..., 1:, :] - ls[..., :-1, :]).abs() > edge)
        n = (mx.sum() + my.sum()).clamp(min=1)
        terms.append((torch.where(mx, gx, torch.zeros_like(gx)).sum() + torch.where(my, gy, torch.zeros_like(gy)).sum())
                     / n)
    return torch.stack(terms).mean() if terms else r.sum() * 0
