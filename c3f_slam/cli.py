"""Command line of the SLAM runtime.

    python -m c3f_slam run SEQUENCE_DIR --depth-source files --descriptors sift --out OUT
        [--preset colon|room] [--baseline odometry] [--max-frames N] [--stride K] [--no-mesh]
    python -m c3f_slam evaluate OUT --gt SEQUENCE_DIR

Bad input prints one line ``error: <message>`` and exits with status 2; the outputs so far
(summary.json with the error, trajectory) are still written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from c3f_slam.errors import InputError


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m c3f_slam", description="C3Fusion SLAM runtime")
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run SLAM on a sequence folder and write trajectory, mesh, graph, summary")
    r.add_argument("sequence", help="sequence folder (rgb/, depth/, camera.json)")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--depth-source", default="files", choices=("files", "model"),
                   help="files: depth/ of the sequence (RGB-D mode); model: DepthNet ONNX (--depth-model)")
    r.add_argument("--descriptors", default="sift", choices=("sift", "contrafeat"),
                   help="sift (the SIFT baseline) or contrafeat (ONNX, --feature-model)")
    r.add_argument("--depth-model", help="DepthNet ONNX file (not available yet)")
    r.add_argument("--feature-model", help="ContraFeat ONNX file (not available yet)")
    r.add_argument("--preset", default="colon", choices=("colon", "room"), help="scene scale of the thresholds")
    r.add_argument("--baseline", choices=("odometry",), help="frame-to-frame odometry only (no fragments/loops)")
    r.add_argument("--max-frames", type=int, help="process at most N frames")
    r.add_argument("--stride", type=int, default=1, help="use every K-th frame")
    r.add_argument("--no-mesh", action="store_true", help="skip TSDF fusion")
    r.add_argument("--min-correspondences", type=int,
                   help="new fragment below this many consecutive correspondences (paper: 100)")
    r.add_argument("--min-overlap", type=float, help="new fragment below this frustum overlap (paper: 0.85)")
    r.add_argument("--max-keypoints", type=int, help="SIFT keypoints per frame (default 1000)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    e = sub.add_parser("evaluate", help="ATE / RPE / registered share / coverage of a run against ground truth")
    e.add_argument("out", help="run folder (trajectory.txt, summary.json, mesh.ply)")
    e.add_argument("--gt", required=True, help="ground-truth sequence folder (poses.txt, optional mesh.ply)")
    return ap


def _run(args: argparse.Namespace) -> int:
    from c3f_slam.pipeline import SlamConfig, run_slam

    if args.stride < 1:
        raise InputError(f"--stride must be >= 1, got {args.stride}")
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {args.max_frames}")
    over = {}
    if args.min_correspondences is not None:
        over["min_consecutive_correspondences"] = args.min_correspondences
    if args.min_overlap is not None:
        over["min_overlap"] = args.min_overlap
    if args.max_keypoints is not None:
        over["max_keypoints"] = over["keyframe_keypoints"] = args.max_keypoints
    cfg = SlamConfig.preset_config(args.preset, mode=args.baseline or "full", fuse=not args.no_mesh, **over)
    s = run_slam(args.sequence, args.out, cfg, args.descriptors, args.depth_source, args.depth_model,
                 args.feature_model, args.max_frames, args.stride, progress=not args.quiet)
    fps = s["timings"]["total"]["frames_per_second"]
    print(f"{s['frames']} frames, {s['registered_frames']} registered ({100 * s['registered_share']:.1f} %), "
          f"{s.get('fragments', 0)} fragments, {s.get('loop_edges', 0)} loop edges, "
          f"{s.get('pruned_edges', 0)} pruned, {fps or 0:.1f} frames/s -> {args.out}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from c3f_slam.pipeline.evaluation import evaluate_run, format_report

    res = evaluate_run(args.out, args.gt)
    print(format_report(res))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return _run(args) if args.command == "run" else _evaluate(args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
