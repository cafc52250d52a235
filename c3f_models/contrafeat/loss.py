"""InfoNCE over the ground-truth matches of a frame pair (paper §3.2, tau = 0.01).

For a pair with M matches (a_k, b_k) and unit descriptors z_a (M, C), z_b (M, C):
logits[k, m] = z_a[k] . z_b[m] / tau, and match k is a classification with target k, the
other M - 1 matched keypoints of the pair being the negatives. With ``symmetric`` (the
default) the loss is the mean of the i->j and j->i directions. The loss of a batch of pairs
is the mean over all matches of all pairs (pairs with fewer than two matches carry no
negatives and are skipped).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

TAU = 0.01


def info_nce(z_a: torch.Tensor, z_b: torch.Tensor, tau: float = TAU, symmetric: bool = True,
             reduction: str = "mean") -> torch.Tensor:
    """InfoNCE of one pair: (M, C) descriptors of matched keypoints, row k matches row k."""
    if z_a.shape != z_b.shape or z_a.ndim != 2:
        raise ValueError(f"z_a and z_b must be (M, C) of equal shape, got {tuple(z_a.shape)} and {tuple(z_b.shape)}")
    logits = (z_a.float() @ z_b.float().T) / tau
    target = torch.arange(len(z_a), device=z_a.device)
    loss = F.cross_entropy(logits, target, reduction="none")
    if symmetric:
        loss = 0.5 * (loss + F.cross_entropy(logits.T, target, reduction="none"))
    return loss.mean() if reduction == "mean" else loss.sum() if reduction == "sum" else loss


def batch_info_nce(pairs: list[tuple[torch.Tensor, torch.Tensor]], tau: float = TAU,
                   symmetric: bool = True) -> tuple[torch.Tensor | None, int]:
    """Mean InfoNCE over all matches of several pairs; returns (loss or None, number of matches)."""
    total, count = None, 0
    for z_a, z_b in pairs:
        if len(z_a) < 2:
            continue
        s = info_nce(z_a, z_b, tau, symmetric, reduction="sum")
        total = s if total is None else total + s
        count += len(z_a)
    return (total / count if total is not None else None), count
