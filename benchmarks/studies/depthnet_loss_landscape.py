"""Does DepthNet's objective prefer the true depth? Loss terms at ground-truth depth and pose.

For simulator triplets (ground-truth depth and camera-to-world poses), evaluate the
self-supervised objective (c3f_models.depth.objective, the training code) at fixed inputs
instead of network outputs:

- ``gt depth, gt pose``: the answer the training should find;
- ``flat depth, gt pose``: each frame's depth replaced by its median (no structure);
- ``flat depth, no motion``: flat depth and identity poses (the trivially consistent
  solution depth consistency cannot tell from the truth);
- ``gt depth, no motion``.

If a term is not lower at the truth than with flat depth, it gives the depth network no
signal towards structure on this data. Terms are averaged over all triplets of the given
sequences (finest scale, each LossConfig switch as in configs/depthnet/small.yaml unless
changed with --no-outlier). Outside CI.

    python -m benchmarks.studies.depthnet_loss_landscape --data runs/bench/depth_slow --seqs test0 test1
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarks.common import STUDIES
from benchmarks.common.report import Report

TERMS = ("ph", "ph_extra", "dc", "loss")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="folder of sequences in the project layout")
    ap.add_argument("--seqs", nargs="+", required=True, help="sequence names in --data (with depth and poses)")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--no-outlier", action="store_true", help="turn off the 80th-percentile outlier removal")
    ap.add_argument("--out", type=Path, default=STUDIES / "depthnet_loss_landscape.md")
    a = ap.parse_args()
    import torch

    from c3f_models.depth.objective import LossConfig, SelfSupervisedLoss, compose_triplet_poses
    from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
    from datamodules.sequence import C3FSequenceDataModule

    torch.set_num_threads(1)
    dm = C3FSequenceDataModule(data_dir=str(a.data), split=SplitConfig(train=[], val=[], test=a.seqs),
                               frames=FramesConfig(size=(a.size, a.size)), loader=LoaderConfig(batch_size=8))
    dm.setup("test")
    loss = SelfSupervisedLoss(LossConfig(use_outlier_mask=not a.no_outlier))
    cases = ("gt depth, gt pose", "flat depth, gt pose", "gt depth, no motion", "flat depth, no motion")
    sums = {c: dict.fromkeys(TERMS, 0.0) for c in cases}
    n = 0
    with torch.no_grad():
        for b in dm.test_dataloader():
            images = list(b["image"].unbind(1))
            specular = list(b["specular"].bool().unbind(1))
            P = b["pose"].double()  # camera-to-world
            T_10 = (torch.linalg.inv(P[:, 1]) @ P[:, 0]).float()
            T_21 = (torch.linalg.inv(P[:, 2]) @ P[:, 1]).float()
            true_poses = compose_triplet_poses(T_10, T_21)
            still = {k: torch.eye(4).expand_as(v).clone() for k, v in true_poses.items()}
            gt = [d.clamp(min=1e-3) for d in b["depth"].unbind(1)]
            flat = [torch.ones_like(d) * d.flatten(1).median(1).values.view(-1, 1, 1, 1) for d in gt]
            k = b["image"].shape[0]
            for case in cases:
                depth = gt if case.startswith("gt depth") else flat
                poses = true_poses if case.endswith("gt pose") else still
                t = loss.single_scale(images, specular, dict(enumerate(depth)), poses, b["K"])
                for name in TERMS:
                    sums[case][name] += float(getattr(t, name)) * k
            n += k
    rows = "".join(f"| {c} | " + " | ".join(f"{sums[c][t] / n:.5f}" for t in TERMS) + " |\n" for c in cases)
    report = Report(__file__, "DepthNet objective at ground-truth depth and pose")
    text = report.render([
        f"{n} triplets of {', '.join(a.seqs)} in `{a.data}`, {a.size}x{a.size}; terms of the training objective "
        f"(finest scale, lambda 0.1 for both extras, outlier removal {'off' if a.no_outlier else 'on'}), averaged over "
        "triplets. Flat depth: each frame's depth replaced by its median; no motion: identity poses.\n\n"
        "| inputs | L_ph | L_ph-extra | L_dc | L |\n|---|---|---|---|---|\n" + rows
    ])
    report.write(a.out, text)
    print(text)


if __name__ == "__main__":
    main()
