"""Predicted depth against a relative reference depth on real frames: rank correlation (no torch).

A real recording rarely comes with metric depth; a data set's rendered depth (8-bit grey,
relative) still orders the pixels by distance. Spearman's rank correlation of predicted depth
with such a reference, over the pixels of a mask, is then the fair measure: 1 when the
prediction orders every pixel as the reference does, -1 when it orders them the other way; any
increasing transform of either side (a scale, a gamma, an 8-bit quantisation) leaves it
unchanged. Ties (many, in an 8-bit reference) take their average rank.

Conventions: both depth maps are (H, W) arrays in the frame's pixel grid with larger = farther
(any unit); a reference of the opposite sense (brighter = nearer) is negated by the caller;
masks are (H, W) bool, True = pixel counted. Non-finite values are never counted.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from scipy.stats import spearmanr

from c3f_core.errors import InputError

#: fewer counted pixels than this give no correlation (None)
MIN_PIXELS = 3
#: the "darker is farther" heuristic blurs the luma with a Gaussian of this share of the smaller image side
LUMA_BLUR_SHARE = 0.02


def _counted(pred: np.ndarray, ref: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    pred, ref = np.asarray(pred), np.asarray(ref)
    if pred.shape != ref.shape or pred.ndim != 2:
        raise InputError(f"depth maps must be (H, W) of one shape, got {pred.shape} and {ref.shape}")
    ok = np.isfinite(pred) & np.isfinite(ref)
    if mask is not None:
        mask = np.asarray(mask, bool)
        if mask.shape != pred.shape:
            raise InputError(f"mask is {mask.shape} but the depth maps are {pred.shape}")
        ok &= mask
    return ok


def spearman(pred: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    """Spearman's rank correlation (-1..1) of ``pred`` with ``ref`` over the pixels of ``mask``
    (None: all) where both are finite; None under :data:`MIN_PIXELS` pixels or when either side
    is constant there."""
    ok = _counted(pred, ref, mask)
    return _rank_corr(np.asarray(pred)[ok], np.asarray(ref)[ok])


def _rank_corr(x: np.ndarray, y: np.ndarray) -> float | None:
    """SciPy's Spearman rho (ties ranked by their mean), None when too few or constant."""
    if x.size < MIN_PIXELS or np.ptp(x) == 0 or np.ptp(y) == 0:
        return None
    return float(spearmanr(x, y).statistic)


def luminance_depth(rgb: np.ndarray, blur_share: float = LUMA_BLUR_SHARE) -> np.ndarray:
    """The heuristic "darker is farther" of an (H, W, 3) uint8 RGB frame: 255 minus its luma
    (0..255) blurred by a Gaussian of ``blur_share`` of the smaller image side (sigma, pixels);
    (H, W) float32, larger = farther (relative, no unit)."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InputError(f"frame must be (H, W, 3) uint8 RGB, got {rgb.dtype} {rgb.shape}")
    luma = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    sigma = max(blur_share * min(rgb.shape[:2]), 0.0)
    if sigma > 0:
        luma = cv2.GaussianBlur(luma, (0, 0), sigma)
    return np.float32(255.0) - luma


def outside_share(pred: np.ndarray, tissue: np.ndarray) -> float | None:
    """Share (0..1) of the pixels outside the tissue area (``tissue`` False) where ``pred`` holds a
    depth (finite and not 0); None when every pixel is tissue."""
    pred, tissue = np.asarray(pred), np.asarray(tissue, bool)
    if pred.shape != tissue.shape:
        raise InputError(f"tissue mask is {tissue.shape} but the depth map is {pred.shape}")
    outside = ~tissue
    if not outside.any():
        return None
    p = pred[outside]
    return float((np.isfinite(p) & (p != 0)).mean())


def rank_depth(preds: Sequence[np.ndarray], refs: Sequence[np.ndarray], masks: Sequence[np.ndarray]) -> dict:
    """Spearman of each predicted depth map with its reference inside its mask, and over the
    frames: ``per_frame`` (None where undefined), ``mean`` and ``median`` of the defined ones,
    ``pooled`` (every counted pixel of every frame ranked together: a scale that changes from frame
    to frame counts against it), ``pixels`` counted per frame. None where nothing is defined."""
    if not (len(preds) == len(refs) == len(masks)):
        raise InputError(f"give one reference and one mask per prediction, got {len(preds)}, {len(refs)}, "
                         f"{len(masks)}")
    per_frame, pixels, xs, ys = [], [], [], []
    for p, r, m in zip(preds, refs, masks):
        ok = _counted(p, r, m)
        x, y = np.asarray(p)[ok], np.asarray(r)[ok]
        per_frame.append(_rank_corr(x, y))
        pixels.append(int(ok.sum()))
        xs.append(x)
        ys.append(y)
    defined = [v for v in per_frame if v is not None]
    pooled = _rank_corr(np.concatenate(xs), np.concatenate(ys)) if xs else None
    return {"per_frame": per_frame, "pixels": pixels, "pooled": pooled,
            "mean": float(np.mean(defined)) if defined else None,
            "median": float(np.median(defined)) if defined else None}


__all__ = ["LUMA_BLUR_SHARE", "MIN_PIXELS", "luminance_depth", "outside_share", "rank_depth", "spearman"]
