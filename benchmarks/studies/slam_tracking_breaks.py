"""Where and why consecutive-frame tracking breaks on a sequence (RGB-D; outside CI).

Runs the SLAM frontend (SIFT outside speculars, depth from the sequence's depth/ files) and the
runtime's pair matching (:func:`c3f_slam.pipeline.frontend.explain_match`, default
:class:`SlamConfig` thresholds) on every pair of consecutive frames, and reports:

- pairs the runtime cannot link (no accepted match: the full system opens a fragment whose
  keyframe must match some earlier keyframe, the odometry baseline loses track), with the
  filter's reason;
- pairs under the new-fragment threshold (``--min-correspondences``);
- for each, the ground-truth motion between the two frames (poses.txt) and, for simulator
  sequences, the event the frames belong to (frames.csv: closeup, burst, occluded, roll);
- whether the runtime's guided matching (``fallback.guided``: search by projection with the
  last accepted inter-frame motion) links the broken pair, as the runtime tries it next;
- with ``--run OUT`` (a ``c3f_slam run`` folder on the same sequence): where frame i ended up
  in that run -- the main map, another component, or not registered -- so the report says which
  breaks remain in the final map.

    python -m benchmarks.studies.slam_tracking_breaks /work/slam_ate4500/seq1_s1 --report /tmp/breaks.md
    python -m benchmarks.studies.slam_tracking_breaks SEQ --run OUT --report /tmp/breaks.md

Writes a Markdown report (the command line, a summary by event and the broken pairs).
"""

from __future__ import annotations

import argparse
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from benchmarks.common.report import Report
from c3f_slam.frames.stream import FrameStream
from c3f_slam.geometry import relative_motion
from c3f_slam.io import Sequence, read_tum
from c3f_slam.pipeline import SlamConfig
from c3f_slam.pipeline.frontend import Frontend, SiftDescriptors, explain_match, guided_matcher
from datamodules.synthetic.generate import read_event_labels


def events_of(seq: Path, n: int) -> list[str]:
    """Per-frame simulator event labels ('' = none; all '' without frames.csv)."""
    return (read_event_labels(seq) + [""] * n)[:n]


def reason_kind(reason: str) -> str:
    """The filter's reason without its numbers."""
    return reason.split(" (")[0] if reason else ""


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence", type=Path, help="sequence folder with depth/ (and poses.txt, frames.csv if any)")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--min-correspondences", type=int, default=None,
                    help="new-fragment threshold to report against (default: the runtime's, from the frame size)")
    ap.add_argument("--run", type=Path, default=None,
                    help="a c3f_slam run folder on this sequence: where each broken pair's frame ended up")
    ap.add_argument("--list", type=int, default=60, help="broken pairs listed one by one (0 = none)")
    ap.add_argument("--report", type=Path, default=None, help="Markdown report (default: print only)")
    return ap.parse_args()


