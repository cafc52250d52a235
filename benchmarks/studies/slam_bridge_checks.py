"""What the motion bridge's residual checks see: a continuation against a cut.

For each sequence (with poses; depth from a depth model, as the runtime sees it) every
``--step``-th frame i is checked, as the bridge checks it, against frame i-1 moved by the true
velocity of the step before (a continuation: the constant-velocity prediction, its error only
the change of velocity), and against a frame at least ``--min-gap`` frames away moved the same
way (a cut to another view of the same colon). Printed: the percentiles of the share of depth
pixels that land on the other frame's depth (within ``--depth-residual`` of the depth) and of the
intensity RMSE (0..1), per sequence and kind; the numbers go to a JSON file too.

    python -m benchmarks.studies.slam_bridge_checks runs/bench/slam_unseen/seq5_s7610_x1 \\
        runs/bench/slam_unseen/seq1_s7601_x1 runs/bench/slam_unseen/seq3_s7615_x3
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.common import STUDIES
from c3f_slam.geometry import invert_pose
from c3f_slam.io import Sequence
from c3f_slam.io.sequence import read_rgb
from c3f_slam.models.nets import DepthModel
from c3f_slam.models.zoo import resolve
from c3f_slam.pipeline.fallback import RgbdFrame, verify_alignment

PERCENTILES = (5, 50, 95)


def sequence_checks(seq: Sequence, model: DepthModel, *, step: int, min_gap: int, depth_residual: float,
                    seed: int = 0) -> dict[str, np.ndarray]:
    """(inlier share, intensity RMSE) rows of the continuations and the cuts of one sequence."""
    rng = np.random.default_rng(seed)
    frames: dict[int, RgbdFrame] = {}
    scale = model.metric_scale or 1.0

    def frame(i: int) -> RgbdFrame:
        if i not in frames:
            rgb = read_rgb(seq.rgb_paths[i])
            frames[i] = RgbdFrame.from_rgb(rgb, model.predict(rgb, seq.camera) * scale)
        return frames[i]

    P, K, n = seq.poses, seq.camera.K, len(seq.rgb_paths)
    rows: dict[str, list[tuple[float, float]]] = {"continuation": [], "cut": []}
    for i in range(2, n, step):
        velocity = invert_pose(P[i - 2]) @ P[i - 1]  # T_{i-2,i-1}: the step before, as T_prev,cur
        v = verify_alignment(velocity, frame(i - 1), frame(i), K, depth_residual)
        rows["continuation"].append((v.inlier_share, v.photometric_rmse))
        j = int(rng.integers(0, n))
        if abs(j - i) >= min_gap:
            v = verify_alignment(velocity, frame(j), frame(i), K, depth_residual)
            rows["cut"].append((v.inlier_share, v.photometric_rmse))
    return {k: np.array(v, dtype=float).reshape(-1, 2) for k, v in rows.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sequences", nargs="+", type=Path, help="sequence folders with poses.txt")
    ap.add_argument("--depth-model", default="zoo:c3f-depth-r18w32", help="depth ONNX file or zoo:NAME")
    ap.add_argument("--step", type=int, default=3, help="every N-th frame (default 3)")
    ap.add_argument("--min-gap", type=int, default=45, help="frames between a cut's two frames, at least")
    ap.add_argument("--depth-residual", type=float, default=0.05,
                    help="share of the depth a landed pixel may miss by (default 0.05, the runtime's)")
    ap.add_argument("--out", type=Path, default=STUDIES / "slam_bridge_checks.json", help="JSON of the numbers")
    args = ap.parse_args(argv)
    model = DepthModel(resolve(args.depth_model, "depth", "--depth-model"), threads=1)
    out: dict[str, dict] = {}
    for root in args.sequences:
        seq = Sequence(root)
        checks = sequence_checks(seq, model, step=args.step, min_gap=args.min_gap, depth_residual=args.depth_residual)
        out[seq.name] = {}
        for kind, a in checks.items():
            inl, rmse = (np.percentile(a[:, c], PERCENTILES).round(3).tolist() for c in (0, 1))
            out[seq.name][kind] = {"pairs": len(a), "inlier_share": inl, "photometric_rmse": rmse}
            print(f"{seq.name} {kind}: {len(a)} pairs, inlier share p{PERCENTILES} {inl}, "
                  f"intensity RMSE {rmse}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"settings": {k: str(v) for k, v in vars(args).items()}, "sequences": out},
                                   indent=1) + "\n")
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
