"""``python -m c3f_demo --out DIR [--quick] [--overwrite]``: the whole pipeline in one command.

Exit status: 0 done, 1 a stage's command failed (its error line and log named), 2 bad input
(e.g. DIR holds a demo made with other settings), 130 Ctrl-C (or SIGTERM / SIGHUP: the running
commands get one SIGINT each and are waited for). Always one line on error.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from c3f_demo.config import demo_config
from c3f_slam.errors import InputError


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m c3f_demo",
        description="Simulate a colon sequence, start from the zoo's DepthNet and ContraFeat (or train them: "
                    "--from-scratch), test-time train DepthNet on the held-out sequence, export, run SLAM on it "
                    "(4 configurations), evaluate, write DIR/report.html. Rerunning into the same "
                    "DIR skips the stages already done with the same settings.")
    ap.add_argument("--out", type=Path, required=True, help="demo folder (created; every artefact goes here)")
    ap.add_argument("--quick", action="store_true", help="a few minutes instead of about 10 (CI size)")
    ap.add_argument("--from-scratch", action="store_true",
                    help="train DepthNet and ContraFeat first (minutes, CPU size) instead of starting from the zoo's "
                         "models (zoo/)")
    ap.add_argument("--overwrite", action="store_true",
                    help="redo stages recorded in DIR with other settings (and the stages after them)")
    return ap


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    # the stages (OpenCV, Open3D, onnxruntime): only once the arguments parsed (--help needs none)
    from c3f_demo.runner import DemoInterrupted, StageFailed, run_demo

    # SIGTERM and SIGHUP (the terminal closed) stop the demo like Ctrl-C; restored on return
    previous = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        run_demo(args.out, demo_config(args.quick, args.from_scratch), overwrite=args.overwrite)
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
