"""The zoo's held-out evaluation of one model: what its card reports.

- depth (the shipped ONNX file, through the runtime's :class:`~c3f_slam.models.nets.DepthModel`):
  the seven metrics with per-image median scaling (the project's protocol), and the metric
  depth: the network's depth times the metric scale recorded at export, never scaled by the
  ground truth; per sequence its scale ratio (median over frames of median(true) /
  median(predicted)) and scale error |ratio - 1|; and the SimCol3D challenge's depth metrics
  (one least-squares scale per sequence; L1 and RMSE in cm, relative error in %,
  :mod:`c3f_slam.io.simcol3d`).
- descriptors (the shipped weights in the LightningModule's test step): recall and precision
  of SIFT, SIFT+kpf, ContraFeat and ContraFeat+kpf matches on frame pairs at the given gaps.

Sequences are folders in the project's layout with true depth (and poses for matches).
Lengths are metres.
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceABC
from pathlib import Path

import numpy as np

from c3f_slam.evaluation.depth import METRIC_NAMES, depth_metrics
from c3f_slam.io import Sequence
from c3f_slam.io.simcol3d import depth_metrics_per_trajectory, mean_over_trajectories
from c3f_slam.models.nets import DepthModel

#: frame pairs of the descriptor evaluation: gaps (frames) and every STRIDE-th pair of each
MATCH_GAPS, MATCH_STRIDE = (2, 4, 8), 3


def depth_heldout(model_path: str | Path, sequences: SequenceABC[Path], stride: int = 3, threads: int = 2) -> dict:
    """Depth metrics of the ONNX model on every ``stride``-th frame of each sequence, per
    sequence and over them (``mean`` of the median-scaled metrics, ``median_scale_error``)."""
    model = DepthModel(model_path, threads=threads)
    lo, hi = model.depth_range or (1e-3, 0.3)
    scale = model.metric_scale or 1.0
    per_seq = {}
    for path in sequences:
        seq = Sequence(path)
        idx = list(range(0, len(seq), stride))
        pred = np.stack([model.predict(seq.read_rgb(i), seq.camera) for i in idx]) * scale
        gt = np.stack([seq.read_depth(i) for i in idx])
        scaled = depth_metrics(pred, gt, median_scaling=True, min_depth=lo, max_depth=hi)
        metric = depth_metrics(pred, gt, median_scaling=False, min_depth=lo, max_depth=hi)
        per_seq[Path(path).name] = {
            "frames": len(idx),
            "median_scaled": {k: scaled[k] for k in (*METRIC_NAMES, "pred_cv", "gt_cv")},
            "metric": {k: metric[k] for k in METRIC_NAMES},
            "scale_ratio": metric["scale"],
            "scale_error": abs(metric["scale"] - 1.0),
            "simcol3d": depth_metrics_per_trajectory(list(pred), list(gt)),
        }
    rows = list(per_seq.values())
    return {
        "metric_scale_in_model": model.metric_scale,
        "per_sequence": per_seq,
        "mean": {k: float(np.mean([r["median_scaled"][k] for r in rows])) for k in METRIC_NAMES},
        "metric_mean": {k: float(np.mean([r["metric"][k] for r in rows])) for k in METRIC_NAMES},
        "median_scale_error": float(np.median([r["scale_error"] for r in rows])),
        "simcol3d": mean_over_trajectories([r["simcol3d"] for r in rows]),
    }


def descriptor_metrics(model, data_dir: Path, names: SequenceABC[str], gaps: SequenceABC[int] = MATCH_GAPS,
                       stride: int = MATCH_STRIDE, size: int = 128, max_batches: int | None = None) -> dict[str, dict]:
    """Per sequence ``names`` of ``data_dir``: the ContraFeat test metrics of ``model`` (keys
    ``test/{sift,sift_kpf,cdf,cdf_kpf}_{recall,precision}``, ``test/gt_matches``, ...) on the
    pairs at ``gaps``, every ``stride``-th pair of each gap, frames of ``size`` pixels."""
    import lightning as L

    from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
    from datamodules.pairs import ContraFeatDataModule, PairSamplingConfig

    out = {}
    for name in names:
        dm = ContraFeatDataModule(str(data_dir), split=SplitConfig(train=[], val=[], test=[name]),
                                  sampling=PairSamplingConfig(gaps=list(gaps), eval_stride=stride),
                                  frames=FramesConfig(size=(size, size)), loader=LoaderConfig(batch_size=4))
        trainer = L.Trainer(accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
                            enable_model_summary=False, limit_test_batches=max_batches)
        out[name] = {k: float(v) for k, v in trainer.test(model, dm, verbose=False)[0].items()}
    return out


def descriptor_heldout(model, data_dir: Path, names: SequenceABC[str], **kwargs) -> dict:
    """:func:`descriptor_metrics` per sequence and their mean (recall/precision as fractions)."""
    per_seq = descriptor_metrics(model, data_dir, names, **kwargs)
    keys = next(iter(per_seq.values())).keys() if per_seq else []
    mean = {k.removeprefix("test/"): float(np.nanmean([r[k] for r in per_seq.values()])) for k in keys}
    return {"per_sequence": per_seq, "mean": mean,
            "pairs": {"gaps": list(kwargs.get("gaps", MATCH_GAPS)), "stride": kwargs.get("stride", MATCH_STRIDE)}}


__all__ = ["MATCH_GAPS", "MATCH_STRIDE", "depth_heldout", "descriptor_heldout", "descriptor_metrics"]
