"""Evaluate saved ContraFeat checkpoints on held-out sequences (paper table 2), without training.

For each checkpoint (saved by ``benchmarks.protocols.contrafeat_pr``, small configuration) and each
keypoint-filter residual threshold: recall / precision of SIFT, SIFT+kpf, CDF and CDF+kpf,
averaged over the sequences, and where the precision goes (near misses vs gross errors, see
:mod:`c3f_slam.matching.match_accuracy`). The residual sweep shows what the kpf's threshold trades:
the pairwise tolerance follows it (2 x residual, as in ``MatchFilterConfig()``, the colon's).

    python -m benchmarks.studies.contrafeat_eval --data DIR/test --checkpoint A.ckpt --checkpoint B.ckpt \
        --max-residual-mm 1.0 0.5 --out /tmp/contrafeat_eval.md

Findings so far: docs/lab_notes/2026-11-22-contrafeat-precision.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from benchmarks.common import contrafeat as cf
from benchmarks.common.report import Report
from c3f_models.contrafeat.module import ContraFeat


def load(ckpt: Path, residual_m: float) -> tuple[ContraFeat, int]:
    """The small-configuration model with the checkpoint's weights and the given kpf residual."""
    overrides = {"max_residual": residual_m, "pairwise_tolerance": 2 * residual_m}
    model = ContraFeat(**{**cf.SMALL_MODEL, "evaluation": {**cf.SMALL_MODEL["evaluation"],
                                                           "filter_overrides": overrides}})
    steps = cf.load_weights(model, ckpt)
    return model.eval(), steps


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="folder of held-out sequences (DIR/<seq>/rgb, ...)")
    ap.add_argument("--seqs", nargs="+", default=None, help="sequence names inside --data (default: all)")
    ap.add_argument("--checkpoint", type=Path, action="append", required=True, help="repeat for several")
    ap.add_argument("--max-residual-mm", type=float, nargs="+", default=[1.0],
                    help="kpf residual thresholds, millimetres (1.0 = the colon's MatchFilterConfig)")
    ap.add_argument("--size", type=int, default=128, help="frame size (square), pixels")
    ap.add_argument("--eval-gaps", type=int, nargs="+", default=[2, 4, 8], help="evaluation frame gaps")
    ap.add_argument("--eval-stride", type=int, default=3, help="evaluate every n-th pair of each gap")
    ap.add_argument("--eval-batches", type=int, default=None, help="cap on evaluation batches per sequence")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    ap.add_argument("--out", type=Path, required=True, help="markdown report (written atomically)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    if not args.data.is_dir():
        raise SystemExit(f"--data: no such folder: {args.data}")
    seqs = args.seqs or sorted(p.name for p in args.data.iterdir() if (p / "rgb").is_dir())
    missing = [s for s in seqs if not (args.data / s / "rgb").is_dir()]
    if not seqs or missing:
        raise SystemExit(f"--data: no sequence folders {missing or ''} in {args.data}")
    if any(r <= 0 for r in args.max_residual_mm):
        raise SystemExit(f"--max-residual-mm must be positive, got {args.max_residual_mm}")

    t0 = time.time()
    pairs = cf.PairSelection.from_args(args)
    lines = [(f"Sequences: {', '.join(seqs)} in `{args.data}`; pairs at gaps {args.eval_gaps} (one "
             f"pair in {args.eval_stride} of each gap), {args.size}x{args.size}, "
             "mutual nearest neighbours without ratio test, "
             f"correctness radius {cf.GROUND_TRUTH['pixel_radius']:g} px, kpf on ground-truth depth. "
             "Recall/precision %, averaged over the sequences."), ""]
    for ckpt in args.checkpoint:
        for r_mm in args.max_residual_mm:
            model, steps = load(ckpt, r_mm * 1e-3)
            res = cf.metrics_per_sequence(model, args.data, seqs, pairs)
            lines += [f"## `{ckpt}` ({steps} steps), kpf residual {r_mm:g} mm", "", *cf.recall_precision_table(res), "",
                      *cf.wrong_match_table(res), ""]
            print(f"{ckpt} residual {r_mm:g} mm done ({time.time() - t0:.0f} s)", flush=True)
    lines.append(f"Wall time {(time.time() - t0) / 60:.1f} min, {args.threads} torch thread(s).")
    report = Report(__file__, "ContraFeat checkpoints on held-out sequences", argv)
    text = report.render(lines)
    report.write(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