def pair_rows(sequence: Path, max_frames: int | None, cfg: SlamConfig) -> tuple[list[dict], bool]:
    """One row per consecutive pair (i - 1, i) and whether the rows hold the true motion.

    A row holds ``i``, the keypoints of frame i (``kp``), descriptor matches (``candidates``),
    filter survivors (``filtered``), accepted correspondences ``n`` (0 = broken pair), the
    filter's ``reason``, the event of either frame and, with poses.txt, the ground-truth
    rotation (``rot_deg``, degrees) and translation (``trans_mm``, mm) between the frames.
    """
    stream = FrameStream(sequence, use_depth=True, max_frames=max_frames)
    seq = Sequence(sequence)
    # ground-truth motion of each consecutive pair (i - 1, i), at index i - 1
    step_t, step_rot = relative_motion(seq.poses) if seq.has_poses else (None, None)
    front = Frontend(stream.camera.K, SiftDescriptors(), cfg.frontend)
    guided = guided_matcher(cfg, stream.camera.K)
    rows = []
    prev, last_motion = None, np.eye(4)
    for frame in stream:
        if frame.depth is None:
            raise SystemExit(f"{sequence}: no depth/ folder (this diagnostic runs in RGB-D mode)")
        feat = front.describe(frame, front.keypoints(frame.rgb), frame.depth)
        if prev is not None:
            att = explain_match(prev, feat, cfg.match_filter, "l2", cfg.frontend.ratio)
            row = {"i": frame.index, "kp": len(feat), "candidates": att.candidates, "filtered": att.filtered,
                   "n": att.match.n if att.match else 0, "reason": att.reason, "guided": 0}
            link = att.match
            if link is None and cfg.fallback.guided:
                radius = cfg.fallback.guided_radius * min(frame.depth.shape[:2])
                link, row["guided"] = guided(prev, feat, last_motion, radius)
            last_motion = link.T_ij if link is not None else np.eye(4)  # as the runtime's LinkRecovery
            if step_t is not None:
                row["rot_deg"] = float(step_rot[frame.index - 1])
                row["trans_mm"] = 1e3 * float(step_t[frame.index - 1])
            rows.append(row)
        prev = feat
    events = events_of(sequence, len(rows) + 1)
    for r in rows:  # a pair belongs to an event when either frame does
        r["event"] = events[r["i"]] or events[r["i"] - 1]
    return rows, step_t is not None


def run_placement(run: Path, sequence: Path) -> dict[int, str]:
    """Frame index -> where the run put it: ``main`` (trajectory.txt), ``component NN``
    (components/NN/trajectory.txt) or absent (not registered). Frames are matched to the
    sequence's poses.txt time stamps (within 1 ms)."""
    seq = Sequence(sequence)
    if seq.timestamps is None:
        raise SystemExit(f"{sequence}: no poses.txt, cannot match the run's time stamps to frames")
    files = [("main", run / "trajectory.txt")]
    files += [(f"component {p.parent.name}", p) for p in sorted(run.glob("components/*/trajectory.txt"))]
    if not files[0][1].is_file():
        raise SystemExit(f"{files[0][1]}: no trajectory (is {run} a c3f_slam run folder?)")
    where: dict[int, str] = {}
    for name, path in files:
        stamps, _ = read_tum(path)
        idx = np.searchsorted(seq.timestamps, stamps).clip(0, len(seq.timestamps) - 1)
        prev = (idx - 1).clip(0)
        best = np.where(np.abs(seq.timestamps[prev] - stamps) < np.abs(seq.timestamps[idx] - stamps), prev, idx)
        for k, st in zip(best, stamps):
            if abs(seq.timestamps[k] - st) < 1e-3:
                where.setdefault(int(k), name)
    return where


def _median(rows: list[dict], key: str, have_motion: bool) -> str:
    return f"{np.median([r[key] for r in rows]):.2f}" if rows and have_motion else "-"


def _summary_lines(rows: list[dict], cfg: SlamConfig, min_correspondences: int) -> list[str]:
    """Counts of pairs, broken and weak pairs, the matching settings and the reasons of the breaks."""
    broken = [r for r in rows if r["n"] == 0]
    weak = [r for r in rows if 0 < r["n"] < min_correspondences]
    reasons = Counter(reason_kind(r["reason"]) for r in broken).most_common()
    guided = [r for r in broken if r["guided"] > 0]
    placed = [r for r in broken if "placed" in r]
    lines = [
        (f"- {len(rows) + 1} frames, {len(rows)} consecutive pairs; "
         f"SIFT (max {cfg.frontend.max_keypoints} keypoints, contrast "
         f"threshold {cfg.frontend.sift_contrast_threshold}), ratio {cfg.frontend.ratio}, match filter defaults (>= "
         f"{cfg.match_filter.min_matches} correspondences, residual {1e3 * cfg.match_filter.max_residual:g} mm)."),
        (f"- Broken pairs (no accepted match): {len(broken)}; accepted but under {min_correspondences} "
         f"correspondences: {len(weak)}; "
         f"median correspondences of all pairs: {np.median([r['n'] for r in rows]):.0f}."),
        "- Reasons of the broken pairs: " + (", ".join(f"{k} {v}" for k, v in reasons) or "-") + ".",
        (f"- Of the broken pairs, guided matching (search by projection with the last motion, radius "
         f"{cfg.fallback.guided_radius:g} of the image side{'' if cfg.fallback.guided else '; off'}) links "
         f"{len(guided)}; the other {len(broken) - len(guided)} leave the runtime to its keyframe matching "
         "and re-joining."),
    ]
    if placed:
        where = Counter(r["placed"] for r in placed)
        lines.append(f"- In the run given, frame i of the {len(placed)} broken pairs is: "
                     + ", ".join(f"{k} {v}" for k, v in sorted(where.items())) + ".")
    return lines


