"""How steady is a depth network's scale from frame to frame, against how far the camera moves?
(outside CI)

A monocular run registers each frame to others by fitting rigid motions to the 3D points of its
matches, so a frame whose whole depth map is 1 % too far looks, along the tube, like a camera
that moved back by 1 % of the depth. For every ``--every``-th frame of each sequence with true
depth and poses this script measures the frame's scale, k = median over pixels of true / predicted
depth (the model's recorded metric scale applied), and reports per sequence

- ``mean`` and ``std`` of k over the frames (%: the scale error of single frames);
- ``change``: |k_j / k_i - 1| between consecutive sampled frames, median and 90th percentile (%);
- ``lag`` correlation of k between frames ``--lag`` apart (how slowly the scale wanders);
- ``wobble / motion``: the median over consecutive sampled pairs of |k_j / k_i - 1| x the median
  true depth of frame i, over the true camera travel between them, and the same over pairs
  ``--lag`` frames apart (the distance of the SLAM's nearer loop edges). Above 1, the apparent
  motion that the scale change alone makes is larger than the real one.

    python -m benchmarks.studies.depth_scale_wobble SEQ [SEQ ...] --depth-model zoo:c3f-depth-r18w32 \
        [--depth-model OTHER.onnx ...] --report /tmp/depth_scale_wobble.md

Findings so far: docs/lab_notes/2026-12-06-depth-scale-wobble.md.

``--slam OUT`` instead runs ``c3f_slam run`` on the one SEQ in model mode with
``--depth-model`` and ``--feature-model``, in this process, with every frame's predicted depth
multiplied by its true k (``--oracle``; without it, unchanged): what the trajectory would be if
the depth's scale did not wobble, its shape errors left as they are.
"""

from __future__ import annotations

import argparse
import hashlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.common import STUDIES
from benchmarks.common.depth_models import add_depth_study_arguments, depth_runs, open_depth_model
from benchmarks.common.report import Report
from c3f_slam.io import Sequence


def frame_scale(true: np.ndarray, pred: np.ndarray) -> tuple[float, float]:
    """(median true / predicted depth, median true depth in metres) over pixels where both are
    positive and finite; (NaN, NaN) without such pixels."""
    t, p = np.asarray(true, np.float64), np.asarray(pred, np.float64)
    ok = np.isfinite(t) & np.isfinite(p) & (t > 0) & (p > 0)
    if not ok.any():
        return float("nan"), float("nan")
    return float(np.median(t[ok] / p[ok])), float(np.median(t[ok]))


def wobble_measures(scales: np.ndarray, depths: np.ndarray, positions: np.ndarray, lag: int) -> dict:
    """The measures of the module docstring from per-frame scales k (F,), median true depths (F,)
    and true camera positions (F, 3) of the sampled frames; ``lag`` in sampled frames."""
    k, z, c = np.asarray(scales, float), np.asarray(depths, float), np.asarray(positions, float)

    def over_motion(gap: int) -> float:
        change = np.abs(k[gap:] / k[:-gap] - 1)
        travel = np.linalg.norm(c[gap:] - c[:-gap], axis=1)
        moving = travel > 0
        return float(np.median(change[moving] * z[:-gap][moving] / travel[moving])) if moving.any() else float("nan")

    change = np.abs(k[1:] / k[:-1] - 1)
    fits = 0 < lag < len(k) - 2
    corr = float(np.corrcoef(k[:-lag], k[lag:])[0, 1]) if fits and np.std(k) > 0 else float("nan")
    return {"frames": len(k), "mean": float(np.mean(k)), "std": float(np.std(k)),
            "change_median": float(np.median(change)), "change_p90": float(np.percentile(change, 90)),
            "lag_corr": corr, "wobble_over_motion": over_motion(1),
            "wobble_over_motion_lag": over_motion(lag) if fits else float("nan")}


def analyse(seq: Sequence, predict: Callable[[int], np.ndarray], every: int, lag: int) -> dict:
    """:func:`wobble_measures` over every ``every``-th frame of ``seq`` (lag in frames)."""
    idx = list(range(0, len(seq), every))
    pairs = [frame_scale(seq.read_depth(i), predict(i)) for i in idx]
    return wobble_measures(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]),
                           seq.poses[idx, :3, 3], max(1, round(lag / every)))


