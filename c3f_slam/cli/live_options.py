"""The options of ``python -m c3f_slam live`` that are not ``run``'s: the page's address, the
source's pacing and the alert (:class:`c3f_slam.live.settings.LiveSettings`, where their
defaults are)."""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path

from c3f_slam.live.settings import LiveSettings

_DEFAULTS = {f.name: f.default for f in fields(LiveSettings)}


def add_live_options(r: argparse.ArgumentParser) -> None:
    d = _DEFAULTS
    r.add_argument("--host", help=f"address the page is served on (default {d['host']}: this machine only; "
                                  "another address exposes the page, without any authentication, to that network)")
    r.add_argument("--port", type=int, help=f"port of the page (default {d['port']}; 0: any free port)")
    pace = r.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, metavar="FPS",
                      help="frames per second the source delivers (default: a video's own rate, a sequence folder's "
                           "poses.txt timestamps, else 30; a capture device delivers as it captures)")
    pace.add_argument("--as-fast-as-possible", action="store_true",
                      help="no pacing: frames are delivered as fast as they are read (tests, benchmarks); frames "
                           "the run cannot take in time are still dropped")
    r.add_argument("--keep-every-frame", action="store_true",
                   help="never drop a frame: when processing is slower than the source, the run falls behind it "
                        "and the delay grows (a recording reviewed whole, not a live capture)")
    r.add_argument("--alert-threshold", type=float, metavar="SHARE",
                   help=f"alert when the scope leaves a segment with more unseen wall than this share "
                        f"(default {d['alert_threshold']})")
    r.add_argument("--alert-margin", type=float, metavar="METRES",
                   help=f"the scope has left a segment once this far beyond its ends (default {d['alert_margin']})")
    r.add_argument("--linger", type=float, metavar="SECONDS",
                   help=f"seconds the page keeps showing the final state after the run ends (default "
                        f"{d['linger']:g}; Ctrl-C ends it)")


def live_settings_from_args(args: argparse.Namespace) -> LiveSettings:
    """The :class:`LiveSettings` of the options given (the others at their defaults)."""
    given = {name: getattr(args, name) for name in ("host", "port", "rate", "alert_threshold", "alert_margin",
                                                     "linger") if getattr(args, name) is not None}
    return LiveSettings(as_fast_as_possible=args.as_fast_as_possible, keep_every_frame=args.keep_every_frame, **given)


def live_source(source: str) -> str | Path | int:
    """A capture device's index (digits that name no file or folder), else the path."""
    return int(source) if source.isdigit() and not Path(source).exists() else source
