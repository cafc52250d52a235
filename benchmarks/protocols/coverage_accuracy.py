"""Accuracy of the run's unseen-surface estimate against the truth.

For each case (a simulator sequence whose true unseen share differs: path kind, fold height,
speed, close-ups, a loop), generate it, run ``python -m c3f_slam run`` with ground-truth
depth and SIFT at default settings (coverage on, 5 cm segments), then ``python -m c3f_slam
evaluate --gt``: the estimate (from the run's trajectory and fused mesh only) against the
truth (the true mesh seen from the true poses of every frame, folds occluding), overall and
per segment. Goal: overall within +-2 percentage points, per segment within +-5.
``--set depth_model=MODEL`` runs the same on predicted depth instead.

    python -m benchmarks.protocols.coverage_accuracy --set jobs=2
    python -m benchmarks.protocols.coverage_accuracy --set cases=insertion,loop --report /tmp/coverage.md

Settings (``--print-config``: each with its default and meaning): :class:`Settings`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, WORK_HELP, ProtocolCli, check_choices, check_not_empty
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence

PRESET, SEED, FRAMES, SIZE = "seq1", 7, 300, 128  #: the cases' simulator defaults (size in pixels)
BASE = ("path.coverage=0.15",)  #: README's first example: 19 cm of colon in 300 frames (~0.6 mm per frame)


@dataclass(frozen=True)
class Case:
    name: str
    overrides: tuple[str, ...]
    what: str


CASES = (
    Case("insertion", BASE, "README's first example (path A)"),
    Case("withdrawal", (*BASE, "path.kind=B"), "path B"),
    Case("tall-folds", (*BASE, "colon.fold_height=0.6"), "folds 60 % of the radius (default 38 %)"),
    Case("low-folds", (*BASE, "colon.fold_height=0.15"), "folds 15 % of the radius"),
    Case("fast", ("path.coverage=0.4",), "2.7x faster: 50 cm in 300 frames"),
    Case("close-ups", (*BASE, "path.closeups=15"), "15 close-ups of the wall per 1000 frames (default 3)"),
    Case("loop", (*BASE, "path.loop=true"), "forward, then back over the same stretch"),
)


def case_sequence(case: Case, preset: str = PRESET, seed: int = SEED, frames: int = FRAMES,
                  size: int = SIZE) -> SimSequence:
    """The simulator settings of ``case`` (frame size in pixels)."""
    return SimSequence(preset, seed, frames, size, case.overrides)


@dataclass(frozen=True)
class Settings:
    """What coverage_accuracy measures."""

    #: the cases run: insertion, withdrawal, tall-folds, low-folds, fast, close-ups, loop
    cases: tuple[str, ...] = tuple(c.name for c in CASES)
    preset: str = PRESET  #: simulator preset of every case
    seed: int = SEED  #: simulator seed of every case
    frames: int = FRAMES  #: frames per sequence
    size: int = SIZE  #: square frame size, pixels
    jobs: int = 2  #: cases run at once
    depth_model: str | None = None  #: DepthNet ONNX export or zoo:NAME: predicted depth instead of the true depth

    def __post_init__(self) -> None:
        check_not_empty(self, "cases")
        check_choices("cases", self.cases, (c.name for c in CASES))


CLI = ProtocolCli("coverage_accuracy", Settings, __doc__, example="cases=insertion,loop")


def slam_command(seq: Path, out: Path, depth_model: Path | str | None = None,
                 options: tuple[str, ...] = ()) -> list[str]:
    """The SLAM run of a case on ``seq`` into ``out`` (replaced): ground-truth depth (or
    ``depth_model``'s), SIFT, default settings (plus ``options``, e.g. ``--set K=V``), mesh and
    coverage on."""
    depth = ["--depth-model", str(depth_model)] if depth_model else ["--depth-source", "files"]
    return [sys.executable, "-m", "c3f_slam", "run", str(seq), *depth, "--descriptors", "sift", "--quiet",
            "--overwrite", "--out", str(out), *options]


def run_case(case: Case, a: Settings | argparse.Namespace, work: Path) -> dict:
    """Generate (into ``work``), run, evaluate one case with the simulator and depth settings of ``a``
    (plus its ``slam_options``, if any); returns evaluation.json's ``unseen`` plus the run's registered share."""
    seq = ensure_sequence(case_sequence(case, a.preset, a.seed, a.frames, a.size), work / case.name)
    out = work / "runs" / case.name
    run = subprocess.run(slam_command(seq, out, a.depth_model, tuple(getattr(a, "slam_options", ()))), cwd=ROOT,
                         capture_output=True, text=True)
    if run.returncode != 0:
        return {"status": f"run failed: {run.stderr.strip()[-200:]}"}
    ev = subprocess.run([sys.executable, "-m", "c3f_slam", "evaluate", str(out), "--gt", str(seq)], cwd=ROOT,
                        capture_output=True, text=True)
    if ev.returncode != 0:
        return {"status": f"evaluate failed: {ev.stderr.strip()[-200:]}"}
    res = json.loads((out / "evaluation.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    return {**res["unseen"], "registered_share": summary.get("registered_share", 0.0)}


def case_row(case: Case, u: dict) -> str:
    if u.get("status") != "ok":
        return f"| {case.name} | {case.what} | {u.get('status')} | | | | | | |"
    seg = np.array([s["error_pp"] for s in u["segments"]])
    return (f"| {case.name} | {case.what} | {100 * u['registered_share']:.1f} | {100 * u['truth']:.1f} |"
            f" {100 * u['estimate']:.1f} | {u['error_pp']:+.1f} | {np.abs(seg).max():.1f} | {len(seg)} |"
            f" {100 * u['truth_registered']:.1f} | {100 * (u['estimate'] - u['truth_registered']):+.1f} |")


def segment_rows(case: Case, u: dict) -> list[str]:
    return [f"| {case.name} | {100 * s['start_m']:.0f}-{100 * s['end_m']:.1f} | {100 * s['truth']:.1f} |"
            f" {100 * s['estimate']:.1f} | {s['error_pp']:+.1f} | {100 * s['truth_registered']:.1f} |"
            f" {100 * (s['estimate'] - s['truth_registered']):+.1f} |" for s in u.get("segments", [])]


def summary_lines(results: list[tuple[Case, dict]]) -> list[str]:
    ok = [u for _, u in results if u.get("status") == "ok"]
    if not ok:
        return ["No case completed."]
    out = []
    for label, key in (("truth", "truth"), ("truth from the registered frames", "truth_registered")):
        overall = np.abs([100 * (u["estimate"] - u[key]) for u in ok])
        seg = np.abs([100 * (s["estimate"] - s[key]) for u in ok for s in u["segments"]])
        out += [f"- vs the {label}: overall mean |error| {overall.mean():.1f} pp, max {overall.max():.1f} pp, "
                f"{int((overall <= 2).sum())} of {len(ok)} cases within +-2 pp; per segment mean |error| "
                f"{seg.mean():.1f} pp, max {seg.max():.1f} pp, {int((seg <= 5).sum())} of {len(seg)} within +-5 pp"]
    return out


def main(argv: list[str] | None = None) -> None:
    ap = CLI.parser()
    ap.add_argument("--work", type=Path, default=WORK / "coverage_accuracy", help=WORK_HELP)
    ap.add_argument("--report", type=Path, default=RESULTS / "coverage_accuracy.md", help=REPORT_HELP)
    a, settings = CLI.parse(ap, argv)
    cases = [c for c in CASES if c.name in settings.cases]
    with ThreadPoolExecutor(max(1, settings.jobs)) as pool:
        results = list(zip(cases, pool.map(lambda c: run_case(c, settings, a.work), cases), strict=True))
    depth = f"predicted depth ({Path(settings.depth_model).name})" if settings.depth_model else "ground-truth depth"
    lines = ["| case | sequence | registered % | truth unseen % | estimate % | error pp | max segment error pp "
             "| segments | truth, registered frames % | error vs it pp |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [case_row(c, u) for c, u in results]
    seg = ["| case | segment cm | truth unseen % | estimate % | error pp | truth, registered frames % "
           "| error vs it pp |", "|---|---|---|---|---|---|---|"]
    seg += [r for c, u in results for r in segment_rows(c, u)]
    for line in lines:
        print(line)
    rep = Report(__file__, f"Unseen-surface estimate vs truth ({depth})")
    body = [f"- preset {settings.preset}, seed {settings.seed}, {settings.frames} frames, {settings.size} px; "
            f"SLAM with {depth} and SIFT at default settings; 5 cm segments along the centreline of the camera path.",
            "- truth: the true mesh seen from the true poses of every frame (registered or not), occluded by the "
            "true surface, same cells and settings; estimate: the run's own trajectory and fused mesh only.",
            "- error = estimate - truth, percentage points; 'truth, registered frames': the truth seen from the "
            "frames the run registered only (the estimate cannot know frames it did not register: the difference "
            "between the two truths is what tracking losses cost).", "", *summary_lines(results), "", *lines, "",
            "Per segment:", "", *seg]
    rep.publish(a.report, body, settings, options=a)
    print(f"wrote {a.report}")


if __name__ == "__main__":
    main()
