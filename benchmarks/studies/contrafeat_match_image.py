"""Match images of ContraFeat checkpoints on one held-out frame pair, stacked top to bottom.

Each row shows frame i (left) and frame j (right) with the mutual-nearest-neighbour CDF
matches at SIFT keypoints: green = correct (ground truth within ``pixel_radius``), yellow = near
miss (wrong, but within 3 x ``pixel_radius`` of the true position), red = other wrong.
The checkpoints are those ``benchmarks.protocols.contrafeat_pr`` saves (small configuration).

    python -m benchmarks.studies.contrafeat_match_image --data DIR/test --seq test_seq3 --gap 8 \
        --checkpoint A.ckpt --checkpoint B.ckpt --out matches.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks.common.contrafeat import SMALL_MODEL, load_weights
from c3f_models.contrafeat.module import ContraFeat
from c3f_models.contrafeat.pairs import batch_frames, make_pairs
from c3f_slam.matching.match_accuracy import near_misses
from c3f_slam.matching.visual import draw_matches
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
from datamodules.pairs import ContraFeatDataModule, PairSamplingConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="folder holding the sequence")
    ap.add_argument("--seq", required=True, help="sequence name inside --data")
    ap.add_argument("--gap", type=int, default=8, help="frame gap of the pair")
    ap.add_argument("--pair", type=int, default=1, help="which pair of the first evaluation batch (0-3)")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--checkpoint", type=Path, action="append", required=True, help="one row per checkpoint")
    ap.add_argument("--out", type=Path, required=True, help="PNG file")
    args = ap.parse_args()
    torch.set_num_threads(1)
    dm = ContraFeatDataModule(str(args.data), split=SplitConfig(train=[], val=[], test=[args.seq]),
                              sampling=PairSamplingConfig(gaps=(args.gap,), eval_stride=3),
                              frames=FramesConfig(size=(args.size, args.size)), loader=LoaderConfig(batch_size=4))
    dm.setup("test")
    batch = next(iter(dm.test_dataloader()))
    frames = batch_frames(batch)
    rows = []
    for ckpt in args.checkpoint:
        model = ContraFeat(**SMALL_MODEL)
        load_weights(model, ckpt)
        model.eval()
        with torch.no_grad():
            maps = model._descriptor_maps(batch)
        pairs = make_pairs(frames, model.kp_settings, model.gt_settings, sift_descriptors=True)
        counts, details = model.evaluate_pairs(maps, frames, pairs)
        p, ev = details[args.pair]
        fi, fj = frames[p.b][p.i], frames[p.b][p.j]
        near, _ = near_misses(ev.matches, p.kp_j.xy, p.projection, ev.correct,
                              pixel_radius=model.gt_settings.pixel_radius)
        rows.append(draw_matches(fi.image, fj.image, p.kp_i.xy, p.kp_j.xy, ev.matches, correct=ev.correct, scale=2,
                                 near=near))
        print(f"{ckpt}: this pair {int(np.sum(ev.correct))} correct of {len(ev.matches)} matches "
              f"({int(np.sum(near))} of the wrong ones near misses; {len(p.gt)} ground-truth); "
              "first batch CDF recall/precision "
              f"{100 * counts['cdf'].recall:.1f}/{100 * counts['cdf'].precision:.1f} %, "
              f"SIFT {100 * counts['sift'].recall:.1f}/{100 * counts['sift'].precision:.1f} %")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp.png")
    cv2.imwrite(str(tmp), cv2.cvtColor(np.concatenate(rows, axis=0), cv2.COLOR_RGB2BGR))
    tmp.replace(args.out)


if __name__ == "__main__":
    main()
