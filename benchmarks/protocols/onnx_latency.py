"""Per-frame latency: PyTorch eager vs onnxruntime on CPU, for every exported graph.

Each net is built at its config's default (paper) size with random weights (latency does
not depend on the weight values), exported with the project's exporter
(:func:`export.onnx_io.to_onnx`), then timed at batch 1 with the same number of threads
for both (torch.set_num_threads / intra_op_num_threads). Runs alternate between the two
back-ends, so machine noise hits both alike; the table gives medians and the ratio
eager / onnxruntime (> 1 means onnxruntime is faster).

    python -m benchmarks.protocols.onnx_latency --set threads=2 --set repeats=20

Inputs: none (random weights, the configs' networks).

Writes benchmarks/results/onnx_latency.md (numbers + the command line) and its .json (``--report``;
``--out`` its former name). Settings (``--print-config``: each with its default and meaning):
:class:`Settings`.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

from benchmarks.common import RESULTS
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli
from benchmarks.common.report import Report
from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_models.contrafeat.graphs import DescriptorGraph
from c3f_models.contrafeat.network import ContraFeatNet
from c3f_models.depth.config import DepthNetworkConfig
from c3f_models.depth.graphs import DepthGraph, PoseGraph
from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from export.graphs import OPSET, OPSET_DEFORM
from export.onnx_io import to_onnx


def graphs(size: int, small: bool):
    """(label, module, input names, output name, opset, example inputs) for each net."""
    x = torch.rand(1, 3, size, size)
    if small:
        depth = DepthGraph(DepthNetwork(DepthNetworkConfig(num_scales=1)))
        yield "DepthNet (ResNet18, no DCN)", depth, ("image",), "depth", OPSET, (x,)
    else:
        depth = DepthGraph(DepthNetwork(DepthNetworkConfig(encoder_layers=50, dcn=True, num_scales=1)))
        yield "DepthNet (ResNet50 + DCN)", depth, ("image",), "depth", OPSET_DEFORM, (x,)
    pose = PoseGraph(PoseNetwork(DepthNetworkConfig()))
    yield "PoseNet (ResNet18, 2 frames)", pose, ("image_a", "image_b"), "T_ba", OPSET, (x, torch.rand_like(x))
    cf = ContraFeatNet(ContraFeatNetworkConfig(fpn_channels=64, stem_channels=16, head_channels=64) if small
                       else ContraFeatNetworkConfig(head_channels=128))
    yield (f"ContraFeat (ResNet18 FPN, 128-d{', small' if small else ''})", DescriptorGraph(cf), ("image",),
           "descriptors", OPSET, (x,))


def time_pair(module, session, inputs, names, repeats: int, warmup: int) -> tuple[list[float], list[float]]:
    feeds = {n: t.numpy() for n, t in zip(names, inputs)}
    eager, onnx_rt = [], []
    with torch.inference_mode():
        for _ in range(warmup):
            module(*inputs)
            session.run(None, feeds)
        for _ in range(repeats):
            t0 = time.perf_counter()
            module(*inputs)
            eager.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            session.run(None, feeds)
            onnx_rt.append(time.perf_counter() - t0)
    return eager, onnx_rt


@dataclass(frozen=True)
class Settings:
    """What onnx_latency measures."""

    threads: int = 2  #: threads of both back-ends (torch.set_num_threads, intra_op_num_threads)
    repeats: int = 20  #: timed runs of each back-end (alternating; median reported)
    warmup: int = 3  #: untimed runs before them
    size: int = 224  #: input height = width, pixels (the configs' default: 224)
    small: bool = False  #: the CPU variants (ResNet18 depth without DCN, small FPN)


CLI = ProtocolCli("onnx_latency", Settings, __doc__, example="repeats=5")


def main(argv: list[str] | None = None) -> None:
    ap = CLI.parser()
    ap.add_argument("--report", "--out", type=Path, default=RESULTS / "onnx_latency.md",
                    help=REPORT_HELP + " (--out: its former name)")
    a, settings = CLI.parse(ap, argv)
    torch.manual_seed(0)
    torch.set_num_threads(settings.threads)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = settings.threads
    opts.inter_op_num_threads = 1
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL

    rows = []
    for label, module, names, out_name, opset, inputs in graphs(settings.size, settings.small):
        module.eval()
        proto = to_onnx(module, inputs, names, out_name, opset)
        session = ort.InferenceSession(proto.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        eager, rt = time_pair(module, session, inputs, names, settings.repeats, settings.warmup)
        with torch.inference_mode():
            onnx_out = session.run(None, {n: t.numpy() for n, t in zip(names, inputs)})[0]
            diff = float(np.abs(onnx_out - module(*inputs).numpy()).max())
        e, r = statistics.median(eager) * 1e3, statistics.median(rt) * 1e3
        rows.append((label, e, r, e / r, diff))
        print(f"{label}: eager {e:.1f} ms, onnxruntime {r:.1f} ms, ratio {e / r:.2f}, max|diff| {diff:.2g}", flush=True)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    report = Report(__file__, "Per-frame latency: PyTorch eager vs onnxruntime (CPU)", argv)
    text = report.publish(a.report, [
        f"Setup: batch 1, {settings.size}x{settings.size}, {settings.threads} threads for both back-ends, random "
        f"weights, median of {settings.repeats} alternating runs after {settings.warmup} warm-up runs. torch "
        f"{torch.__version__}, onnxruntime {ort.__version__}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, load average at the end {load:.2f}.\n\n"
        "| net | eager ms | onnxruntime ms | eager / onnxruntime | max abs diff |\n|---|---|---|---|---|\n"
        + "".join(f"| {label} | {e:.1f} | {r:.1f} | {ratio:.2f} | {d:.1e} |\n" for label, e, r, ratio, d in rows)
    ], settings, options=a)
    print(text)


if __name__ == "__main__":
    main()