def _event_table(rows: list[dict], min_correspondences: int, have_motion: bool) -> list[str]:
    """Markdown table: pairs, broken and weak pairs and median motions per event ('none' first)."""
    by_event: dict[str, list] = defaultdict(list)
    for r in rows:
        by_event[r["event"] or "none"].append(r)
    lines = [
        ("| event | pairs | broken | of them linked by guided matching | under threshold "
         "| median rotation deg/frame | median translation mm/frame "
         "| median rotation of broken pairs | median translation of broken pairs |"),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for ev in sorted(by_event, key=lambda e: (e != "none", e)):
        rs = by_event[ev]
        br = [r for r in rs if r["n"] == 0]
        wk = [r for r in rs if 0 < r["n"] < min_correspondences]
        gd = sum(r["guided"] > 0 for r in br)
        lines.append(f"| {ev} | {len(rs)} | {len(br)} | {gd} | {len(wk)} | {_median(rs, 'rot_deg', have_motion)} | "
                     f"{_median(rs, 'trans_mm', have_motion)} | "
                     f"{_median(br, 'rot_deg', have_motion)} | {_median(br, 'trans_mm', have_motion)} |")
    return lines


def _broken_list(rows: list[dict], limit: int, have_motion: bool) -> list[str]:
    """The first ``limit`` broken pairs one by one (nothing when ``limit`` is 0 or none broke)."""
    broken = [r for r in rows if r["n"] == 0]
    if not (limit and broken):
        return []
    lines = ["", "Broken pairs (frame i-1 -> i; guided: correspondences of guided matching, 0 = no link; "
             "in the run: where frame i ended up, with --run):", "",
             ("| frame i | event | keypoints | descriptor matches | filter survivors | rotation deg | "
              "translation mm | reason | guided | in the run |"), "|---|---|---|---|---|---|---|---|---|---|"]
    for r in broken[:limit]:
        lines.append(f"| {r['i']} | {r['event'] or '-'} | {r['kp']} | {r['candidates']} | {r['filtered']} | "
                     + (f"{r['rot_deg']:.1f} | {r['trans_mm']:.2f}" if have_motion else "- | -")
                     + f" | {r['reason']} | {r['guided']} | {r.get('placed', '-')} |")
    if len(broken) > limit:
        lines.append(f"\n({len(broken) - limit} more not listed)")
    return lines


def main() -> None:
    a = _arguments()
    camera = Sequence(a.sequence).camera
    cfg = SlamConfig().for_frame_size(camera.width, camera.height)
    min_corr = a.min_correspondences or cfg.fragments.min_correspondences
    rows, have_motion = pair_rows(a.sequence, a.max_frames, cfg)
    if a.run is not None:
        where = run_placement(a.run, a.sequence)
        for r in rows:
            if r["n"] == 0:
                r["placed"] = where.get(r["i"], "not registered")
    lines = [*_summary_lines(rows, cfg, min_corr), "",
             *_event_table(rows, min_corr, have_motion),
             *_broken_list(rows, a.list, have_motion)]
    report = Report(__file__, "Consecutive-frame tracking breaks")
    text = report.render(lines)
    if a.report:
        report.write(a.report, text)
    print(text)


if __name__ == "__main__":
    main()
