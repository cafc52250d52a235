"""Does a depth network draw the occluding edges of the folds? Predicted vs true depth steps
(outside CI).

The unseen-wall estimate needs the wall hidden behind a fold to be hidden in the map too, so
the predicted depth must step where the true depth steps (the fold's crest in front of the wall
behind it). For every ``--every``-th frame of each sequence with true depth this script finds
the true occluding edges, the pixels where the true log depth changes by more than ``--step``
between the pixels 4 px apart around it (horizontally or vertically, the larger), and reports

- the median true step there and the predicted step at the same pixels (log depth, so a step of
  0.41 is a 50 % jump in depth);
- ``kept``: the share of those pixels where the prediction steps at least half as much as the
  truth;
- ``range``: the predicted log-depth range (10th to 90th percentile) over the true one, median
  over frames: the depth's overall relief, against which the edges are compared.

    python -m benchmarks.studies.depth_edges SEQ [SEQ ...] --depth-model zoo:c3f-depth-r18w32 \
        [--depth-model OTHER.onnx ...] --report /tmp/depth_edges.md

Findings so far: docs/lab_notes/2026-12-06-depth-edges.md.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from benchmarks.common import STUDIES
from benchmarks.common.depth_models import add_depth_study_arguments, depth_runs
from benchmarks.common.report import Report
from c3f_slam.io import Sequence

SPAN = 2  # pixels between the two depths a step is measured across


def log_steps(depth: np.ndarray) -> np.ndarray:
    """(H - 2 SPAN, W - 2 SPAN) the larger of the horizontal and vertical |log depth| change
    across ``2 * SPAN`` pixels, centred on each inner pixel; NaN where a depth is missing (<= 0)."""
    d = np.asarray(depth, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        log = np.where(d > 0, np.log(np.where(d > 0, d, 1.0)), np.nan)
    s = SPAN
    gx = np.abs(log[s:-s, 2 * s:] - log[s:-s, : -2 * s])
    gy = np.abs(log[2 * s:, s:-s] - log[: -2 * s, s:-s])
    return np.fmax(gx, gy)


def edge_measures(true: np.ndarray, pred: np.ndarray, step: float) -> dict | None:
    """The measures of the module docstring for one frame (None without true edges)."""
    st, sp = log_steps(true), log_steps(pred)
    edge = np.isfinite(st) & np.isfinite(sp) & (st > step)
    if edge.sum() < 5:
        return None
    lt, lp = np.log(true[(true > 0) & (pred > 0)]), np.log(pred[(true > 0) & (pred > 0)])
    return {"true_step": float(np.median(st[edge])), "pred_step": float(np.median(sp[edge])),
            "kept": float(np.mean(sp[edge] >= 0.5 * st[edge])), "pixels": int(edge.sum()),
            "range": float(np.subtract(*np.percentile(lp, [90, 10])) / np.subtract(*np.percentile(lt, [90, 10])))}


def analyse(seq: Sequence, predict: Callable[[int], np.ndarray], every: int, step: float) -> dict:
    """Medians over the frames of ``seq`` (every ``every``-th) that have true occluding edges."""
    rows = [r for i in range(0, len(seq), every)
            if (r := edge_measures(seq.read_depth(i), np.asarray(predict(i), np.float64), step)) is not None]
    if not rows:
        return {"frames": 0}
    return {"frames": len(rows), **{k: float(np.median([r[k] for r in rows]))
                                    for k in ("true_step", "pred_step", "kept", "range")}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_depth_study_arguments(ap, 10, STUDIES / "depth_edges.md", "depth/")
    ap.add_argument("--step", type=float, default=0.25, help="true log-depth step that makes an edge")
    args = ap.parse_args()
    if args.every < 1 or args.step <= 0:
        raise SystemExit("--every must be >= 1 and --step > 0")
    rows = []
    for name, path, seq, predict in depth_runs(args.depth_model, args.sequences, args.threads):
        r = analyse(seq, predict, args.every, args.step)
        print(name, path.name, r, flush=True)
        if r["frames"] == 0:
            rows.append(f"| {name} | {path.name} | 0 | | | | |")
            continue
        rows.append(f"| {name} | {path.name} | {r['frames']} | {r['true_step']:.3f} | {r['pred_step']:.3f} | "
                    f"{100 * r['kept']:.0f} | {r['range']:.2f} |")
    report = Report(__file__, "Does the depth network draw the occluding edges of the folds?")
    text = report.render([
        (f"- Every {args.every}th frame; a true occluding edge is a pixel where the true log depth changes by more "
         f"than {args.step} across {2 * SPAN} px (horizontally or vertically). Medians over the frames with such "
         "edges."),
        ("- Columns: frames; median log-depth step at the true edges, true and predicted (the same pixels; 0.41 = "
         "a 50 % jump); share of edge pixels where the prediction steps at least half as much as the truth (%); "
         "predicted over true log-depth range (10th-90th percentile)."), "",
        "| depth model | sequence | frames | true step | predicted step | kept % | range |",
        "|---|---|---|---|---|---|---|",
        *rows])
    report.write(args.report, text)
    print(text)


if __name__ == "__main__":
    main()
