"""Descriptors at keypoints: the dense ContraFeat graph + sampling in NumPy vs the keypoint graph (outside CI).

For each net size, a randomly initialised ContraFeat (time and memory do not depend on the
weight values) is exported with the project's exporter (:func:`export.export_model`, parity
checks included: ``contrafeat.onnx`` and ``contrafeat_kp.onnx``) and both files run through the
runtime's :meth:`c3f_slam.models.DescriptorModel.describe_keypoints_batch` at batch 1, on the
same random network input and keypoints (uniform sub-pixel positions) per size:

- dense: the (1, C, H, W) map out of onnxruntime, then
  :func:`c3f_slam.matching.sample_descriptor_map` at the keypoints (what the runtime does with a
  dense file);
- keypoints: the keypoint graph, (1, N, C) out of onnxruntime.

Runs alternate between the two files (machine noise hits both alike); the table gives medians,
the ratio dense / keypoints (> 1: the keypoint graph is faster), the bytes of each graph's output
array, and the largest |difference| of the descriptors. The keypoint graph still runs the net's
trunk (FPN, stem) at full resolution, but its 1x1 head and the normalisation only at the four
pixels around each keypoint, and no map leaves the session.

Sizes: ``paper``, ResNet18-FPN with 128-d descriptors (configs/contrafeat/full.yaml); ``zoo``,
the half-width ResNet18 of the zoo's features model (configs/zoo/c3f-features-r18w32.yaml).

    python -m benchmarks.studies.descriptor_sampling --sizes 128 224 --keypoints 500 --threads 2 \\
        --report /tmp/descriptor_sampling.md
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

from benchmarks.common.report import Report
from c3f_models import ContraFeat
from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_slam.matching import sample_descriptor_map
from c3f_slam.models import DescriptorModel
from datamodules.synthetic.fixture import make_tiny_sequence
from export import export_model

#: the compared nets: name -> (label, network settings)
NETS = {
    "paper": ("paper: ResNet18-FPN, 128-d", ContraFeatNetworkConfig(
        backbone_layers=18, backbone_width=64, descriptor_dim=128, fpn_channels=128, stem_channels=32,
        head_channels=128)),
    "zoo": ("zoo: half-width ResNet18-FPN, 128-d", ContraFeatNetworkConfig(
        backbone_layers=18, backbone_width=32, descriptor_dim=128, fpn_channels=64, stem_channels=16,
        head_channels=64)),
}


def export_both(net: ContraFeatNetworkConfig, work: Path, frames: Path) -> tuple[Path, Path]:
    """(dense file, keypoint file) of a randomly initialised ContraFeat with ``net``."""
    torch.manual_seed(0)
    ckpt = work / "random.ckpt"
    torch.save({"state_dict": ContraFeat(net).state_dict()}, ckpt)
    dense, kp = export_model(ContraFeat(net), ckpt, work / "export", frames=frames, num_frames=2)
    return dense, kp


def time_pair(dense: DescriptorModel, kp: DescriptorModel, size: int, n: int, repeats: int,
              warmup: int) -> dict:
    """Median ms per frame of the dense file (its graph, then the NumPy sampling: the steps of its
    ``describe_keypoints_batch``) and of the keypoint file, output bytes and the largest
    |difference|, on one random input of ``size`` px with ``n`` keypoints."""
    rng = np.random.default_rng(size)
    x = rng.random((1, 3, size, size), dtype=np.float32)
    pts = rng.uniform(0, size - 1, (1, n, 2)).astype(np.float32)
    runs: dict[str, list[float]] = {"map": [], "sampling": [], "dense": [], "keypoints": []}
    for k in range(warmup + repeats):
        t0 = time.perf_counter()
        maps = dense.describe_batch(x)
        t1 = time.perf_counter()
        a = np.stack([sample_descriptor_map(m, p, normalise=True) for m, p in zip(maps, pts)])
        t2 = time.perf_counter()
        b = kp.describe_keypoints_batch(x, pts)
        t3 = time.perf_counter()
        if k >= warmup:
            runs["map"].append(t1 - t0)
            runs["sampling"].append(t2 - t1)
            runs["dense"].append(t2 - t0)
            runs["keypoints"].append(t3 - t2)
    assert np.array_equal(a, dense.describe_keypoints_batch(x, pts))  # the runtime's steps, timed above
    ms = {k: 1e3 * statistics.median(v) for k, v in runs.items()}
    return {**ms, "dense_bytes": maps.nbytes, "kp_bytes": b.nbytes, "max_diff": float(np.abs(a - b).max())}


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nets", nargs="+", choices=tuple(NETS), default=list(NETS))
    ap.add_argument("--sizes", nargs="+", type=int, default=[128, 224], help="network input height = width, px")
    ap.add_argument("--keypoints", type=int, default=500, help="keypoints per frame")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--report", type=Path, default=None, help="Markdown report (default: print only)")
    return ap.parse_args()


def _table(rows: list[tuple[str, int, dict]]) -> list[str]:
    lines = ["| net | px | dense graph ms | + NumPy sampling ms | dense total ms | keypoint graph ms | "
             "dense / keypoints (time) | dense output | keypoint output | dense / keypoints (output) | "
             "max abs diff |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for label, size, r in rows:
        lines.append(f"| {label} | {size} | {r['map']:.1f} | {r['sampling']:.2f} | {r['dense']:.1f} | "
                     f"{r['keypoints']:.1f} | {r['dense'] / r['keypoints']:.2f} | {r['dense_bytes'] / 1e6:.2f} MB | "
                     f"{r['kp_bytes'] / 1e3:.0f} kB | {r['dense_bytes'] / r['kp_bytes']:.0f} | {r['max_diff']:.1e} |")
    return lines


def main() -> None:
    a = _arguments()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        frames = make_tiny_sequence(Path(tmp) / "frames", frames=2, size=128, seed=0)
        for name in a.nets:
            label, net = NETS[name]
            work = Path(tmp) / name
            work.mkdir()
            dense_path, kp_path = export_both(net, work, frames)
            dense, kp = DescriptorModel(dense_path, a.threads), DescriptorModel(kp_path, a.threads)
            for size in a.sizes:
                r = time_pair(dense, kp, size, a.keypoints, a.repeats, a.warmup)
                rows.append((label, size, r))
                print(f"{label}, {size} px: dense {r['dense']:.1f} ms, keypoints {r['keypoints']:.1f} ms, "
                      f"output {r['dense_bytes'] / 1e6:.2f} MB vs {r['kp_bytes'] / 1e3:.0f} kB", flush=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    report = Report(__file__, "Descriptors at keypoints: dense graph + NumPy sampling vs the keypoint graph")
    text = report.render([
        f"Setup: batch 1, {a.keypoints} keypoints (uniform sub-pixel positions), random weights, {a.threads} "
        f"onnxruntime threads, median of {a.repeats} alternating runs after {a.warmup} warm-up runs (dense total: "
        "median of graph + sampling per run). onnxruntime "
        f"{ort.__version__} (CPU), {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load "
        f"average at the end {load:.2f}. Outputs: float32 arrays out of the session.",
        "",
        *_table(rows),
    ])
    if a.report:
        report.write(a.report, text)
    print(text)


if __name__ == "__main__":
    main()
