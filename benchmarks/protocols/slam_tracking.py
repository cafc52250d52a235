"""Registered share and ATE at default settings on simulator sequences with events.

For each preset x seed x pace x frame size: generate the sequence (the simulator's events
on), run ``python -m c3f_slam run`` with ground-truth depth and SIFT at **default settings**
(no threshold on the command line; no mesh, for speed) and evaluate: share of the usable
frames in the main map, ATE Sim(3) (cm and % of the ground-truth path length), frames/s,
tracking breaks and how many were re-joined. ``--baseline CHECKOUT`` runs the same with the
code of another checkout (e.g. a git worktree of the commit before the change; one whose
``run`` takes ``--set``), at its defaults (and with ``--set fragments.min_correspondences=15``,
what README used to pass, with ``--set baseline_tuned=true``), side by side.

Pace: the paper's sequences cross the 1.25 m colon in 4,500 frames (~0.28 mm per frame);
pace p travels ``p x frames / 4500`` of it (``path.coverage``). Events are placed per 1000
frames; their ramps keep the simulator's rate limits (``path.max_turn_rate`` 120 deg/s,
``path.max_event_speed`` 6 cm/s at 30 fps; ``--set events=bounded,unbounded`` also runs the
former timing, ramps fixed in frames, close-ups turning up to ~38 deg per frame).
``--set depth_model=MODEL.onnx`` adds a run on predicted depth.

    python -m benchmarks.protocols.slam_tracking --set presets=seq1,seq3,seq2 --set seeds=1,2 \\
        --set paces=1,3 --set frames=1500 --set sizes=128 --baseline /tmp/before

Settings (``--print-config``: each with its default and meaning): :class:`Settings`; ``--baseline``
(a checkout) stays a plain option.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, WORK_HELP, ProtocolCli, check_choices, check_not_empty
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from c3f_slam.evaluation.trajectory import evaluate_trajectory
from c3f_slam.io import Sequence, read_tum
from datamodules.synthetic.generate import read_event_labels

PAPER_FRAMES = 4500  #: frames of the paper's sequences over the whole colon
#: simulator overrides per event timing (setting ``events``)
EVENT_TIMINGS = {"bounded": (), "unbounded": ("path.max_turn_rate=none", "path.max_event_speed=none")}
PRESETS, SEEDS, PACES = ("seq1", "seq3", "seq2"), (1, 2), (1.0, 3.0)  #: the default sequences


@dataclass(frozen=True)
class Variant:
    """One way of running the SLAM CLI: the checkout whose code runs, and extra options."""

    name: str
    checkout: Path
    options: tuple[str, ...] = ()


@dataclass(frozen=True)
class Settings:
    """What slam_tracking measures."""

    presets: tuple[str, ...] = PRESETS  #: simulator presets
    seeds: tuple[int, ...] = SEEDS  #: simulator seeds of each preset
    paces: tuple[float, ...] = PACES  #: motion per frame, multiples of the paper's pace (0.28 mm per frame)
    frames: int = 1500  #: frames per sequence
    sizes: tuple[int, ...] = (128,)  #: square frame sizes, pixels
    #: event timings: bounded (the simulator's event ramps within path.max_turn_rate / max_event_speed,
    #: its defaults), unbounded (ramps fixed in frames: the simulator before the bounds)
    events: tuple[str, ...] = ("bounded",)
    #: also run the baseline (--baseline) with --set fragments.min_correspondences=15 (README's former advice)
    baseline_tuned: bool = False
    depth_model: str | None = None  #: DepthNet ONNX export: also run with predicted depth from it

    def __post_init__(self) -> None:
        check_not_empty(self, "presets", "seeds", "paces", "sizes", "events")
        check_choices("events", self.events, sorted(EVENT_TIMINGS))


CLI = ProtocolCli("slam_tracking", Settings, __doc__, example="frames=600")


def tracking_sequence(preset: str, seed: int, pace: float, frames: int, size: int,
                      timing: str = "bounded") -> tuple[str, SimSequence]:
    """The sequence of one preset x seed x pace x frame size (pixels) with the simulator's
    event ``timing`` (:data:`EVENT_TIMINGS`): its name (the folder under ``--work``) and settings."""
    cov = min(1.0, pace * frames / PAPER_FRAMES)
    spec = SimSequence(preset, seed, frames, size, (f"path.coverage={cov:.4f}", *EVENT_TIMINGS[timing]))
    name = f"{preset}_s{seed}_{size}px_pace{pace:g}" + ("" if timing == "bounded" else "_unbounded")
    return name, spec


def slam_command(seq: Path, out: Path, options: tuple[str, ...] = ()) -> list[str]:
    """The SLAM run of this benchmark on ``seq`` into ``out`` (replaced): ground-truth depth
    (unless ``options`` name a depth model), SIFT, default settings, no mesh."""
    depth = () if "--depth-model" in options else ("--depth-source", "files")
    return [sys.executable, "-m", "c3f_slam", "run", str(seq), *depth, "--descriptors", "sift",
            "--set", "fusion.enabled=false", "--quiet", "--overwrite", "--out", str(out), *options]


def run_variant(v: Variant, seq: Path, out: Path) -> dict:
    """Run the CLI of ``v`` on ``seq`` into ``out`` (replaced) and return its summary plus the
    ATE against the sequence's ground truth (None where nothing registered)."""
    env = {**os.environ, "PYTHONPATH": str(v.checkout)}
    proc = subprocess.run(slam_command(seq, out, v.options), cwd=v.checkout, env=env, capture_output=True, text=True)
    summary_path = out / "summary.json"
    if not summary_path.is_file():
        raise SystemExit(f"{v.name} on {seq}: no summary.json ({proc.stderr.strip()[-300:]})")
    s = json.loads(summary_path.read_text())
    g = Sequence(seq)
    ate = None
    if (out / "trajectory.txt").is_file() and s.get("registered_frames", 0) >= 3:
        st, P = read_tum(out / "trajectory.txt")
        ate = evaluate_trajectory(st, P, g.timestamps, g.poses)
    s["_ate"] = ate
    s["_path_length"] = float(np.linalg.norm(np.diff(g.poses[:, :3, 3], axis=0), axis=1).sum())  # whole GT path
    return s


