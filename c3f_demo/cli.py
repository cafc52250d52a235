"""``python -m c3f_demo --out DIR [--quick] [--overwrite]``: the whole pipeline in one command;
``python -m c3f_demo --video FILE [--camera camera.json | --fov DEG] --out DIR``: the same on a
user's own recording (docs/own_video.md), with a report that needs no ground truth.

Exit status: 0 done, 1 a stage's command failed (its error line and log named), 2 bad input
(e.g. DIR holds a demo made with other settings, a video without intrinsics), 130 Ctrl-C (or
SIGTERM / SIGHUP: the running commands get one SIGINT each and are waited for). Always one line
on error.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError
from c3f_demo.config import DemoConfig, demo_config, video_config


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(
        prog="python -m c3f_demo",
        description="Simulate a colon sequence, start from the zoo's DepthNet and ContraFeat (or train them: "
                    "--from-scratch), test-time train DepthNet on the held-out sequence, export, run SLAM on it "
                    "(4 configurations), evaluate, write DIR/report.html. With --video: the same on your own "
                    "recording (no ground truth: its frames, test-time training on them, SLAM with and without it, "
                    "the 3D views, a report without the ground-truth sections). Rerunning into the same "
                    "DIR skips the stages already done with the same settings.")
    ap.add_argument("--out", type=Path, required=True, help="demo folder (created; every artefact goes here)")
    ap.add_argument("--quick", action="store_true", help="a few minutes instead of about 10 (CI size)")
    ap.add_argument("--from-scratch", action="store_true",
                    help="train DepthNet and ContraFeat first (minutes, CPU size) instead of starting from the zoo's "
                         "models (zoo/)")
    ap.add_argument("--overwrite", action="store_true",
                    help="redo stages recorded in DIR with other settings (and the stages after them)")
    ap.add_argument("--video", type=Path,
                    help="your own colonoscopy video instead of the simulator (docs/own_video.md)")
    lens = ap.add_mutually_exclusive_group()
    lens.add_argument("--camera", type=Path, help="with --video: its camera.json (default: camera.json beside the "
                                                  "video; make one with `python -m c3f_slam calibrate`)")
    lens.add_argument("--fov", type=float, metavar="DEG",
                      help="with --video and no calibration: guess a pinhole camera of DEG degrees horizontal field "
                           "of view")
    return ap


def config_of(args: argparse.Namespace) -> DemoConfig:
    """The settings the options ask for; InputError for options that do not go together. A video's
    camera.json is the one given, else the one beside the video when there is one."""
    if args.video is None:
        if args.camera is not None or args.fov is not None:
            raise InputError("--camera and --fov are options of --video")
        return demo_config(args.quick, args.from_scratch)
    if args.from_scratch:
        raise InputError("--from-scratch does not go with --video (a video starts from the zoo's models)")
    video = args.video.resolve()
    beside = video.parent / "camera.json"
    camera = args.camera.resolve() if args.camera else beside if args.fov is None and beside.is_file() else None
    return video_config(str(video), str(camera) if camera else None, args.fov, args.quick)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    # the stages (OpenCV, Open3D, onnxruntime): only once the arguments parsed (--help needs none)
    from c3f_demo.runner import DemoInterrupted, StageFailed, run_demo
    from c3f_demo.video import check_video

    # SIGTERM and SIGHUP (the terminal closed) stop the demo like Ctrl-C; restored on return
    previous = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        cfg = config_of(args)
        if cfg.video is not None:
            check_video(cfg.video)
        run_demo(args.out.resolve(), cfg, overwrite=args.overwrite)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except StageFailed as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (DemoInterrupted, KeyboardInterrupt) as exc:
        print(f"error: {exc or 'interrupted'}", file=sys.stderr)
        return 130
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
