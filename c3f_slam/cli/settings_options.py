"""The settings options of ``python -m c3f_slam run`` (and ``batch``): ``--preset``, ``--config``,
``--set``, ``--print-config``.

Defaults, ranges and meanings live only in the dataclasses (:mod:`c3f_slam.config`);
``--print-config`` shows them. The older tuning flags that were aliases of ``--set`` are gone
(:data:`REMOVED`): giving one is a usage error, one ``error: --FLAG was removed: use --set ...``
line and exit status 2, and ``--help`` no longer lists them.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from c3f_core.settings_cli import add_settings_options as add_settings_options_of
from c3f_slam.config import PAPER_RULES
from c3f_slam.config.loading import SLAM_SETTINGS


def _sets(*items: str) -> str:
    return " ".join(f"--set {item}" for item in items)


def _paper_rules() -> list[str]:
    def text(v: Any) -> str:
        return "none" if v is None else str(v).lower() if isinstance(v, bool) else str(v)

    return [f"{part}.{name}={text(v)}" for part, fs in PAPER_RULES.items() for name, v in fs.items()]


def _switch(flag: str, path: str) -> dict[str, str]:
    return {flag: _sets(f"{path}=true"), f"--no-{flag[2:]}": _sets(f"{path}=false")}


#: the former tuning flags (aliases of ``--set`` until they were removed): the flag as it was
#: given (with its value's form) -> what replaces it
REMOVED: dict[str, str] = {
    "--baseline odometry": _sets("mode=odometry"),
    "--stride K": _sets("frames.stride=K"),
    "--max-frames N": _sets("frames.max_frames=N"),
    "--no-mesh": _sets("fusion.enabled=false"),
    "--no-coverage": _sets("coverage.enabled=false"),
    "--coverage-segment M": _sets("coverage.segment=M"),
    "--min-correspondences N": _sets("fragments.min_correspondences=N"),
    "--min-overlap X": _sets("fragments.min_overlap=X"),
    "--max-keypoints N": _sets("frontend.max_keypoints=N", "keyframes.keypoints=N"),
    "--ratio R": _sets("frontend.ratio=R") + "; for --ratio 0, " + _sets("frontend.ratio=none"),
    "--max-keyframe-candidates N": _sets("candidates.max_candidates=N") + "; for --max-keyframe-candidates 0 "
                                   "(the paper's rules), " + _sets(*_paper_rules()),
    "--max-loop-edges-per-keyframe N": _sets("keyframes.max_loop_edges=N") + "; for 0 (all), "
                                       + _sets("keyframes.max_loop_edges=none"),
    **_switch("--reuse-keyframes", "keyframes.reuse"),
    **_switch("--dense-fallback", "fallback.dense"),
    **_switch("--dense-refine", "refine.enabled"),
    **_switch("--guided-matching", "fallback.guided"),
    "--component-min-frames N": _sets("components.min_frames=N") + " (0 = none, also for a negative N)",
    "--blas-threads N": _sets("blas_threads=N") + "; for --blas-threads 0 (the BLAS library's setting), "
                        + _sets("blas_threads=none"),
}


def removed_message(usage: str) -> str:
    """The one line for the removed flag ``usage`` (a key of :data:`REMOVED`)."""
    return f"{usage} was removed: use {REMOVED[usage]}"


class _Removed(argparse.Action):
    """A removed flag (hidden from ``--help``): one ``error:`` line naming its replacement, exit status 2."""

    def __init__(self, option_strings: Sequence[str], dest: str, usage: str = "", **kw: Any) -> None:
        self.usage = usage
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        parser.error(removed_message(self.usage))


def add_settings_options(r: argparse.ArgumentParser) -> None:
    """``--preset``, ``--config``, ``--set``, ``--print-config`` on the run (or batch) parser (the
    options of every command, :func:`c3f_core.settings_cli.add_settings_options`), and the removed
    flags as hidden options that say what replaces them."""
    add_settings_options_of(r, SLAM_SETTINGS, example="fragments.min_overlap=0.8 --set fusion.tsdf.voxel_size=0.002",
                            replay="a previous run's summary.json (or a batch's batch.json)")
    for usage in REMOVED:
        flag, _, value = usage.partition(" ")
        r.add_argument(flag, action=_Removed, usage=usage, nargs="?" if value else 0, dest=argparse.SUPPRESS,
                       default=argparse.SUPPRESS, help=argparse.SUPPRESS)


__all__ = ["REMOVED", "add_settings_options", "removed_message"]
