"""Depth evaluation metrics (the Monodepth2 protocol), the one function every evaluation uses.

Units: metres in, metres out (Sq Rel and RMSE carry units; print cm only in reports).
Works on NumPy arrays and torch tensors alike and does not import torch.
"""

from __future__ import annotations

from typing import Any

import numpy as np

METRIC_NAMES = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


def _as_numpy(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):  # torch tensor
        x = x.detach().float().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _as_images(x: np.ndarray) -> np.ndarray:
    """(H, W), (B, H, W) or (B, 1, H, W) -> (B, H*W)."""
    if x.ndim == 2:
        x = x[None]
    elif x.ndim == 4:
        if x.shape[1] != 1:
            raise ValueError(f"depth maps must have one channel, got shape {x.shape}")
        x = x[:, 0]
    elif x.ndim != 3:
        raise ValueError(f"depth maps must be (H, W), (B, H, W) or (B, 1, H, W), got shape {x.shape}")
    return x.reshape(x.shape[0], -1)


def image_depth_metrics(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """The seven metrics for one image's valid pixels (1-D arrays of positive depths)."""
    thresh = np.maximum(gt / pred, pred / gt)
    diff = gt - pred
    return {
        "abs_rel": float(np.mean(np.abs(diff) / gt)),
        "sq_rel": float(np.mean(diff**2 / gt)),
        "rmse": float(np.sqrt(np.mean(diff**2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(gt) - np.log(pred)) ** 2))),
        "a1": float(np.mean(thresh < 1.25)),
        "a2": float(np.mean(thresh < 1.25**2)),
        "a3": float(np.mean(thresh < 1.25**3)),
    }


def median_scale(pred: Any, gt: Any, min_pixels: int = 1) -> float:
    """median(gt) / median(pred) over the pixels where both are finite and positive: the
    factor that brings a scale-ambiguous (self-supervised) prediction to the ground truth's
    units (per-image median scaling; the exporter's ``depth.metric_scale``). NaN with fewer
    than ``min_pixels`` such pixels."""
    p, g = _as_numpy(pred).ravel(), _as_numpy(gt).ravel()
    ok = np.isfinite(p) & np.isfinite(g) & (p > 0) & (g > 0)
    if ok.sum() < max(min_pixels, 1):
        return float("nan")
    return float(np.median(g[ok]) / np.median(p[ok]))


def depth_metrics(
    pred: Any,
    gt: Any,
    mask: Any = None,
    median_scaling: bool = True,
    min_depth: float = 1e-3,
    max_depth: float = 0.3,
) -> dict[str, float]:
    """Abs Rel, Sq Rel, RMSE, RMSE log and delta < 1.25^k (``a1``-``a3``), averaged over images.

    Per image (Monodepth2 protocol): valid pixels have ``min_depth < gt < max_depth``, a finite
    prediction and ``mask`` True (if given); with ``median_scaling`` the prediction is
    multiplied by median(gt) / median(pred) over those pixels; then it is clipped to
    [min_depth, max_depth]. Images without valid pixels are skipped; if none is left every
    metric is NaN. ``n_images`` says how many images were averaged. ``pred_cv`` and
    ``gt_cv`` are the spatial coefficients of variation (std / mean over the valid pixels,
    before scaling) of the prediction and the ground truth, averaged over images: a
    ``pred_cv`` near 0 means a flat prediction (a collapsed network), whatever its scale.
    ``scale`` is the median over images of median(gt) / median(pred) (before scaling): the
    factor that brings a scale-ambiguous (self-supervised) prediction to metres, e.g. for the
    SLAM runtime's ``--depth-scale``.

    Args:
        pred, gt: depth maps in metres, (H, W), (B, H, W) or (B, 1, H, W); gt 0 = no depth.
        mask: optional bool array of the same shape, True = evaluate.
    """
    p, g = _as_images(_as_numpy(pred)), _as_images(_as_numpy(gt))
    if p.shape != g.shape:
        raise ValueError(f"pred and gt shapes differ: {p.shape} vs {g.shape}")
    m = np.ones_like(g, dtype=bool) if mask is None else _as_images(_as_numpy(mask)).astype(bool)
    if m.shape != g.shape:
        raise ValueError(f"mask shape {m.shape} differs from gt {g.shape}")
    rows, cvs, scales = [], [], []
    for pi, gi, mi in zip(p, g, m):
        valid = mi & np.isfinite(gi) & (gi > min_depth) & (gi < max_depth) & np.isfinite(pi) & (pi > 0)
        if not valid.any():
            continue
        pv, gv = pi[valid], gi[valid]
        cvs.append((float(np.std(pv) / np.mean(pv)), float(np.std(gv) / np.mean(gv))))
        scales.append(median_scale(pv, gv))
        if median_scaling:
            pv = pv * scales[-1]
        pv = np.clip(pv, min_depth, max_depth)
        rows.append(image_depth_metrics(pv, gv))
    out = {k: float(np.mean([r[k] for r in rows])) if rows else float("nan") for k in METRIC_NAMES}
    out["pred_cv"] = float(np.mean([c[0] for c in cvs])) if cvs else float("nan")
    out["gt_cv"] = float(np.mean([c[1] for c in cvs])) if cvs else float("nan")
    out["scale"] = float(np.median(scales)) if scales else float("nan")
    out["n_images"] = len(rows)
    return out
