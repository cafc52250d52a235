"""Metric scale of a depth export, measured on training sequences with true depth.

A self-supervised DepthNet predicts depth only up to a scale (nothing in the photometric
losses ties it to metres); the CPU-trained networks of this project predict 0.14-0.17 of the
true depth (docs/lab_notes/2026-11-22-depth-motion.md), while the SLAM runtime's thresholds are in
metres. When the training data have true depth (the simulator, UTS-synthetic, SimCol3D), the
exporter measures the factor and records it in the depth model's metadata
(``depth.metric_scale``); ``c3f_slam run`` multiplies the model's depth by it unless
``--depth-scale`` is given. The graph itself is unchanged (parity with PyTorch stays exact).
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceABC

import cv2
import numpy as np
import torch
from torch import nn

from c3f_slam.evaluation.depth import median_scale
from c3f_slam.frames.preprocess import center_crop_resize
from c3f_slam.models.metadata import Preprocessing
from export.frames import evenly_spaced, frames_from_source


def metric_scale(
    depth_graph: nn.Module, sequences: SequenceABC, pre: Preprocessing, frames_per_sequence: int = 8,
    names: SequenceABC[str] | None = None,
) -> dict | None:
    """``{"metric_scale", "spread", "frames", "source"}``: the median over frames of
    median(true depth) / median(predicted depth) (valid pixels: true depth > 0 and finite,
    prediction > 0), on ``frames_per_sequence`` evenly spaced frames of each sequence that has
    depth (anything with ``camera``, ``len``, ``read_rgb``, ``read_depth`` in metres and
    ``has_depth``), pre-processed as in training (true depth: the same crop, nearest-neighbour
    resize); ``spread`` = coefficient of variation of the per-frame ratios. None when no
    sequence has depth. ``depth_graph``: (B, 3, h, w) RGB in [0, 1] -> (B, 1, h, w) depth."""
    ratios: list[float] = []
    used: list[str] = []
    depth_graph = depth_graph.eval()
    for k, seq in enumerate(sequences):
        if not getattr(seq, "has_depth", False) or len(seq) == 0:
            continue
        images = frames_from_source(seq, pre, frames_per_sequence)
        picks = evenly_spaced(len(seq), frames_per_sequence)
        with torch.no_grad():
            pred = depth_graph(images)[:, 0].numpy()
        for p, i in zip(pred, picks):  # frames_from_source reads the same evenly spaced frames
            gt, _ = center_crop_resize(seq.read_depth(int(i)), seq.camera, pre.crop, pre.size, cv2.INTER_NEAREST)
            r = median_scale(p, gt, min_pixels=10)
            if np.isfinite(r):
                ratios.append(r)
        used.append(str(names[k]) if names is not None else getattr(seq, "name", str(k)))
    if not ratios:
        return None
    r = np.asarray(ratios)
    return {
        "metric_scale": float(np.median(r)),
        "spread": float(r.std() / r.mean()),
        "frames": len(ratios),
        "source": f"median over {len(ratios)} frames of the training sequences {', '.join(used)} of "
                  "median(true depth) / median(predicted depth), measured at export",
    }