def oracle_slam(seq_dir: Path, depth_model: str, feature_model: str, out: Path, oracle: bool) -> int:
    """``c3f_slam run`` of ``seq_dir`` into ``out`` (in this process), with ``oracle`` the depth
    network's output multiplied, frame by frame, by the frame's true scale k, the frame
    recognised by its network input."""
    from c3f_slam.cli.main import main as slam_main
    from c3f_slam.models import nets

    run = ["run", str(seq_dir), "--depth-model", depth_model, "--feature-model", feature_model, "--quiet",
           "--overwrite", "--out", str(out)]
    if not oracle:
        return slam_main(run)
    seq = Sequence(seq_dir)
    model, metric = open_depth_model(depth_model, 2)

    def key(x: np.ndarray) -> str:
        return hashlib.sha1(np.ascontiguousarray(x, np.float32).tobytes()).hexdigest()

    table = {}
    for i in range(len(seq)):
        x, view = model.prepare(seq.read_rgb(i), seq.camera)
        depth = view.network_to_frame(model.predict_batch(x[None])[0], model.upsample) * metric
        table[key(x)] = frame_scale(seq.read_depth(i), depth)[0]
    plain = nets.DepthModel.predict_batch

    def scaled(self, images: np.ndarray) -> np.ndarray:
        depth = plain(self, images)
        for b in range(len(images)):
            depth[b] *= table[key(images[b])]
        return depth

    nets.DepthModel.predict_batch = scaled
    try:
        return slam_main(run)
    finally:
        nets.DepthModel.predict_batch = plain


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_depth_study_arguments(ap, 2, STUDIES / "depth_scale_wobble.md", "depth/ and poses.txt")
    ap.add_argument("--lag", type=int, default=10, help="frames between the scales correlated")
    ap.add_argument("--slam", type=Path, metavar="OUT", help="run SLAM on the one sequence into OUT instead")
    ap.add_argument("--feature-model", default="zoo:c3f-features-r18w32", help="with --slam")
    ap.add_argument("--oracle", action="store_true", help="with --slam: each frame's depth times its true k")
    args = ap.parse_args()
    if args.every < 1 or args.lag < 1:
        raise SystemExit("--every and --lag must be >= 1")
    if args.slam is not None:
        if len(args.sequences) != 1 or len(args.depth_model) != 1:
            raise SystemExit("--slam takes one sequence and one --depth-model")
        raise SystemExit(oracle_slam(args.sequences[0], args.depth_model[0], args.feature_model, args.slam,
                                     args.oracle))
    rows = []
    for name, path, seq, predict in depth_runs(args.depth_model, args.sequences, args.threads, needs_poses=True):
        r = analyse(seq, predict, args.every, args.lag)
        print(name, path.name, r, flush=True)
        rows.append(f"| {name} | {path.name} | {r['frames']} | {r['mean']:.3f} | {100 * r['std']:.1f} | "
                    f"{100 * r['change_median']:.1f} / {100 * r['change_p90']:.1f} | {r['lag_corr']:.2f} | "
                    f"{r['wobble_over_motion']:.2f} / {r['wobble_over_motion_lag']:.2f} |")
    report = Report(__file__, "How steady is the depth's scale from frame to frame?")
    text = report.render([
        (f"- One frame in {args.every}; k = median over pixels of true / predicted depth (the model's recorded "
         "metric scale applied)."),
        ("- Columns: frames; mean k; its standard deviation over frames (%); |k_j / k_i - 1| between consecutive "
         f"sampled frames, median / 90th percentile (%); correlation of k between frames {args.lag} apart; median "
         "of |k_j / k_i - 1| x the median true depth over the true camera travel between the two frames (above 1: "
         "the scale change alone moves the points more than the camera moved), for consecutive sampled frames / "
         f"frames {args.lag} apart."), "",
        "| depth model | sequence | frames | mean k | std % | change % (median / p90) | correlation "
        "| wobble / motion (next / lag) |",
        "|---|---|---|---|---|---|---|---|",
        *rows])
    report.write(args.report, text)
    print(text)


if __name__ == "__main__":
    main()
