"""The settings options of ``python -m c3f_slam run``: ``--config``, ``--set``, ``--print-config``,
and the older tuning flags kept for one release as aliases of ``--set``.

Each alias appends the ``part.field=value`` items it stands for to the same ordered list as
``--set`` (so the last one given wins); its value is checked at once by the settings group it
changes, and a bad one is one ``error: argument --FLAG: ...`` line. Defaults, ranges and meanings
live only in the dataclasses (:mod:`c3f_slam.config`); ``--print-config`` shows them.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

from c3f_slam.config import PAPER_RULES, PRESET_NAMES, PRESETS
from c3f_slam.errors import InputError
from c3f_slam.settings import set_path

ToSets = Callable[[Any], list[str]]


def _paper_rules() -> list[str]:
    def text(v: Any) -> str:
        return "none" if v is None else str(v).lower() if isinstance(v, bool) else str(v)

    return [f"{part}.{name}={text(v)}" for part, fs in PAPER_RULES.items() for name, v in fs.items()]


def _none_if_zero(path: str) -> ToSets:
    return lambda v: [f"{path}={'none' if v == 0 else v}"]


def _to(*paths: str) -> ToSets:
    return lambda v: [f"{p}={v}" for p in paths]


#: (flag, argparse type or None for a switch, what it sets, note); ``--no-X`` switches take False
ALIASES: tuple[tuple[str, Any, ToSets, str], ...] = (
    ("--baseline", "odometry", _to("mode"), "the frame-to-frame odometry baseline"),
    ("--stride", int, _to("frames.stride"), ""),
    ("--max-frames", int, _to("frames.max_frames"), ""),
    ("--no-mesh", None, lambda v: ["fusion.enabled=false"], "no TSDF fusion, so no unseen-wall estimate"),
    ("--no-coverage", None, lambda v: ["coverage.enabled=false"], ""),
    ("--coverage-segment", float, _to("coverage.segment"), "metres"),
    ("--min-correspondences", int, _to("fragments.min_correspondences"), ""),
    ("--min-overlap", float, _to("fragments.min_overlap"), ""),
    ("--max-keypoints", int, _to("frontend.max_keypoints", "keyframes.keypoints"), "both"),
    ("--ratio", float, _none_if_zero("frontend.ratio"), "0 = none"),
    ("--max-keyframe-candidates", int, lambda v: _paper_rules() if v == 0 else [f"candidates.max_candidates={v}"],
     "0 = the paper's literal rules: --set " + " ".join(_paper_rules())),
    ("--max-loop-edges-per-keyframe", int, _none_if_zero("keyframes.max_loop_edges"), "0 = none: all"),
    ("--reuse-keyframes", bool, _to("keyframes.reuse"), ""),
    ("--dense-fallback", bool, _to("fallback.dense"), ""),
    ("--dense-refine", bool, _to("refine.enabled"), ""),
    ("--guided-matching", bool, _to("fallback.guided"), ""),
    ("--component-min-frames", int, lambda v: [f"components.min_frames={max(v, 0)}"], "negative = 0"),
    ("--blas-threads", int, _none_if_zero("blas_threads"), "0 = none: the BLAS library's setting"),
)


class _SetItems(argparse.Action):
    """Append ``part.field=value`` items to ``namespace.set`` (``--set`` itself, or an alias
    whose ``to_sets`` turns its value into items, each checked against the colon preset)."""

    def __init__(self, option_strings: Sequence[str], dest: str, to_sets: ToSets | None = None,
                 switch: bool = False, **kw: Any) -> None:
        self.to_sets, self.switch = to_sets, switch
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        items = list(getattr(namespace, "set", None) or [])
        if self.to_sets is None:
            items.append(values)
        else:
            if self.switch:  # --X: True, --no-X: False (a --no-... switch alone ignores it)
                values = not (option_string or "").startswith("--no-")
            new = self.to_sets(values)
            for item in new:
                path, _, value = item.partition("=")
                try:
                    set_path(PRESETS["colon"], path, value)
                except InputError as exc:
                    raise argparse.ArgumentError(self, str(exc)) from None
            items.extend(new)
        namespace.set = items


def add_settings_options(r: argparse.ArgumentParser) -> None:
    """``--preset``, ``--config``, ``--set``, ``--print-config`` and the aliases, on the run parser."""
    g = r.add_argument_group("settings (every setting, its default and meaning: --print-config)")
    g.add_argument("--preset", choices=PRESET_NAMES,
                   help="the settings the others start from: colon (millimetre scale, default) or room (centimetre)")
    g.add_argument("--config", metavar="FILE",
                   help="settings file, YAML or JSON (complete or partial, as --print-config writes it), or a "
                        "previous run's summary.json as is: replays that run's settings")
    g.add_argument("--set", action=_SetItems, default=[], metavar="PART.FIELD=VALUE",
                   help="change one setting, e.g. --set fragments.min_overlap=0.8 --set fusion.tsdf.voxel_size=0.002 "
                        "(after --config; repeatable, the last wins)")
    g.add_argument("--print-config", action="store_true",
                   help="print the settings this command line gives (YAML, each with its type and meaning) and exit")
    a = r.add_argument_group("aliases of --set, kept for one release")
    for flag, kind, to_sets, note in ALIASES:
        meta = "N" if kind is int else "X"
        if kind is None or isinstance(kind, str):
            sets = to_sets(kind)
        else:
            sets = [f"{item.partition('=')[0]}={'true|false' if kind is bool else meta}" for item in to_sets(1)]
        text = "--set " + " ".join(sets) + (f" ({note})" if note else "")
        if kind is None:
            a.add_argument(flag, action=_SetItems, nargs=0, to_sets=to_sets, switch=True, dest="set", help=text)
        elif kind is bool:
            a.add_argument(flag, f"--no-{flag[2:]}", action=_SetItems, nargs=0, to_sets=to_sets, switch=True,
                           dest="set", help=text)
        elif isinstance(kind, str):
            a.add_argument(flag, action=_SetItems, choices=(kind,), to_sets=to_sets, dest="set", help=text)
        else:
            a.add_argument(flag, action=_SetItems, type=kind, metavar=meta, to_sets=to_sets, dest="set", help=text)


__all__ = ["ALIASES", "add_settings_options"]