def row(seq_name: str, v: Variant, s: dict, events: float) -> str:
    ate = s["_ate"]
    if ate is None or "ate_sim3" not in ate:
        ate_cm = ate_pct = "-"
    else:
        rmse = ate["ate_sim3"]["rmse_m"]
        ate_cm, ate_pct = f"{rmse * 100:.2f}", f"{100 * rmse / s['_path_length']:.2f}"
    fps = s.get("timings", {}).get("total", {}).get("frames_per_second", float("nan"))
    share = s.get("registered_share_of_usable", 0.0)
    breaks = f"{s.get('tracking_breaks', '-')}/{s.get('breaks_rejoined', '-')}"
    min_corr = s.get("config", {}).get("fragments", {}).get("min_correspondences")
    return (f"| {seq_name} | {100 * events:.0f} | {v.name} | {min_corr} |"
            f" {100 * share:.1f} | {ate_cm} | {ate_pct} | {s['_path_length'] * 100:.1f} | {breaks} | {fps:.1f} |")


def main(argv: list[str] | None = None) -> None:
    ap = CLI.parser()
    ap.add_argument("--work", type=Path, default=WORK / "slam_tracking", help=WORK_HELP)
    ap.add_argument("--baseline", type=Path, help="checkout of the code to compare with (run from its folder)")
    ap.add_argument("--report", type=Path, default=RESULTS / "slam_tracking.md", help=REPORT_HELP)
    a, settings = CLI.parse(ap, argv)
    variants = [Variant("this code, defaults", ROOT)]
    if settings.depth_model:
        variants.append(Variant("this code, predicted depth", ROOT,
                                ("--depth-model", str(Path(settings.depth_model).resolve()))))
    if a.baseline:
        variants.append(Variant("before, defaults", a.baseline))
        if settings.baseline_tuned:
            variants.append(Variant("before, min_correspondences 15", a.baseline,
                                    ("--set", "fragments.min_correspondences=15")))
    lines = ["| sequence | events % | code | min corr. | registered % of usable | ATE Sim(3) cm | ATE % of path "
             "| path cm | breaks / re-joined | frames/s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for timing, size, pace, preset, seed in itertools.product(settings.events, settings.sizes, settings.paces,
                                                              settings.presets, settings.seeds):
        name, spec = tracking_sequence(preset, seed, pace, settings.frames, size, timing)
        seq = ensure_sequence(spec, a.work / name, echo=True)
        events = read_event_labels(seq)
        ev_share = sum(1 for e in events if e) / max(len(events), 1)
        for k, v in enumerate(variants):
            s = run_variant(v, seq, a.work / "runs" / f"{name}_{k}")
            lines.append(row(name, v, s, ev_share))
            print(lines[-1], flush=True)
    rep = Report(__file__, "Tracking at default settings on sequences with events")
    body = [f"- {settings.frames} frames per sequence; pace 1 = the paper's (1.25 m in {PAPER_FRAMES} frames); "
            "ground-truth depth, SIFT, no mesh; events on (the presets' rates).",
            "- registered % of usable: frames in the main map over frames not skipped as black/saturated/"
            "featureless; breaks / re-joined: consecutive-frame tracking breaks and those bridged "
            "(this code only).", "", *lines]
    rep.publish(a.report, body, settings, options=a)
    print(f"wrote {a.report}")


if __name__ == "__main__":
    main()
