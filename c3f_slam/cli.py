"""Command line of the SLAM runtime.

    python -m c3f_slam run SEQUENCE_DIR --depth-source files --descriptors sift --out OUT
        [--preset colon|room] [--baseline odometry] [--max-frames N] [--stride K] [--no-mesh]
        [--no-coverage] [--coverage-segment METRES]
    python -m c3f_slam run SEQUENCE_DIR|VIDEO --depth-model depth.onnx --feature-model feat.onnx --out OUT
        [--camera camera.json] [--threads N]
    python -m c3f_slam evaluate OUT --gt SEQUENCE_DIR
    python -m c3f_slam inspect MODEL.onnx
    python -m c3f_slam simcol3d SEQUENCE_DIR --depth-model depth.onnx --out SUBMISSION/SCENE/Frames_X_OP
        [--trajectory OUT/trajectory.txt] [--depth-scale F] [--threads N]

``--depth-source`` / ``--descriptors`` default to the models given: model depth with
``--depth-model``, ContraFeat with ``--feature-model``, else files and SIFT.

Bad input prints one line ``error: <message>`` and exits with status 2; the outputs so far
(summary.json with the error, trajectory) are still written.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from c3f_slam.cli_parser import OneLineParser, run_subcommand
from c3f_slam.errors import InputError


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m c3f_slam", description="C3Fusion SLAM runtime")
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run SLAM on a sequence folder and write trajectory, mesh, graph, summary")
    r.add_argument("sequence", help="sequence folder (rgb/, depth/, camera.json), or a video with --depth-model")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--depth-source", choices=("files", "model"),
                   help="files: depth/ of the sequence (RGB-D mode); model: DepthNet ONNX (--depth-model). "
                        "Default: model when --depth-model is given, else files")
    r.add_argument("--descriptors", choices=("sift", "contrafeat"),
                   help="sift (the SIFT baseline) or contrafeat (ONNX, --feature-model). "
                        "Default: contrafeat when --feature-model is given, else sift")
    r.add_argument("--depth-model", help="DepthNet ONNX export (see `python -m c3f_slam inspect`), or zoo:NAME "
                                         "(a model of the repository's zoo/, `python -m c3f_models zoo list`)")
    r.add_argument("--feature-model", help="ContraFeat ONNX export (descriptors at the SIFT keypoints), or zoo:NAME")
    r.add_argument("--camera", help="camera.json of a video (default: camera.json beside the video)")
    r.add_argument("--threads", type=int, default=2, help="onnxruntime threads per model (default 2)")
    r.add_argument("--depth-scale", type=float,
                   help="multiply the --depth-model depth by this factor (self-supervised depth is known up to "
                        "a scale, the thresholds are in metres); default: the factor the exporter measured on the "
                        "training data (metadata depth.metric_scale), else 1")
    r.add_argument("--preset", default="colon", choices=("colon", "room"), help="scene scale of the thresholds")
    r.add_argument("--baseline", choices=("odometry",), help="frame-to-frame odometry only (no fragments/loops)")
    r.add_argument("--max-frames", type=int, help="process at most N frames")
    r.add_argument("--stride", type=int, default=1, help="use every K-th frame")
    r.add_argument("--no-mesh", action="store_true", help="skip TSDF fusion (and so the unseen-surface estimate)")
    r.add_argument("--no-coverage", action="store_true",
                   help="skip the unseen-surface estimate (coverage.json, coverage_map.png, unseen.ply)")
    r.add_argument("--coverage-segment", type=float, metavar="METRES",
                   help="segment length along the centreline for the per-segment unseen shares (default 0.05)")
    r.add_argument("--min-correspondences", type=int,
                   help="new fragment below this many consecutive correspondences (default: the paper's 100 at "
                        "512x512 scaled with the frame's pixel count, at least 15: 15 at 128 px, 25 at 256 px)")
    r.add_argument("--min-overlap", type=float, help="new fragment below this frustum overlap (paper: 0.85)")
    r.add_argument("--max-keypoints", type=int, help="SIFT keypoints per frame (default 1000)")
    r.add_argument("--ratio", type=float,
                   help="ratio test on top of mutual nearest neighbours (best / second-best L2 distance, of unit "
                        "vectors for ContraFeat; default 0.9); 0 = off")
    r.add_argument("--max-keyframe-candidates", type=int,
                   help="match a new keyframe against at most N earlier keyframes (recent, nearby, by appearance; "
                        "default 24); 0 = all keyframes and whole-component optimisation after every loop "
                        "(the paper's rules, quadratic on long sequences; also no --reuse-keyframes)")
    r.add_argument("--max-loop-edges-per-keyframe", type=int,
                   help="keep at most N keyframe-match (loop) edges per new keyframe: the most recent, then the "
                        "strongest (default 8); 0 = all (the paper; also implied by --max-keyframe-candidates 0)")
    r.add_argument("--reuse-keyframes", action=argparse.BooleanOptionalAction, default=None,
                   help="hang a fragment that revisits a mapped place off that place's keyframe instead of adding a "
                        "keyframe (memory stays flat on long revisiting streams; SlamConfig.reuse_keyframes)")
    r.add_argument("--dense-fallback", action=argparse.BooleanOptionalAction, default=None,
                   help="where sparse matching to the previous frame fails, align the two frames densely (Open3D "
                        "RGB-D odometry, verified on its residuals) and add a low-trust, prunable fallback edge "
                        "(default off: inaccurate on the simulator's colon frames; SlamConfig.fallback.dense)")
    r.add_argument("--dense-refine", action=argparse.BooleanOptionalAction, default=None,
                   help="refine each new keyframe's edges to recent keyframes with Open3D's coloured ICP (multi-scale, "
                        "from the sparse estimate, verified; rejected ones stay sparse; SlamConfig.refine.enabled; "
                        "default off, see benchmarks/results/slam_dense_refine.md)")
    r.add_argument("--guided-matching", action=argparse.BooleanOptionalAction, default=None,
                   help="where sparse matching to the previous frame fails, match again near where the last "
                        "motion puts each keypoint (default on; SlamConfig.fallback.guided)")
    r.add_argument("--component-min-frames", type=int,
                   help="every component of the map that could not be joined to the main map and has at least N "
                        "registered frames gets its own trajectory and mesh in OUT/components/NN/ (the 8 largest; "
                        "default 30); 0 or negative = none")
    r.add_argument("--blas-threads", type=int,
                   help="BLAS threads NumPy may use during the run (default 1: the runtime's matrices are small); "
                        "0 = the BLAS library's own setting")
    r.add_argument("--max-bad-frames", type=int, default=10,
                   help="unreadable frames (missing or corrupt files, undecodable video frames) skipped and counted "
                        "(summary.json skipped_unreadable); one more fails the run (default 10)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace a complete earlier run in --out (an incomplete one is always replaced)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    e = sub.add_parser("evaluate", help="ATE / RPE / registered share / coverage of a run against ground truth")
    e.add_argument("out", help="run folder (trajectory.txt, summary.json, mesh.ply)")
    e.add_argument("--gt", required=True, help="ground-truth sequence folder (poses.txt, optional mesh.ply)")
    i = sub.add_parser("inspect", help="print the metadata of an exported ONNX model (kind, size, units, ...)")
    i.add_argument("model", help="an .onnx file written by the C3Fusion exporter")
    c = sub.add_parser("simcol3d", help="write a sequence's depth (and relative poses) as SimCol3D challenge "
                                        "submission files (c3f_slam.simcol3d)")
    c.add_argument("sequence", help="sequence folder (rgb/, camera.json), e.g. a SimCol3D one made by "
                                    "`python -m datamodules convert simcol3d`")
    c.add_argument("--out", required=True,
                   help="the trajectory's submission folder, e.g. SUBMISSION/SyntheticColon_I_Test/Frames_S5_OP: "
                        "gets depth/FrameBuffer_NNNN.npy and pose/FrameBuffer_NNNN_to_FrameBuffer_MMMM.txt")
    c.add_argument("--depth-model", help="DepthNet ONNX export (see `python -m c3f_slam inspect`), or zoo:NAME "
                                         "(a model of the repository's zoo/, `python -m c3f_models zoo list`)")
    c.add_argument("--depth-scale", type=float,
                   help="multiply the model's depth by this factor (the files hold 0-20 cm, clipped); default: "
                        "the model's metadata depth.metric_scale, else 1")
    c.add_argument("--trajectory", help="TUM camera-to-world trajectory in metres (a run's trajectory.txt): "
                                        "relative poses of every consecutive frame pair, missing frames interpolated")
    c.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def _overrides(args: argparse.Namespace) -> dict:
    """SlamConfig overrides (parts as dicts) of the run command's tuning options."""
    from c3f_slam.pipeline import PAPER_RULES

    over: dict[str, dict] = {"fragments": {}, "frontend": {}, "keyframes": {}, "candidates": {}, "coverage": {}}
    if args.no_coverage:
        over["coverage"]["enabled"] = False
    if args.coverage_segment is not None:
        _check(args.coverage_segment > 0, f"--coverage-segment must be > 0 (metres), got {args.coverage_segment}")
        over["coverage"]["segment"] = args.coverage_segment
    if args.min_correspondences is not None:
        over["fragments"]["min_correspondences"] = args.min_correspondences
    if args.min_overlap is not None:
        over["fragments"]["min_overlap"] = args.min_overlap
    if args.max_keypoints is not None:
        over["frontend"]["max_keypoints"] = over["keyframes"]["keypoints"] = args.max_keypoints
    if args.ratio is not None:
        _check(0 <= args.ratio <= 1, f"--ratio must be in [0, 1] (0 = off), got {args.ratio}")
        over["frontend"]["ratio"] = args.ratio or None
    if args.max_keyframe_candidates is not None:
        _check(args.max_keyframe_candidates >= 0,
               f"--max-keyframe-candidates must be >= 0, got {args.max_keyframe_candidates}")
        if args.max_keyframe_candidates == 0:
            for part, fields in PAPER_RULES.items():
                over.setdefault(part, {}).update(fields)
        else:
            over["candidates"]["max_candidates"] = args.max_keyframe_candidates
    if args.max_loop_edges_per_keyframe is not None:
        _check(args.max_loop_edges_per_keyframe >= 0,
               f"--max-loop-edges-per-keyframe must be >= 0, got {args.max_loop_edges_per_keyframe}")
        over["keyframes"]["max_loop_edges"] = args.max_loop_edges_per_keyframe or None
    if args.reuse_keyframes is not None:
        over["keyframes"]["reuse"] = args.reuse_keyframes
    if args.dense_fallback is not None:
        over.setdefault("fallback", {})["dense"] = args.dense_fallback
    if args.dense_refine is not None:
        over["refine"] = {"enabled": args.dense_refine}
    if args.guided_matching is not None:
        over.setdefault("fallback", {})["guided"] = args.guided_matching
    if args.component_min_frames is not None:
        over["components"] = {"min_frames": max(args.component_min_frames, 0)}
    out: dict = {part: fields for part, fields in over.items() if fields}
    if args.blas_threads is not None:
        _check(args.blas_threads >= 0, f"--blas-threads must be >= 0, got {args.blas_threads}")
        out["blas_threads"] = args.blas_threads or None
    return out


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(message)


