"""Registered share and ATE at default settings on simulator sequences with events.

For each preset x seed x pace x frame size: generate the sequence (the simulator's events
on), run ``python -m c3f_slam run`` with ground-truth depth and SIFT at **default settings**
(no threshold on the command line; no mesh, for speed) and evaluate: share of the usable
frames in the main map, ATE Sim(3) (cm and % of the ground-truth path length), frames/s,
tracking breaks and how many were re-joined. ``--baseline CHECKOUT`` runs the same with the
code of another checkout (e.g. a git worktree of the commit before the change; one whose
``run`` takes ``--set``), at its defaults (and with ``--set fragments.min_correspondences=15``,
what README used to pass, with ``--baseline-tuned``), side by side.

Pace: the paper's sequences cross the 1.25 m colon in 4,500 frames (~0.28 mm per frame);
pace p travels ``p x frames / 4500`` of it (``path.coverage``). Events are placed per 1000
frames; their ramps keep the simulator's rate limits (``path.max_turn_rate`` 120 deg/s,
``path.max_event_speed`` 6 cm/s at 30 fps; ``--events unbounded`` also runs the former
timing, ramps fixed in frames, close-ups turning up to ~38 deg per frame).
``--depth-model`` adds a run on predicted depth.

    python -m benchmarks.protocols.slam_tracking --presets seq1 seq3 seq2 --seeds 1 2 --paces 1 3 \\
        --frames 1500 --sizes 128 --baseline /tmp/before
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from c3f_slam.evaluation.trajectory import evaluate_trajectory
from c3f_slam.io import Sequence, read_tum
from datamodules.synthetic.generate import read_event_labels

PAPER_FRAMES = 4500  #: frames of the paper's sequences over the whole colon
#: simulator overrides per event timing (``--events``)
EVENT_TIMINGS = {"bounded": (), "unbounded": ("path.max_turn_rate=none", "path.max_event_speed=none")}
PRESETS, SEEDS, PACES = ("seq1", "seq3", "seq2"), (1, 2), (1.0, 3.0)  #: the default sequences


@dataclass(frozen=True)
class Variant:
    """One way of running the SLAM CLI: the checkout whose code runs, and extra options."""

    name: str
    checkout: Path
    options: tuple[str, ...] = ()


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
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=list(PRESETS))
    ap.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS))
    ap.add_argument("--paces", nargs="+", type=float, default=list(PACES), help="multiples of the paper's pace")
    ap.add_argument("--frames", type=int, default=1500)
    ap.add_argument("--sizes", nargs="+", type=int, default=[128])
    ap.add_argument("--work", type=Path, default=WORK / "slam_tracking", help="folder for sequences and runs")
    ap.add_argument("--baseline", type=Path, help="checkout of the code to compare with (run from its folder)")
    ap.add_argument("--baseline-tuned", action="store_true",
                    help="also run the baseline with --set fragments.min_correspondences=15 (README's former "
                         "advice)")
    ap.add_argument("--events", nargs="+", choices=sorted(EVENT_TIMINGS), default=["bounded"],
                    help="bounded: the simulator's event ramps within path.max_turn_rate / max_event_speed (its "
                         "defaults); unbounded: ramps fixed in frames (the simulator before the bounds)")
    ap.add_argument("--depth-model", type=Path, help="also run with predicted depth from this DepthNet ONNX")
    ap.add_argument("--report", type=Path, default=RESULTS / "slam_tracking.md")
    a = ap.parse_args(argv)
    variants = [Variant("this code, defaults", ROOT)]
    if a.depth_model:
        variants.append(Variant("this code, predicted depth", ROOT, ("--depth-model", str(a.depth_model.resolve()))))
    if a.baseline:
        variants.append(Variant("before, defaults", a.baseline))
        if a.baseline_tuned:
            variants.append(Variant("before, min_correspondences 15", a.baseline,
                                    ("--set", "fragments.min_correspondences=15")))
    lines = ["| sequence | events % | code | min corr. | registered % of usable | ATE Sim(3) cm | ATE % of path "
             "| path cm | breaks / re-joined | frames/s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for timing, size, pace, preset, seed in itertools.product(a.events, a.sizes, a.paces, a.presets, a.seeds):
        name, spec = tracking_sequence(preset, seed, pace, a.frames, size, timing)
        seq = ensure_sequence(spec, a.work / name, echo=True)
        events = read_event_labels(seq)
        ev_share = sum(1 for e in events if e) / max(len(events), 1)
        for k, v in enumerate(variants):
            s = run_variant(v, seq, a.work / "runs" / f"{name}_{k}")
            lines.append(row(name, v, s, ev_share))
            print(lines[-1], flush=True)
    rep = Report(__file__, "Tracking at default settings on sequences with events")
    body = [f"- {a.frames} frames per sequence; pace 1 = the paper's (1.25 m in {PAPER_FRAMES} frames); "
            "ground-truth depth, SIFT, no mesh; events on (the presets' rates).",
            "- registered % of usable: frames in the main map over frames not skipped as black/saturated/"
            "featureless; breaks / re-joined: consecutive-frame tracking breaks and those bridged "
            "(this code only).", "", *lines]
    rep.publish(a.report, body, a)
    print(f"wrote {a.report}")


if __name__ == "__main__":
    main()
