"""``python -m c3f_demo --out DIR [--quick] [--from-scratch] [--overwrite]``: the whole pipeline in one
command; ``python -m c3f_demo --video FILE [--camera camera.json | --fov DEG] --out DIR``: the same on a
user's own recording (docs/own_video.md), with a report that needs no ground truth.

Settings (:data:`c3f_demo.config.DEMO_SETTINGS`): ``--preset`` (``--quick`` / ``--from-scratch``
are its shorthands), ``--config FILE`` (e.g. an earlier run's ``DIR/demo_state.json``: replays its
settings), ``--set part.field=value``, ``--print-config`` (the YAML of the settings, then exit).

Exit status: 0 done, 1 a stage's command failed (its error line and log named), 2 bad input
(e.g. DIR holds a demo made with other settings, a video without intrinsics, a bad setting), 130
Ctrl-C (or SIGTERM / SIGHUP: the running commands get one SIGINT each and are waited for). Always
one line on error.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError
from c3f_core.settings_cli import add_settings_options, read_config_file
from c3f_demo.config import DEMO_SETTINGS, DemoConfig, on_video, preset_name


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(
        prog="python -m c3f_demo",
        description="Simulate a colon sequence, start from the zoo's DepthNet and ContraFeat (or train them: "
                    "--from-scratch), test-time train DepthNet on the held-out sequence, export, run SLAM on it "
                    "(4 configurations), evaluate, write DIR/report.html. With --video: the same on your own "
                    "recording (no ground truth: its frames, test-time training on them, SLAM with and without it, "
                    "the 3D views, a report without the ground-truth sections). Rerunning into the same "
                    "DIR skips the stages already done with the same settings.")
    ap.add_argument("--out", type=Path, help="demo folder (created; every artefact goes here; required but "
                                             "with --print-config)")
    ap.add_argument("--quick", action="store_true", help="a few minutes instead of about 10 (CI size): "
                                                         "--preset quick")
    ap.add_argument("--from-scratch", action="store_true",
                    help="train DepthNet and ContraFeat first (minutes, CPU size) instead of starting from the zoo's "
                         "models (zoo/): --preset from-scratch (with --quick: quick-from-scratch)")
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
    add_settings_options(ap, DEMO_SETTINGS, example="ttt.steps=30 --set simulate.test_frames=60",
                         replay="an earlier run's DIR/demo_state.json")
    return ap


def _preset(args: argparse.Namespace) -> str | None:
    """The preset ``--preset`` or its shorthands ``--quick`` / ``--from-scratch`` name (None: neither)."""
    short = preset_name(args.quick, args.from_scratch) if args.quick or args.from_scratch else None
    if short and args.preset and short != args.preset:
        raise InputError(f"--preset {args.preset} contradicts --quick/--from-scratch (they stand for "
                         f"--preset {short}); give one")
    return args.preset or short


def config_of(args: argparse.Namespace) -> DemoConfig:
    """The settings the options ask for: preset, ``--config``, ``--set``, then the input video
    (``--video`` / ``--camera`` / ``--fov`` win over the file's). InputError for options that do not
    go together or a bad setting. A video's camera.json is the one given, else the one beside the
    video when there is one and no intrinsics are set."""
    config = read_config_file(args.config, DEMO_SETTINGS.record_key) if args.config else None
    if args.video is None:
        if args.camera is not None or args.fov is not None:
            raise InputError("--camera and --fov are options of --video")
        return DEMO_SETTINGS.resolve(_preset(args), config, args.set)
    if args.from_scratch:
        raise InputError("--from-scratch does not go with --video (a video starts from the zoo's models)")
    video = str(args.video.resolve())
    lens = ({"camera": str(args.camera.resolve()), "fov": None} if args.camera else
            {"camera": None, "fov": args.fov} if args.fov is not None else {})
    # the presets on this video, so that --set video.FIELD=... has a group to change
    spec = replace(DEMO_SETTINGS, presets={name: (lambda make=make: on_video(make(), video, **lens))
                                           for name, make in DEMO_SETTINGS.presets.items()})
    cfg = spec.resolve(_preset(args), config, args.set)
    base = cfg.video or on_video(cfg, video).video  # a file's "video: null" (a replayed simulator run)
    v = replace(base, path=video, **lens)
    beside = args.video.resolve().parent / "camera.json"
    if v.camera is None and v.fov is None and beside.is_file():
        v = replace(v, camera=str(beside))
    return replace(cfg, simulate=None, video=v)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.out is None and not args.print_config:
        parser.error("the following arguments are required: --out")
    if args.print_config:
        try:
            print(DEMO_SETTINGS.yaml(config_of(args)), end="")
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        return 0
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