def _run(args: argparse.Namespace) -> int:
    from c3f_slam.pipeline import RunInputs, SlamConfig, run_slam

    _check(args.stride >= 1, f"--stride must be >= 1, got {args.stride}")
    _check(args.max_frames is None or args.max_frames >= 1, f"--max-frames must be >= 1, got {args.max_frames}")
    _check(args.threads >= 1, f"--threads must be >= 1, got {args.threads}")
    cfg = SlamConfig.preset_config(args.preset, mode=args.baseline or "full", fusion={"enabled": not args.no_mesh},
                                   **_overrides(args))
    inputs = RunInputs(args.descriptors, args.depth_source, args.depth_model, args.feature_model, args.camera,
                       args.threads, args.depth_scale, args.max_bad_frames)
    s = run_slam(args.sequence, args.out, cfg, inputs, max_frames=args.max_frames, stride=args.stride,
                 progress=not args.quiet, overwrite=args.overwrite)
    fps = s["timings"]["total"]["frames_per_second"]
    unseen = s.get("unseen_share")
    print(f"{s['frames']} frames, {s['registered_frames']} registered ({100 * s['registered_share']:.1f} %), "
          f"{s.get('fragments', 0)} fragments, {s.get('loop_edges', 0)} loop edges, "
          f"{s.get('pruned_edges', 0)} pruned, {fps or 0:.1f} frames/s"
          + (f", unseen wall {100 * unseen:.1f} %" if unseen is not None else "") + f" -> {args.out}")
    written = [c for c in s.get("components", []) if not c["main"] and c["files"]]
    if written:
        print(f"{len(written)} part(s) not joined to the main map written to {args.out}/components/: "
              + ", ".join(f"{c['id']:02d} ({c['frames']} frames, {c['first_frame']}-{c['last_frame']})"
                          for c in written))
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from c3f_slam.pipeline.run_evaluation import evaluate_run, format_report

    res = evaluate_run(args.out, args.gt)
    print(format_report(res))
    return 0


