"""Which DepthNet loss term drives the networks? Gradient norms per term (outside CI).

For batches of frame triplets of the given simulator sequences, the gradient of each term of
the training objective (L_ph, L_ph-extra, L_dc, unweighted, as the module computes them) is
taken with respect to the depth network's and PoseNet's parameters, and its L2 norm is
reported, with the ratio |grad L_dc| / |grad L_ph|. Multiply that ratio by lambda_dc (0.1 in
the paper) to compare the two terms' pulls in the training loss. Run at the random
initialisation (seeded) and, with --ckpt, at a trained checkpoint's weights.

    python -m benchmarks.studies.depthnet_gradients --data runs/bench/depth_slow --seqs train0 train1 \
        --ckpt runs/bench/baseline400.ckpt
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from benchmarks.common import ROOT
from benchmarks.common.report import Report

TERMS = ("ph", "ph_extra", "dc")


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT / "runs/bench/depth_slow")
    ap.add_argument("--seqs", nargs="+", default=["train0", "train1"])
    ap.add_argument("--ckpt", type=Path, default=None, help="also evaluate at this DepthNet checkpoint's weights")
    ap.add_argument("--batches", type=int, default=8, help="batches, evenly spread over the sequences")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--num-scales", type=int, default=2, help="as configs/depthnet/small.yaml")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="Markdown report (default: print only)")
    a = ap.parse_args()
    if a.ckpt is not None and not a.ckpt.is_file():
        ap.error(f"--ckpt: no such checkpoint: {a.ckpt}")
    return a


def _batches(a: argparse.Namespace) -> list:
    """``a.batches`` batches of 4 triplets, evenly spread over the test split of the sequences."""
    from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
    from datamodules.sequence import C3FSequenceDataModule

    dm = C3FSequenceDataModule(data_dir=str(a.data), split=SplitConfig(train=[], val=[], test=a.seqs),
                               frames=FramesConfig(size=(a.size, a.size)), loader=LoaderConfig(batch_size=4))
    dm.setup("test")
    n_batches = len(dm.test_dataloader())
    step = max(n_batches // a.batches, 1)
    return [b for k, b in enumerate(dm.test_dataloader()) if k % step == step // 2][: a.batches]


def _gradient_row(name: str, ckpt: Path | None, a: argparse.Namespace, batches: list) -> str:
    """One table row: median loss terms, gradient norms per term and network, and the
    |grad L_dc| / |grad L_ph| ratios, for the seeded initialisation or ``ckpt``'s weights."""
    import torch

    from c3f_models.depth.module import DepthNet

    torch.manual_seed(a.seed)
    model = DepthNet({"encoder_layers": 18, "dcn": False, "num_scales": a.num_scales})
    if ckpt is not None:
        model.load_init_weights(ckpt)
    nets = {"depth": list(model.depth_net.parameters()), "pose": list(model.pose_net.parameters())}
    norms: dict[tuple[str, str], list[float]] = {}
    values: dict[str, list[float]] = {t: [] for t in TERMS}
    for b in batches:
        terms, _ = model.compute_loss(b)
        for t in TERMS:
            v = getattr(terms, t)
            values[t].append(float(v.detach()))
            for net, params in nets.items():
                g = torch.autograd.grad(v, params, retain_graph=True, allow_unused=True)
                norms.setdefault((t, net), []).append(float(sum((x ** 2).sum() for x in g if x is not None) ** 0.5))
    ratio = {net: statistics.median(d / p for d, p in zip(norms[("dc", net)], norms[("ph", net)])) for net in nets}
    return (f"| {name} | " + " | ".join(f"{statistics.median(values[t]):.4f}" for t in TERMS) + " | "
            + " | ".join(f"{statistics.median(norms[(t, net)]):.2e}" for net in nets for t in TERMS)
            + f" | {ratio['depth']:.1f} | {ratio['pose']:.1f} |")


def main() -> None:
    a = _arguments()
    import torch

    torch.set_num_threads(1)
    batches = _batches(a)
    rows = []
    for name, ckpt in (("random init", None), (f"weights of {a.ckpt}", a.ckpt)):
        if name != "random init" and ckpt is None:
            continue
        rows.append(_gradient_row(name, ckpt, a, batches))

    report = Report(__file__, "DepthNet: gradient norm of each loss term")
    text = report.render([
        (f"{len(batches)} batches of 4 triplets from {', '.join(a.seqs)} in `{a.data}`, {a.size}x{a.size}, small CPU "
         f"variant (ResNet18, no DCN, {a.num_scales} scales), every loss switch on; medians over the batches. Terms "
         "unweighted (the training loss adds 0.1 x L_ph-extra and lambda_dc x L_dc)."), "",
        ("| weights | L_ph | L_ph-extra | L_dc | depth: grad L_ph | grad L_ph-extra | grad L_dc | pose: grad L_ph "
         "| grad L_ph-extra | grad L_dc | depth: grad L_dc / grad L_ph | pose: grad L_dc / grad L_ph |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|", *rows])
    if a.out:
        report.write(a.out, text)
    print(text)


if __name__ == "__main__":
    main()
