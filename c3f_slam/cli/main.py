"""Command line of the SLAM runtime.

    python -m c3f_slam run SEQUENCE_DIR --out OUT [--depth-source files] [--descriptors sift]
        [--preset colon|room] [--config FILE|OLD_OUT/summary.json] [--set part.field=value ...]
    python -m c3f_slam run SEQUENCE_DIR|VIDEO --depth-model depth.onnx --feature-model feat.onnx --out OUT
        [--camera camera.json | --fov DEG] [--threads N] [--providers CUDAExecutionProvider,CPUExecutionProvider]
    python -m c3f_slam run [--preset room] [--config FILE] [--set ...] --print-config
    python -m c3f_slam live VIDEO|SEQUENCE_DIR|DEVICE --out OUT [the options of run] [--port N] [--host ADDRESS]
        [--rate FPS | --as-fast-as-possible] [--alert-threshold SHARE] [--alert-margin METRES] [--linger SECONDS]
    python -m c3f_slam batch DATASET_DIR|LIST_FILE --out OUT [--workers N] [--threads N] [--ray auto|ADDRESS|local]
        [the options of run: models, --preset, --config, --set ...]
    python -m c3f_slam evaluate OUT --gt SEQUENCE_DIR
    python -m c3f_slam inspect MODEL.onnx
    python -m c3f_slam calibrate IMAGE_DIR|VIDEO --out camera.json --board COLSxROWS --square METRES
        [--model pinhole|fisheye] [--every N]
    python -m c3f_slam view OUT [--gt SEQUENCE_DIR] [--sequence SEQ_OR_VIDEO] [--no-video] [--no-open]
        [--config FILE|OUT/view.json] [--set part.field=value ...] [--print-config]
    python -m c3f_slam simcol3d SEQUENCE_DIR --depth-model depth.onnx --out SUBMISSION/SCENE/Frames_X_OP
        [--trajectory OUT/trajectory.txt] [--depth-scale F] [--threads N]

``--depth-source`` / ``--descriptors`` default to the models given: model depth with
``--depth-model``, ContraFeat with ``--feature-model``, else files and SIFT. Every other
setting of a run is one of the settings tree (:mod:`c3f_slam.config`): ``--preset``, then
``--config``, then ``--set`` in order (:mod:`c3f_slam.cli.settings_options`; the older tuning flags
were removed, and giving one names the ``--set`` that replaces it); ``--print-config`` shows
the result.

Bad input prints one line ``error: <message>`` and exits with status 2; the outputs so far
(summary.json with the error, trajectory) are still written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from c3f_core.cli_parser import OneLineParser, run_subcommand
from c3f_core.errors import InputError
from c3f_core.settings_cli import add_settings_options as add_settings_options_of
from c3f_slam.cli.inputs import add_input_options, inputs_from_args, settings_from_args
from c3f_slam.cli.settings_options import add_settings_options
from c3f_slam.view.settings import VIEW_SETTINGS


def _run_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("run", help="run SLAM on a sequence folder and write trajectory, mesh, graph, summary",
                       description="Run SLAM on a sequence folder (rgb/, depth/, camera.json) or a video. Named "
                                   "options are the inputs, outputs and models; every other setting is one of the "
                                   "settings tree (--print-config lists them with their defaults and meanings).")
    r.add_argument("sequence", nargs="?", help="sequence folder (rgb/, depth/, camera.json), or a video with "
                                               "--depth-model")
    r.add_argument("--out", help="output folder (a run folder: built beside it and moved into place)")
    add_input_options(r)
    r.add_argument("--overwrite", action="store_true",
                   help="replace a complete earlier run in --out (an incomplete one is always replaced)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    add_settings_options(r)


def _live_parser(sub: argparse._SubParsersAction) -> None:
    from c3f_slam.cli.live_options import add_live_options

    r = sub.add_parser("live", help="run SLAM on a video, sequence folder or capture device as it plays, with a "
                                    "page that shows the unseen wall (http://127.0.0.1:PORT/)",
                       description="The run of `run`, live: the source is played at its own frame rate (newest "
                                   "frame wins when processing falls behind: the others are dropped and counted), "
                                   "and a page on the loopback address shows the frame, the map so far, the "
                                   "unrolled wall with its unseen cells, the unseen share per segment and an alert "
                                   "when the scope leaves a segment with more unseen wall than the threshold. The "
                                   "run folder is written at the end as `run` writes it, plus live.json. "
                                   "docs/live.md")
    r.add_argument("source", nargs="?", help="a video (with --depth-model), a sequence folder, or a capture device's "
                                             "OpenCV index (0, 1, ...; with --camera or --fov)")
    r.add_argument("--out", help="output folder (a run folder, as `run` writes it)")
    add_input_options(r)
    add_live_options(r)
    r.add_argument("--overwrite", action="store_true",
                   help="replace a complete earlier run in --out (an incomplete one is always replaced)")
    add_settings_options(r)


def _view_parser(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser("view", help="write OUT/view.html (interactive 3D view) and the videos rerender.mp4, "
                                    "flythrough.mp4 of a run folder, and open the page",
                       description="Write an interactive 3D view of a run folder (view.html: one self-contained "
                                   "file, offline) and two videos: the input beside the reconstruction re-rendered "
                                   "from the estimated poses (rerender.mp4) and a fly-through along the smoothed "
                                   "camera path (flythrough.mp4); the settings used go to view.json. Named options "
                                   "are the inputs and switches; the page's budget and the videos' settings are "
                                   "the settings tree (--print-config lists them). docs/view.md")
    v.add_argument("out", nargs="?", help="run folder (summary.json, trajectory.txt, mesh.ply, unseen.ply)")
    v.add_argument("--gt", help="ground-truth sequence folder: its path and surface as layers (default: the one "
                                "`evaluate --gt` recorded in evaluation.json, if any)")
    v.add_argument("--sequence", help="the run's input (sequence folder or video) for rerender.mp4, when it is no "
                                      "longer where summary.json says")
    v.add_argument("--no-video", action="store_true", help="the page alone (no rerender.mp4, flythrough.mp4)")
    v.add_argument("--no-open", action="store_true", help="do not open the page in a browser (never opened "
                                                          "without a display)")
    v.add_argument("--quiet", action="store_true", help="no progress bar")
    add_settings_options_of(v, VIEW_SETTINGS, example="budget.surface=60000 --set flythrough.frames=120",
                            replay="an earlier view's OUT/view.json")


def _calibrate_parser(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("calibrate", help="camera.json of a real camera from checkerboard images or a video",
                       description="Fit a camera's intrinsics and lens distortion to views of a checkerboard "
                                   "(OpenCV) and write them as camera.json for `run --camera`. "
                                   "docs/runtime.md#intrinsics-of-a-real-scope-calibrate-fov-distorted-lenses")
    c.add_argument("input", help="a folder of checkerboard images (.png, .jpg, ...) or a checkerboard video")
    c.add_argument("--out", required=True, help="camera.json to write")
    c.add_argument("--board", required=True, metavar="COLSxROWS",
                   help="inner corners of the board per row x per column, e.g. 9x6 for a board of 10 x 7 squares")
    c.add_argument("--square", required=True, type=float, metavar="METRES", help="side of a board square in metres")
    c.add_argument("--model", default="pinhole", choices=("pinhole", "fisheye"),
                   help="pinhole: k1, k2, p1, p2, k3 (fields of view up to about 120 degrees); fisheye: k1..k4 "
                        "(OpenCV's fisheye model, wider lenses such as colonoscopes); default pinhole")
    c.add_argument("--every", type=int, default=1, metavar="N",
                   help="use every N-th image or video frame (default 1; at most 40 views with the board are fitted, "
                        "evenly spread)")


def _batch_parser(sub: argparse._SubParsersAction) -> None:
    from c3f_slam.batch.cli import add_batch_parser

    add_batch_parser(sub)


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m c3f_slam", description="C3Fusion SLAM runtime")
    sub = ap.add_subparsers(dest="command", required=True)
    _run_parser(sub)
    _live_parser(sub)
    _batch_parser(sub)
    e = sub.add_parser("evaluate", help="ATE / RPE / registered share / coverage of a run against ground truth")
    e.add_argument("out", help="run folder (trajectory.txt, summary.json, mesh.ply)")
    e.add_argument("--gt", required=True, help="ground-truth sequence folder (poses.txt, optional mesh.ply)")
    i = sub.add_parser("inspect", help="print the metadata of an exported ONNX model (kind, size, units, ...)")
    i.add_argument("model", help="an .onnx file written by the C3Fusion exporter")
    _view_parser(sub)
    _calibrate_parser(sub)
    c = sub.add_parser("simcol3d", help="write a sequence's depth (and relative poses) as SimCol3D challenge "
                                        "submission files (c3f_slam.io.simcol3d)")
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


def _warn_replay_inputs(summary: dict, inputs) -> None:
    """One stderr line when a replayed run read its depth or descriptors from other sources."""
    was = {k: summary.get(k) for k in ("depth_source", "descriptors")}
    now = {"depth_source": inputs.depth_source, "descriptors": inputs.descriptors}
    diff = [f"{k} {was[k]} -> {now[k]}" for k in was if was[k] and was[k] != now[k]]
    if diff:
        print(f"warning: --config replays a run with other inputs ({', '.join(diff)}); give the same models "
              "to replay it exactly", file=sys.stderr)


def _settings_or_print(args: argparse.Namespace):
    """The run's settings tree and the replayed summary (``--config``); None after printing the
    tree (``--print-config``)."""
    from c3f_slam.config.loading import config_yaml

    cfg, replayed = settings_from_args(args)
    if args.print_config:
        print(config_yaml(cfg), end="")
        return None
    return cfg, replayed


def _run(args: argparse.Namespace) -> int:
    settings = _settings_or_print(args)
    if settings is None:
        return 0
    cfg, replayed = settings
    from c3f_slam.pipeline import run_slam

    inputs = inputs_from_args(args)
    if replayed is not None:
        _warn_replay_inputs(replayed, inputs.resolved())
    s = run_slam(args.sequence, args.out, cfg, inputs, progress=not args.quiet, overwrite=args.overwrite)
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


def _live(args: argparse.Namespace) -> int:
    from c3f_slam.cli.live_options import live_settings_from_args, live_source

    tree = _settings_or_print(args)
    if tree is None:
        return 0
    cfg, _ = tree
    settings = live_settings_from_args(args)
    from c3f_slam.live.loop import run_live

    s, live = run_live(live_source(args.source), args.out, cfg, inputs_from_args(args), settings,
                       overwrite=args.overwrite)
    rec = s.get("live", {})
    unseen = s.get("unseen_share")
    print(f"{s['frames']} frames taken of {rec.get('frames_delivered', 0)} delivered "
          f"({100 * rec.get('dropped_share', 0):.1f} % dropped), {s['registered_frames']} registered, "
          f"{len(rec.get('alerts', []))} alert(s)"
          + (f", unseen wall {100 * unseen:.1f} %" if unseen is not None else "") + f" -> {args.out}")
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
    from c3f_slam.io.simcol3d import write_submission

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


def _calibrate(args: argparse.Namespace) -> int:
    from c3f_slam.camera.calibration import calibrate_command

    r = calibrate_command(args.input, args.out, args.board, args.square, args.model, args.every)
    cam = r.camera
    print(f"{len(r.views.corners)} views with the board (of {r.views.tried} looked at), RMS reprojection error "
          f"{r.rms:.3f} px: {cam.model} fx {cam.fx:.2f} fy {cam.fy:.2f} cx {cam.cx:.2f} cy {cam.cy:.2f} px, "
          f"distortion {[round(d, 5) for d in cam.distortion]} -> {args.out}")
    if r.rms > 1.0:
        print(f"warning: an RMS error of {r.rms:.2f} px is high (a good calibration is well under 1 px): blurred "
              "views, a board that is not flat, or --model pinhole for a fisheye lens?", file=sys.stderr)
    return 0


def _view(args: argparse.Namespace) -> int:
    settings = VIEW_SETTINGS.from_args(args)
    if args.print_config:
        print(VIEW_SETTINGS.yaml(settings), end="")
        return 0
    if args.out is None:
        raise InputError("view: the following arguments are required: out")
    from c3f_slam.view.command import view_command

    return view_command(args.out, gt=args.gt, sequence=args.sequence, videos=not args.no_video,
                        open_page=not args.no_open, progress=not args.quiet, settings=settings)


def _batch(args: argparse.Namespace) -> int:
    from c3f_slam.batch.cli import batch_command

    return batch_command(args)


COMMANDS = {"run": _run, "live": _live, "batch": _batch, "evaluate": _evaluate, "inspect": _inspect,
            "simcol3d": _simcol3d, "view": _view, "calibrate": _calibrate}


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command in ("run", "live") and not args.print_config:
        first = "sequence" if args.command == "run" else "source"
        missing = [name for name, v in ((first, getattr(args, first)), ("--out", args.out)) if v is None]
        if missing:
            parser.error(f"the following arguments are required: {', '.join(missing)}")
    running = args.command in ("run", "live") and args.out and not args.print_config
    where = f"; the run so far is in {args.out} (summary.json status error)" if running else ""
    return run_subcommand(COMMANDS, args, where)