def _inspect(args: argparse.Namespace) -> int:
    from c3f_slam.models import OnnxModel, format_metadata

    model = OnnxModel(args.model, threads=1, option=None)
    print(format_metadata(model.metadata, str(args.model)))
    return 0


def _simcol3d(args: argparse.Namespace) -> int:
    from c3f_slam.simcol3d import write_submission

    r = write_submission(args.sequence, args.out, args.depth_model, threads=args.threads,
                         depth_scale=args.depth_scale, trajectory=args.trajectory, progress=not args.quiet)
    parts = []
    if args.depth_model:
        parts.append(f"{r['depth_files']} depth maps (x{r['depth_scale']:g}) -> {args.out}/depth")
    if args.trajectory:
        filled = f", {r['filled_poses']} frame(s) without a pose interpolated" if r["filled_poses"] else ""
        parts.append(f"{r['pose_files']} relative poses -> {args.out}/pose{filled}")
    print(f"{r['frames']} frames: " + "; ".join(parts))
    return 0


COMMANDS = {"run": _run, "evaluate": _evaluate, "inspect": _inspect, "simcol3d": _simcol3d}


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    where = f"; the run so far is in {args.out} (summary.json status error)" if args.command == "run" else ""
    return run_subcommand(COMMANDS, args, where)
